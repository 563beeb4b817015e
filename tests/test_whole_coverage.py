"""Coverage of whole-record 90 % intervals on data bayesdamper did not make (slow; run in CI).

Each replicate is one record made by the independent scipy-Radau generator (``tests/independent.py``,
rtol 1e-9, first sample off any grid), written as CSV, read back and identified with the CLI's defaults
(AR(1) noise model, whole-record sampler and convergence rules). The replicates sweep:

* input: sine 0.5 Hz / 15 mm, sine 1 Hz / 10 mm, sine 2 Hz / 5 mm, random-phase multisine 0.3-3 Hz
  (8 tones, 4 mm RMS);
* sample rate: 100, 250, 500 Hz (the 500 Hz records are decimated by the record-window rule);
* noise: white, or AR(1) with lag-1 correlation 0.8 (marginal sd 2 N either way);
* truth: α_V log-uniform on [15, 80], p_R log-uniform on [0.15, 0.6] MPa, each flow coefficient the small
  damper's (``SMALL_FLOW``) times a log-uniform factor in [e^-0.3, e^0.3] — every parameter estimated,
  none given.

Reported (``-s``): coverage per parameter and per noise type, the median relative 90 % width, convergence.
``BAYESDAMPER_COVERAGE_N`` sets the number of replicates (default ``N_REPLICATES``, for CI's time budget;
the README's table is of 30).
"""

from __future__ import annotations

import math
import os
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from independent import SMALL, SMALL_FLOW, make_record, multisine_input, sine_input, write_dataset

#: Replicates (every input, rate and noise type appear in all combinations of pairs).
N_REPLICATES = int(os.environ.get("BAYESDAMPER_COVERAGE_N", "14"))
NAMES = ("C_L12", "C_Q12", "C_L21", "C_Q21", "alpha_V", "p_R_Pa")
INPUTS = ("sine 0.5 Hz", "sine 1 Hz", "sine 2 Hz", "multisine")
RATES = (100.0, 250.0, 500.0)
DURATION = 5.0  # [s]
NOISE_SD = 2.0  # [N], about 1 % of the forces
PHI = 0.8
#: Pooled coverage band over all parameter-replicate pairs. With 6 x 20 = 120 pairs the binomial sd is
#: 2.7 % if they were independent (CI runs 14 replicates since issue 9 added its slow tests: 84 pairs,
#: 3.3 %); the parameters of one replicate are correlated (C_L and C_Q of a
#: direction miss together), so about 2.5 sd of an effective 60 pairs below 0.9: 0.80; above, at least
#: two misses in 120 (0.99). Above the band means inflated intervals, below it overconfident ones.
POOLED_BAND = (0.80, 0.99)
#: Smallest share of converged records. Not every record determines every parameter well: a 0.5 Hz sine
#: sampled at 100 Hz (2 of the first 14 or 20 replicates) leaves α_V and p_R on a curved ridge whose τ keeps
#: growing past 100 steps, and the rules report "not converged" at the step budget rather than accept
#: it. 0.8 allows that cell and two more (a 30-record run had 3 unconverged: that cell and a 1 Hz sine at
#: 250 Hz with AR(1) noise; the constant was chosen after it, and is said so). The intervals of every record,
#: converged or not, enter the coverage (they are what the report shows).
MIN_CONVERGED = 0.8


def _min_count(n: int) -> int:
    """Smallest per-parameter count of n replicates accepted: the binomial(n, 0.9) 0.5 % quantile, so six
    honest parameters fail together less than 3 % of the time."""
    from scipy.stats import binom

    return int(binom.ppf(0.005, n, 0.9))


