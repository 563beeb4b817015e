"""The output folder of a run: its files, the settings fingerprint, resume and ``--force``.

An ``identify`` output folder holds ``run.json`` (the settings fingerprint and provenance),
``summary.json``, ``posteriors/<id>.nc`` and ``figures/``. Runs are resumable: a transient whose
posterior file exists and carries the same settings fingerprint is read back, not re-sampled, and its
file is not rewritten. A folder holding results of other settings is refused unless ``force`` is set.
"""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import sys
from pathlib import Path

from bayesdamper.core.errors import SettingsError
from bayesdamper.inference.stage2 import WindowResult
from bayesdamper.report.figures import FIGURES_DIR
from bayesdamper.report.html import REPORT_FILE

#: Files and folders an ``identify`` run owns inside its output folder (``--force`` clears them).
RUN_FILE = "run.json"
SUMMARY_FILE = "summary.json"
DIAGNOSIS_FILE = "diagnosis.json"
POSTERIORS_DIR = "posteriors"
OWNED = (POSTERIORS_DIR, FIGURES_DIR, SUMMARY_FILE, RUN_FILE, REPORT_FILE)
#: Name of a temporary file of the atomic writers (``outputs.atomic_write_bytes``,
#: ``posterior.write_netcdf``): ``.<name>.tmp<pid>``. Only a killed process leaves one behind.
_TEMPORARY = re.compile(r"^\..+\.tmp\d+$")


def fingerprint_basis(settings: dict, tmax: float, seed: int, dataset_sha256: str) -> dict:
    """What a stored result depends on: stage-2 settings, window length [s], run seed, input data."""
    basis = {"settings": settings, "tmax_s": float(tmax), "seed": int(seed), "dataset_sha256": dataset_sha256}
    return json.loads(json.dumps(basis))  # tuples -> lists, as read back from a file


