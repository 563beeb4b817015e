"""The ``report`` job, the main job: identify, diagnose and write the HTML report of one or more data sets.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from pathlib import Path

from bayesdamper.run.identify import identify_out_dir, run_identify
from bayesdamper.run.progress import Progress


def run_report(data_dir: str | os.PathLike | Sequence[str | os.PathLike], out: str, *, seed: int = 0,
               credible_mass: float = 0.9, tmax: float = 3.0, workers: int = 0, max_steps: int | None = None,
               figures: bool = True, diagnose: bool = True, **identify_options) -> list[Path]:
    """``bayesdamper report``: ``identify``, then (if available) ``diagnose``, then ``OUT/report.html``.

    Takes the options of :func:`run_identify`. Returns the written report(s), one per data set.
    """
    from bayesdamper.report.html import render_report

    single = isinstance(data_dir, str | os.PathLike)
    dirs = [data_dir] if single else list(data_dir)
    summaries = run_identify(dirs, out, seed=seed, credible_mass=credible_mass, tmax=tmax, workers=workers,
                             max_steps=max_steps, figures=figures, **identify_options)
    run_diagnosis, note = None, None
    if not diagnose:
        note = "not requested"
    elif identify_options.get("only"):
        note = "--only selects a subset of the transients; the diagnosis needs them all"
    else:
        try:
            from bayesdamper.run.diagnose import run_diagnosis
        except ImportError as err:  # not part of this installation (yet): the report says so
            note = f"the diagnosis module cannot be imported ({err})"
            print(f"bayesdamper report: no diagnosis: {note}", file=sys.stderr)
    joint = None
    if run_diagnosis is not None and len(dirs) > 1:
        from bayesdamper.io.dataset import load_dataset
        from bayesdamper.run.conditions import one_damper, run_conditions

        if one_damper([load_dataset(d, tmax=None) for d in dirs]) is None:  # one damper under several conditions
            joint = run_conditions([str(d) for d in dirs], str(out), seed=seed, workers=workers, tmax=tmax,
                                   credible_mass=credible_mass, max_steps=max_steps, figures=figures,
                                   mode=identify_options.get("mode", "auto"))["diagnoses"]
    pages = []
    for k, (d, summary) in enumerate(zip(dirs, summaries, strict=True)):
        out_dir = identify_out_dir(out, summary, len(dirs))
        diagnosis = None
        if joint is not None:
            diagnosis = joint[k]
        elif run_diagnosis is not None:
            diagnosis = run_diagnosis(str(d), str(out_dir), seed=seed, workers=workers, tmax=tmax,
                                      credible_mass=credible_mass, max_steps=max_steps, figures=figures,
                                      mode=identify_options.get("mode", "auto"))
        with Progress().phase(f"report ({summary['dataset']})", unit="page") as ph:
            page = render_report(summary, diagnosis, out_dir, diagnosis_note=note)
            ph.done = 1
        print(f"report written to {page}")
        pages.append(page)
    return pages
