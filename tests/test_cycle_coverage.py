"""Coverage of the 90 % intervals of windows of whole cycles on data bayesdamper did not make (slow; run in CI).

The harness is ``tests/record_coverage.py``: data from the independent scipy-Radau generators, identification by
``bayesdamper identify`` in a subprocess with its defaults, every window scored against its record's truth. Every
parameter is estimated in every window, none given: the four flow coefficients, α_V and p_R (and the start's Δp, not
scored).

Two tests, on subsets of the harness's cases chosen by their measured run time (one seed, 2 cores, simulation and
identify; in the comment of each name):

* :func:`test_cycle_window_intervals_cover_the_truth`: small-damper and rig-A sines, a random record, abrupt stops
  and rest, a velocity channel, AR(1) force noise and displacement noise at 100 Hz (~6 min);
* :func:`test_intervals_cover_the_truth_with_displacement_noise_on_slow_sines`: rig-A's slow sines (0.6-1.5 mm/s)
  with 30 µm displacement noise. The input's harmonic part (io/harmonic.py) brings its velocity error to 0.02-0.05 %
  of the peak speed and J_fit / J_truth to 1.00, but what error remains is common to every sample of a window and
  moves the parameters by up to several posterior sds, which the posterior does not carry (1-3 min; a known
  limitation, strict xfail, ``make test-limits``, not in CI).

Left out of CI for time: REST (18 s, 2 windows), SLOW-REST (35 s, 7 windows), SLOW-5MM (5 mm sines, AR(1) φ 0.9,
2 µm ADC step; 238 s, 7 windows), STOP-SMOOTH (476 s), FAST-AR (530 s), FAST-25MM (300 s), SWEEP (350 s),
RANDOM-AR (482 s), FAST-1C (318 s: 18 of 18 intervals hold the truth) and SLOW-1C (80 s: 14 of 18).
``BAYESDAMPER_COVERAGE_SEEDS`` (comma-separated) runs more seeds, ``BAYESDAMPER_COVERAGE_CASES`` other cases in the
first test. Reported (``-s``): the harness's table per case and over all windows, and every window.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from record_coverage import CASES, PARAMS, format_table, run_cases, table

#: The cases of the first test in CI, with one seed's wall time on 2 cores and its windows (39 in all).
CASE_NAMES = tuple(os.environ.get("BAYESDAMPER_COVERAGE_CASES", ",".join((
    "FAST",         # small damper, 4 sines 0.5-5 Hz, 2-15 mm at 500 Hz, white noise: 48 s, 4 windows
    "STOP-ABRUPT",  # stops with a velocity step, then rests: 21 s, 2 windows
    "VELOCITY",     # a measured velocity channel fitted with the displacement: 16 s, 2 windows
    "FAST-100HZ",   # 100 Hz with 30 µm displacement noise: 35 s, 4 windows
    "RANDOM",       # band-limited random motion (rms displacement, rms velocity): 124 s, 3 windows
    "SLOW-W",       # rig-A, 2 mm sines at 0.6-1.5 mm/s, 100 Hz: 32 s, 6 windows
    "SLOW-AR",      # AR(1) force noise φ = 0.95, 10 µm displacement noise, 250 Hz: 26 s, 5 windows
    "SLOW-STOP",    # abrupt stops and 6 s at rest: 29 s, 7 windows
    "SLOW-LVDT",    # the slow sines at 200 Hz, 10 N force noise, 1 µm LVDT noise: ~60 s, 6 windows
))).split(","))
#: The case of the second test: SLOW-W's sines with 30 µm white displacement noise (61-200 s on a loaded machine,
#: 5 windows).
NOISY_INPUT_CASE = "SLOW-DN"
SEEDS = tuple(int(s) for s in os.environ.get("BAYESDAMPER_COVERAGE_SEEDS", "0").split(","))
#: Pooled coverage band over all parameter-window pairs. 6 x 39 pairs; the parameters of one window are correlated
#: (C_L and C_Q of a direction miss together), so count an effective half of them: a binomial sd of 3 % about
#: 0.9. Below: about 3.5 sd (0.80); above: about 2.7 sd (0.98). Above the band means inflated intervals, below it
#: overconfident ones.
POOLED_BAND = (0.80, 0.98)
#: Smallest share of converged windows: not every window determines every parameter well (a ridge of α_V and p_R
#: can keep τ growing past the step budget); the intervals of every window, converged or not, enter the coverage.
MIN_CONVERGED = 0.8
#: Largest J of the fit over J of the truth (eq. (9) against the measured force over the window's raw samples) where
#: the displacement is recorded without noise or ADC step: a fit of seven parameters cannot do worse than the truth
#: except by missing the optimum (measured 0.995-1.000). With displacement noise the model is driven by a
#: reconstructed input and the truth's J is out of reach by what the reconstruction misses (FAST-100HZ 0.991-0.999,
#: SLOW-AR 0.967-0.984, SLOW-DN 0.996-1.042 with the harmonic part); those windows are reported, not bounded.
MAX_J_RATIO = 1.02


def _min_count(n: int) -> int:
    """Smallest per-parameter count of n windows accepted: the binomial(n, 0.9) 0.5 % quantile, so six honest
    parameters fail together less than 3 % of the time."""
    from scipy.stats import binom

    return int(binom.ppf(0.005, n, 0.9))


def _clean_input(case: str) -> bool:
    cs = CASES[case]
    return cs.displacement_sd == 0.0 and cs.displacement_step == 0.0


def _report(rows: list[dict], tables: dict) -> str:
    lines = [f"{len(rows)} windows of {len({r['case'] for r in rows})} case(s) x {len(SEEDS)} seed(s):"]
    for name, tab in tables.items():
        lines.append(f"== {name}\n{format_table(tab)}")
    for r in rows:
        missed = [p for p in PARAMS if p in r and not r[p]]
        lines.append(f"  {r['case']:11s} {r['id']:28s} converged {r['converged']!s:5} J/J_truth {r['J_ratio']:.3f}"
                     + (f"  missed: {', '.join(missed)}" if missed else ""))
    return "\n".join(lines)


def _check_coverage(rows: list[dict]) -> None:
    """Every window of cycles, the converged share, per-parameter counts and the pooled band."""
    assert rows and all(r["kind"] == "cycles" for r in rows)
    tab = table(rows)
    assert tab["converged"] >= MIN_CONVERGED, tab["converged"]
    short = {}
    for p in PARAMS:
        n, hits = tab[p]["n"], tab[p]["hits"]
        assert n == len(rows), p  # every parameter estimated in every window
        if hits < _min_count(n):
            short[p] = f"truth in {hits} of {n} 90 % intervals (need >= {_min_count(n)})"
    assert not short, short
    pooled = np.mean([r[p] for r in rows for p in PARAMS])
    assert POOLED_BAND[0] <= pooled <= POOLED_BAND[1], f"pooled coverage {pooled:.3f} outside {POOLED_BAND}"


@pytest.mark.slow
def test_cycle_window_intervals_cover_the_truth(tmp_path, capsys):
    res = run_cases(CASE_NAMES, SEEDS, tmp_path, workers=2, verbose=False)
    rows = res["rows"]
    with capsys.disabled():
        print("\n" + _report(rows, res["tables"]))
    ratios = {r["id"] + f" ({r['case']})": round(r["J_ratio"], 3) for r in rows if _clean_input(r["case"])}
    if any(_clean_input(c) for c in CASE_NAMES):  # cases chosen by BAYESDAMPER_COVERAGE_CASES may all be noisy
        assert ratios and max(ratios.values()) <= MAX_J_RATIO, {k: v for k, v in ratios.items() if v > MAX_J_RATIO}
    _check_coverage(rows)


@pytest.mark.limits
@pytest.mark.xfail(strict=True, reason=(
    "errors in the input: 30 µm of displacement noise at 100 Hz on 2 mm sines of 0.6-1.5 mm/s. The harmonic part "
    "of the reconstruction leaves 0.15-0.76 µm/s of velocity error (0.02-0.05 % of the peak speed) and J_fit / "
    "J_truth 0.996-1.002, but the displacement's relative noise (1.5 % of the amplitude) is of the order of the "
    "force's (15 N on 1-6 kN), so the error left, common to every sample, moves the parameters by 0.2-9 posterior "
    "sds (α_V by 1.5-9: the MAP refitted under 16 bootstrap replicates of the input): the truth in 21 of 30 90 % "
    "intervals, α_V in 1 of 5 (seed 0). The posterior does not carry the input's uncertainty"))
def test_intervals_cover_the_truth_with_displacement_noise_on_slow_sines(tmp_path, capsys):
    """30 µm of displacement noise at 100 Hz on 2 mm sines of 0.6-1.5 mm/s: the reconstruction averages it over
    every cycle, but the input's relative error is still of the order of the force's. The intervals must still hold
    the truth as often as :func:`test_cycle_window_intervals_cover_the_truth` requires (the input's error is part of
    what a window's posterior must account for)."""
    res = run_cases((NOISY_INPUT_CASE,), SEEDS, tmp_path, workers=2, verbose=False)
    with capsys.disabled():
        print("\n" + _report(res["rows"], res["tables"]))
    _check_coverage(res["rows"])
