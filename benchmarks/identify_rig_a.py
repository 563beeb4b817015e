"""Benchmark and fit check of ``bayesdamper identify data/rig-A``.

Runs the command as a user would (figures included, all cores), prints its wall time, and per transient the
eq. (9) J of the posterior-predictive median force against the paper's Nelder-Mead J, the posterior of α_V
and p_R, σ_w/σ (how much model error widened the intervals), τ, steps and the seconds it took.

    python benchmarks/identify_rig_a.py [--data data/rig-A] [--out /tmp/bench-rig-a] [--extra "--conditional"]

The issue's rule: J within 10 % of Nelder-Mead's on every transient, and the whole command no more than 1.5×
slower than before (compare two runs of this script, or time the command with farm-bench).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="data/rig-A")
    ap.add_argument("--out", default="/tmp/bench-rig-a")
    ap.add_argument("--extra", default="", help="more identify options, space separated")
    a = ap.parse_args(argv)
    out = Path(a.out)
    if out.exists():
        shutil.rmtree(out)
    cmd = [sys.executable, "-m", "bayesdamper", "identify", a.data, "--out", str(out), *a.extra.split()]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True)
    wall = time.perf_counter() - t0
    summ = json.loads((out / "summary.json").read_text())
    segs = summ["segments"]
    print(f"identify {a.data} {a.extra}: {wall:.1f} s wall, {len(segs)} transients, "
          f"{sum(e['converged'] for e in segs)} converged")
    print(f"{'transient':18s} {'kind':8s} {'J':>7s} {'J_NM':>7s} {'ratio':>6s} {'alpha_V [90 %]':>24s} "
          f"{'p_R kPa [90 %]':>24s} {'sw/s':>5s} {'tau':>5s} {'steps':>5s} {'s':>5s}")
    worst = 0.0
    for e in segs:
        ratio = e["J"] / e["ls"]["J"]
        worst = max(worst, ratio)
        a_, p_ = e["alpha_V"], e["p_R_Pa"]
        print(f"{e['id']:18s} {e['kind']:8s} {e['J']:7.4f} {e['ls']['J']:7.4f} {ratio:6.3f} "
              f"{a_['median']:7.2f} [{a_['lo']:6.2f}, {a_['hi']:6.2f}] "
              f"{p_['median'] / 1e3:7.1f} [{p_['lo'] / 1e3:6.1f}, {p_['hi'] / 1e3:6.1f}] "
              f"{e.get('window_scale_ratio', float('nan')):5.1f} {max(e['tau'].values()):5.1f} {e['n_steps']:5d} "
              f"{e['wall_s']:5.1f}")
    n_bad = sum(e["J"] > 1.1 * e["ls"]["J"] for e in segs)
    print(f"largest J / J_NM {worst:.3f}; transients with J > 1.1 J_NM: {n_bad}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