def settings_fingerprint(basis: dict) -> str:
    """SHA-256 of the canonical JSON (sorted keys, no spaces) of a :func:`fingerprint_basis`."""
    return hashlib.sha256(json.dumps(basis, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def _flatten(d, prefix: str = "") -> dict:
    if not isinstance(d, dict):
        return {prefix: d}
    out = {}
    for k, v in d.items():
        out.update(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
    return out


def _differences(old: dict, new: dict) -> list[str]:
    a, b = _flatten(old), _flatten(new)
    out = []
    for k in sorted(set(a) | set(b)):
        if a.get(k) != b.get(k):
            out.append("the input data (dataset_sha256)" if k == "dataset_sha256" else
                       f"{k} {json.dumps(a.get(k))} -> {json.dumps(b.get(k))}")
    return out


def _stored_basis(out_dir: Path) -> tuple[str, dict | None] | None:
    """Where ``out_dir`` records the settings of results it holds, and their basis.

    None if it holds no results; ``(source, None)`` if it holds results whose settings are unknown.
    Results of versions before ``run.json`` are recognised by their ``summary.json`` or posteriors.
    """
    from bayesdamper.inference import posterior as post

    if (out_dir / RUN_FILE).is_file():
        try:
            return RUN_FILE, json.loads((out_dir / RUN_FILE).read_text())["fingerprint_basis"]
        except (OSError, ValueError, KeyError, TypeError):
            return RUN_FILE, None
    if (out_dir / SUMMARY_FILE).is_file():
        try:
            s = json.loads((out_dir / SUMMARY_FILE).read_text())
            return SUMMARY_FILE, fingerprint_basis(s["settings"], s["tmax_s"], s["seed"],
                                                   s["provenance"]["dataset_sha256"])
        except (OSError, ValueError, KeyError, TypeError):
            return SUMMARY_FILE, None
    ncs = sorted((out_dir / POSTERIORS_DIR).glob("*.nc")) if (out_dir / POSTERIORS_DIR).is_dir() else []
    if ncs:
        try:
            a = post.read_transient(ncs[0])["attrs"]
            return (f"{POSTERIORS_DIR}/{ncs[0].name}",
                    fingerprint_basis(a["settings"], a["tmax_s"], a["run_seed"], a["dataset_sha256"]))
        except Exception:  # noqa: BLE001 - any unreadable file: settings unknown
            return f"{POSTERIORS_DIR}/{ncs[0].name}", None
    return None


def check_output_folder(out_dir: Path, basis: dict, force: bool) -> None:
    """Raise SettingsError if ``out_dir`` holds results of other (or unknown) settings and not ``force``."""
    if out_dir.exists() and not out_dir.is_dir():
        raise SettingsError(f"{out_dir}: exists and is not a folder")
    if force or not out_dir.is_dir():
        return
    stored = _stored_basis(out_dir)
    if stored is None:
        return
    source, old = stored
    if old is None:
        why = f"{source} records no readable settings"
    elif old == basis:
        return
    else:
        why = "; ".join(_differences(old, basis)) + " differ"
    raise SettingsError(f"{out_dir}: holds results of different settings ({why}); use --force to overwrite")


def _clear(out_dir: Path) -> None:
    for name in OWNED:
        p = out_dir / name
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        elif p.exists() or p.is_symlink():
            p.unlink()


def _remove_temporaries(out_dir: Path) -> int:
    """Delete temporary files a killed run's atomic writers left in the folders this run owns."""
    n = 0
    for folder in (out_dir, out_dir / POSTERIORS_DIR, out_dir / FIGURES_DIR):
        if not folder.is_dir():
            continue
        for p in (folder.rglob("*") if folder != out_dir else folder.iterdir()):
            if p.is_file() and _TEMPORARY.match(p.name):
                p.unlink()
                n += 1
    return n


def open_run(job, settings, *, seed: int, workers: int, force: bool, progress, started_utc: str, mode: str,
             prov_extra: dict, run_extra: dict) -> tuple[Path, dict, dict]:
    """Prepare a validated job's output folder and write its ``run.json`` (status "running").

    Clears results of other settings (``force``), removes temporaries of a killed run, and returns
    (posteriors folder, provenance stored with every posterior, the run record).
    """
    from bayesdamper.io.outputs import atomic_write_json, versions

    ds, out_dir = job.ds, job.out_dir
    if force:
        _clear(out_dir)
    post_dir = out_dir / POSTERIORS_DIR
    post_dir.mkdir(parents=True, exist_ok=True)
    if (n := _remove_temporaries(out_dir)):
        progress(f"removed {n} temporary file(s) left by an interrupted run")
    prov = {"dataset": ds.name, "dataset_path": str(ds.path), "input_sha256": ds.input_hashes(),
            "dataset_sha256": ds.sha256, "versions": versions(), "run_seed": seed, **prov_extra,
            "settings_fingerprint": job.fingerprint}
    run = {"fingerprint": job.fingerprint, "fingerprint_basis": job.basis,
           "fingerprint_of": "sha256 of the canonical JSON (sorted keys, no spaces) of fingerprint_basis",
           "status": "running", "started_utc": started_utc, "dataset": ds.name, "dataset_path": str(ds.path),
           "mode": mode, "mode_reason": job.plan.mode_reason if job.plan else "",
           "input_sha256": prov["input_sha256"], "settings": settings.as_dict(), "seed": seed,
           "versions": prov["versions"], "workers": workers, **run_extra}
    atomic_write_json(out_dir / RUN_FILE, run)
    return post_dir, prov, run


def close_run(out_dir: Path, summary: dict, run: dict, *, wall: float, finished_utc: str, resumed: list,
              computed: list, units: str) -> None:
    """Write a finished job's ``summary.json``, then its ``run.json`` (status "complete"), and say so in one
    line (``units``: what was identified, e.g. "transient(s)")."""
    from bayesdamper.io.outputs import atomic_write_json

    summary["wall_time_s"] = wall
    atomic_write_json(out_dir / SUMMARY_FILE, summary)
    run.update(status="complete", finished_utc=finished_utc, resumed=resumed, computed=computed, wall_time_s=wall)
    atomic_write_json(out_dir / RUN_FILE, run)
    n, n_ok = len(summary["segments"]), summary["n_converged"]
    print(f"identified {n} {units} of {summary['dataset']!r}: {n_ok} converged, {n - n_ok} not"
          + (f" ({len(resumed)} resumed)" if resumed else "") + f"; results in {out_dir}; wall time {wall:.1f} s")


def close_diagnosis(out_dir: Path, diagnosis: dict, text: str, wall: float, quiet: bool) -> None:
    """Add the report text and wall time to a finished diagnosis, write ``diagnosis.json`` (atomically, last)
    and, unless ``quiet``, print the text and where it went."""
    from bayesdamper.io.outputs import atomic_write_json

    diagnosis["report_text"] = text
    diagnosis["wall_time_s"] = wall
    atomic_write_json(out_dir / DIAGNOSIS_FILE, diagnosis)
    if not quiet:
        print(text)
        print(f"diagnosis written to {out_dir / DIAGNOSIS_FILE}; wall time {wall:.1f} s")


def read_finished(path: Path, unit_id: str, fingerprint: str) -> dict | None:
    """The stored posterior of ``unit_id`` (a transient or a whole record) if ``path`` holds it under
    ``fingerprint`` (:func:`bayesdamper.inference.posterior.read_transient`'s dict), else None."""
    from bayesdamper.inference import posterior as post

    if not path.is_file():
        return None
    try:
        s = post.read_transient(path)
    except Exception as err:  # noqa: BLE001 - an unreadable file is sampled again, and said so
        print(f"{path}: unreadable ({type(err).__name__}); sampling {unit_id} again", file=sys.stderr)
        return None
    a = s["attrs"]
    if (a.get("settings_fingerprint") != fingerprint or a.get("segment_id") != unit_id
            or not isinstance(a.get("entry"), dict) or s["band"] is None or s["ls_force"] is None):
        return None
    return s


def _load_finished(path: Path, transient, fingerprint: str) -> WindowResult | None:
    """The stored result of ``transient`` if ``path`` holds it under ``fingerprint``, else None."""
    s = read_finished(path, transient.id, fingerprint)
    if s is None:
        return None
    return WindowResult(s["attrs"]["entry"], s["names"], s["chains"], s["time"], s["force"], s["band"],
                           s["ls_force"])
