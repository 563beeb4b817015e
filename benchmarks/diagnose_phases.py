"""Wall time per phase of a cold ``bayesdamper diagnose``, and the profile searches' cost per stage.

"Cold": a fresh output folder, so the baseline is calibrated, not re-used from ``identify``. The composed-kernel
cache (``~/.cache/bayesdamper/kernels``, or ``BAYESDAMPER_KERNEL_CACHE``) is kept warm: compiling every effect
combination is a one-off cost of an installation, not of a diagnosis (``--cold-kernels`` empties it, as
``benchmarks/diagnose_rig_a.py`` does by default). Each data set runs in its own process, one after the other.

Printed per data set: the wall time of every progress phase (from the run's phase summary lines, which a run whose
stderr is not a terminal prints as each phase ends: :mod:`bayesdamper.run.progress`), the total wall and CPU time of
the run, the load average before it (a shared machine's other jobs slow the run), the profile searches' seconds and
evaluations per stage (grid, global starts, refinement, intervals: ``diagnosis.json`` ``search.cost_by_stage``) and
the select-and-refit loop's wall time per step (``search.cost_by_step``), the selected effects, the pooled J before
and after and the findings (parameters on a bound, speeds that got worse).

    python benchmarks/diagnose_phases.py [DATA ...] [--out /tmp/bench-phases] [--workers 2] [--cold-kernels]
                                         [-- EXTRA DIAGNOSE ARGS]

DATA defaults to data/rig-A; give further folders to time them too (``benchmarks/triangular_sets.py`` writes
independent 33-transient sets at 200 Hz, 500 Hz and 1 kHz).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: A phase summary line (:meth:`bayesdamper.run.progress.Phase.summary`): "<name>: [<n> <unit> ]in <t> s[ (<note>)]".
PHASE_LINE = re.compile(r"^(?P<name>.+?): (?:\d+(?:/\d+)? \S+ )?in (?P<s>\d+(?:\.\d+)?) s(?: \((?P<note>.*)\))?$")


def parse_phases(text: str) -> list[tuple[str, float, str]]:
    """``(name, seconds, note)`` of every phase summary line in ``text``, in the order the phases ended."""
    out = []
    for line in text.splitlines():
        m = PHASE_LINE.match(line.strip())
        if m:
            out.append((m["name"], float(m["s"]), m["note"] or ""))
    return out


def run(data: str, out: Path, workers: int, cold_kernels: bool, extra: list[str]) -> int:
    shutil.rmtree(out, ignore_errors=True)
    env = dict(os.environ)
    if cold_kernels:
        env["BAYESDAMPER_KERNEL_CACHE"] = tempfile.mkdtemp(prefix="bd-kernels-")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "bayesdamper", "diagnose", data, "--out", str(out), "--workers",
                           str(workers), *extra], capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (cpu1.ru_utime - cpu0.ru_utime) + (cpu1.ru_stime - cpu0.ru_stime)
    if proc.returncode != 0:
        print(proc.stderr[-4000:], file=sys.stderr)
        return proc.returncode
    kernels = "cold (empty)" if cold_kernels else "warm (kept)"
    print(f"diagnose {data}: {wall:.1f} s wall, {cpu:.1f} s CPU of the run's processes, {workers} workers, "
          f"fresh output folder {out}, kernel cache {kernels}, load average before {load:.2f}")
    phases = parse_phases(proc.stderr + proc.stdout)
    for name, s, note in phases:
        print(f"  {name:<60} {s:8.1f} s" + (f"  ({note[:70]})" if note else ""))
    print(f"  {'phases together':<60} {sum(s for _, s, _ in phases):8.1f} s (the rest of the wall time: start-up, "
          "imports, writing diagnosis.json)")
    path = out / "diagnosis.json"
    if not path.is_file():
        return 0
    d = json.loads(path.read_text())
    cost = (d.get("search") or {}).get("cost_by_stage") or {}
    if cost:
        print("  profile searches by stage (every fit of the run; an evaluation re-fits every window of the stage):")
        for stage in ("grid", "global", "refine", "intervals"):
            if stage in cost:
                c = cost[stage]
                print(f"    {stage:<10} {c['s']:8.1f} s  {c['evaluations']:6d} evaluations  {c['fits']:4d} fits")
    steps = (d.get("search") or {}).get("cost_by_step") or {}
    if steps:
        print("  the select-and-refit loop by step (wall time, the searches run in it, their evaluations):")
        for step, c in sorted(steps.items(), key=lambda kv: -kv[1]["s"]):
            print(f"    {step:<52} {c['s']:8.1f} s  {c['fits']:4d} fits  {c['evaluations']:6d} evaluations")
    print(f"  selected: {', '.join(d.get('selected') or []) or 'none'}; pooled J {d['baseline']['J_pooled']:.4f} -> "
          f"{d['final']['J_pooled']:.4f}; reported wall time {d.get('wall_time_s', float('nan')):.1f} s")
    from bayesdamper.diagnosis.summary import findings_text

    for line in findings_text(d):
        print("  finding: " + line)
    return 0


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[:argv.index("--")] if "--" in argv else argv
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="*", default=["data/rig-A"], help="data-set folder(s) (default data/rig-A)")
    ap.add_argument("--out", default="/tmp/bench-phases", help="parent of the fresh output folders")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--cold-kernels", action="store_true", help="an empty composed-kernel cache")
    a = ap.parse_args(argv)
    rc = 0
    for data in a.data:
        rc = rc or run(data, Path(a.out) / Path(data).name, a.workers, a.cold_kernels, extra)
    return rc


if __name__ == "__main__":
    sys.exit(main())
