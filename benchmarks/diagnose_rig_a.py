"""Benchmark of a cold ``bayesdamper diagnose data/rig-A`` (target: 5 min on 2 cores).

"Cold": a fresh output folder (the baseline is calibrated, not re-used from ``identify``) and an empty
composed-kernel cache (``BAYESDAMPER_KERNEL_CACHE`` set to a new temporary folder, so every combination of
effects is compiled). Prints the wall time, each phase's time from the run's progress lines, the selected
effects and the pooled J before and after.

    python benchmarks/diagnose_rig_a.py [--data data/rig-A] [--out /tmp/bench-diagnose] [--warm]

``--warm`` keeps the kernel cache of earlier runs (``~/.cache/bayesdamper/kernels``).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="data/rig-A")
    ap.add_argument("--out", default="/tmp/bench-diagnose")
    ap.add_argument("--warm", action="store_true", help="keep the composed-kernel cache")
    a = ap.parse_args(argv)
    out = Path(a.out)
    shutil.rmtree(out, ignore_errors=True)
    env = dict(os.environ)
    if not a.warm:
        env["BAYESDAMPER_KERNEL_CACHE"] = tempfile.mkdtemp(prefix="bd-kernels-")
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "bayesdamper", "diagnose", a.data, "--out", str(out)],
                          capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        print(proc.stderr, file=sys.stderr)
        return proc.returncode
    print(f"diagnose {a.data} ({'warm' if a.warm else 'cold'} kernels): {wall:.1f} s wall")
    for line in (proc.stdout + proc.stderr).splitlines():
        if line.startswith("diagnose:") and " in " in line:
            print("  " + line[:150])
    d = json.loads((out / "diagnosis.json").read_text())
    print(f"selected: {', '.join(d['selected']) or 'none'}; pooled J {d['baseline']['J_pooled']:.4f} -> "
          f"{d['final']['J_pooled']:.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