def design(k: int) -> dict:
    """The k-th replicate: input, rate, noise and truth (seeded by k)."""
    rng = np.random.default_rng(10_000 + k)
    return {
        "k": k,
        "input": INPUTS[(k // 2) % len(INPUTS)],
        "rate": RATES[k % len(RATES)],
        "noise": "white" if k % 2 == 0 else "ar1",
        "alpha_V": float(np.exp(rng.uniform(math.log(15.0), math.log(80.0)))),
        "p_R_Pa": float(np.exp(rng.uniform(math.log(1.5e5), math.log(6e5)))),
        "flow": tuple(float(c) for c in np.asarray(SMALL_FLOW) * np.exp(rng.uniform(-0.3, 0.3, 4))),
    }


def _input(name: str, k: int):
    if name == "multisine":
        return multisine_input(0.004, 0.3, 3.0, 8, seed=k)
    freq = float(name.split()[1])
    return sine_input({0.5: 0.015, 1.0: 0.010, 2.0: 0.005}[freq], freq)


def replicate(k: int) -> dict:
    """Make, write, read and identify the k-th replicate; per parameter: covered, relative 90 % width."""
    from bayesdamper.core.params import DamperConstants
    from bayesdamper.inference.stage2 import StageTwoSettings
    from bayesdamper.inference.whole_stage import identify_record
    from bayesdamper.io.dataset import load_record
    from bayesdamper.io.recordkind import classify_record
    from bayesdamper.io.wholerecord import record_window

    d = design(k)
    rec = make_record(_input(d["input"], k), DURATION, d["rate"], SMALL, d["flow"], d["alpha_V"], d["p_R_Pa"],
                      noise=d["noise"], sd=NOISE_SD, phi=PHI, seed=k, t_start=0.0013 + 1.7e-4 * k, rtol=1e-9)
    with tempfile.TemporaryDirectory() as tmp:
        write_dataset(tmp, {"rec": rec}, SMALL, "coverage")
        r = load_record(Path(tmp) / "rec.csv", tmax=None)
    kind = classify_record(r)
    w = record_window(r, kind=kind.kind, description=kind.description)
    damper = DamperConstants(SMALL["area"], SMALL["v01"], SMALL["v02"], SMALL["b0"], "small")
    e = identify_record(w, damper, StageTwoSettings(), seed=k).entry
    truth = dict(zip(NAMES, (*d["flow"], d["alpha_V"], d["p_R_Pa"]), strict=True))
    return {**d, "converged": e["converged"], "kind": kind.kind, "wall_s": e["wall_s"],
            "covered": {n: bool(e[n]["lo"] <= truth[n] <= e[n]["hi"]) for n in NAMES},
            "rel_width": {n: (e[n]["hi"] - e[n]["lo"]) / truth[n] for n in NAMES}}


def coverage_table(results: list[dict]) -> str:
    lines = [f"{'parameter':9} {'all':>6} {'white':>6} {'ar1':>6} {'median 90% width':>18}"]
    for n in NAMES:
        row = [np.mean([r["covered"][n] for r in results if noise in (None, r["noise"])])
               for noise in (None, "white", "ar1")]
        width = np.median([r["rel_width"][n] for r in results])
        lines.append(f"{n:9} {row[0]:6.2f} {row[1]:6.2f} {row[2]:6.2f} {100 * width:17.2f}%")
    for inp in INPUTS:
        sel = [r for r in results if r["input"] == inp]
        lines.append(f"{inp}: {np.mean([np.mean(list(r['covered'].values())) for r in sel]):.2f} of "
                     f"{6 * len(sel)} pairs")
    return "\n".join(lines)


@pytest.fixture(scope="module")
def results():
    with ProcessPoolExecutor(2) as ex:
        return list(ex.map(replicate, range(N_REPLICATES)))


@pytest.mark.slow
def test_whole_record_intervals_cover_the_truth(results):
    print(f"\n{len(results)} whole records from the independent generator:\n{coverage_table(results)}")
    for r in results:
        missed = [n for n in NAMES if not r["covered"][n]]
        print(f"  k={r['k']:2d} {r['input']:12} {r['rate']:5.0f} Hz {r['noise']:5} converged {r['converged']!s:5} "
              f"{r['wall_s']:5.0f} s" + (f"  missed: {', '.join(missed)}" if missed else ""))
    print(f"converged {np.mean([r['converged'] for r in results]):.2f}, "
          f"median wall {np.median([r['wall_s'] for r in results]):.0f} s per record")
    assert all(r["kind"] in ("sine", "other") for r in results)
    assert np.mean([r["converged"] for r in results]) >= MIN_CONVERGED
    n_min = _min_count(len(results))
    for n in NAMES:
        count = sum(r["covered"][n] for r in results)
        assert count >= n_min, f"{n}: truth in {count} of {len(results)} 90 % intervals (need >= {n_min})"
    pooled = np.mean([v for r in results for v in r["covered"].values()])
    assert POOLED_BAND[0] <= pooled <= POOLED_BAND[1], f"pooled coverage {pooled:.3f} outside {POOLED_BAND}"
