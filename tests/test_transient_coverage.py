"""Honest two-stage intervals on data bayesdamper did not make (slow).

Every data set comes from tests/independent.py (scipy Radau, eq. (7) or the two-state eq. (1) re-derived from
the paper; no bayesdamper import), with the first step off the sample grid and different per record. The
harness (tests/transient_coverage.py) writes rig-A-protocol data sets and runs ``bayesdamper identify``
through its command line: stage 1 estimates the flow coefficients, the plateaus the noise.

Rules and their tolerances
--------------------------
* Coverage per parameter and kind of step, pooled over the sets: at least the binomial(n, 0.9) 0.5 %
  quantile (a false alarm on a calibrated method in < 0.5 % per cell, < 2 % over the four cells).
* Width honesty, so that coverage is not bought by inflation: the z-scores (posterior median − truth) /
  (90 % half-width / 1.645) in log units have sd within [0.7, 1.35] (n = 144: the sd of a sample sd is 0.06,
  so the band is > 5 of them from 1 on either side, room for the non-Gaussian shape of starts from rest),
  and the pooled coverage is within [0.83, 0.97] (binomial 99.5 % band for n = 144 is [0.84, 0.96]).
* The conditional stage 2 (the paper's; ``--conditional``) on the set where it fails: at most
  2 of 6 starts from rest hold the true α_V (it held 0 of 6): the harness can fail.
* Misspecified data (two-state model): the intervals are judged against the pseudo-true value: the eq. (9) optimum
  of the noise-free record (residual weighted by the noise colour) at the true step force and flow coefficients,
  which is what the cut stage 2 aims at (White 1982: the maximiser of its expected log-likelihood), computed with
  the independent solver (:func:`transient_coverage.pseudo_true`); they must hold it at least at the binomial
  0.5 % quantile of 90 %, white (M1) and AR(1) noise (M2).
* SBC across a prior box: ranks of the truth among 99 posterior draws, pooled over replicates, uniform by a
  χ² test on 10 bins at p > 0.001 per parameter.
"""

from __future__ import annotations

import math
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from independent import PAPER_FLOW, RIG_A, force_noise, simulate, triangle_input
from scipy import stats
from transient_coverage import PARAMS, SETS, make_set, run_identify, score

pytestmark = pytest.mark.slow

#: The coverage sets of CI: 100 Hz white, 200 Hz white with a soft gas (p_R 30 kPa: the issue's worst), 200 Hz
#: and 1 kHz AR(1) with φ = 0.97. Seed 11: not one of the seeds of the offline tables (0-5).
CI_SETS = ("W3", "W2", "C1", "C3")
SEED = 11


def _lower(n: int) -> int:
    """Smallest hit count accepted for n intervals of nominal 90 %: the binomial 0.5 % quantile."""
    return int(stats.binom.ppf(0.005, n, 0.9))


def _rows(tmp_path: Path, names, seed: int, extra=()) -> list[dict]:
    rows = []
    for name in names:
        folder = tmp_path / name
        data = make_set(SETS[name], folder / "data", seed)
        summ = run_identify(data, folder / "out", seed, tuple(extra))
        pj = folder / "pseudo_true.json"
        import json

        for r in score(summ, SETS[name], json.loads(pj.read_text()) if pj.exists() else None):
            r["set"] = name
            rows.append(r)
    return rows


def _table(rows) -> str:
    lines = []
    for p in PARAMS:
        for kind in ("initial", "reversal"):
            sel = [r for r in rows if r["kind"] == kind]
            lines.append(f"{p:8s} {kind:9s} {sum(r[p] for r in sel):3d}/{len(sel):3d} "
                         f"width {100 * np.median([r[p + '_width'] for r in sel]):.2f} %")
    return "\n".join(lines)


def test_two_stage_intervals_cover_independent_truth(tmp_path):
    rows = _rows(tmp_path, CI_SETS, SEED)
    print("\n" + _table(rows))
    assert all(r["converged"] for r in rows)
    for p in PARAMS:
        for kind in ("initial", "reversal"):
            sel = [r for r in rows if r["kind"] == kind]
            assert sum(r[p] for r in sel) >= _lower(len(sel)), (p, kind)
    z = np.array([r[p + "_z"] for r in rows for p in PARAMS])
    cover = np.mean([r[p] for r in rows for p in PARAMS])
    print(f"z sd {z.std():.2f}, pooled coverage {cover:.3f}")
    assert 0.7 <= z.std() <= 1.35
    assert 0.83 <= cover <= 0.97
    # the posterior-predictive median fits as well as the paper's point estimate (rig-A's rule), where
    # the noise is white; under AR(1) noise the likelihood weights the residual by its colour (generalised
    # least squares), so its optimum is not eq. (9)'s and J may exceed Nelder-Mead's (offline, φ = 0.97 at
    # 200 Hz: up to 1.08), by design
    assert max(r["J_ratio"] for r in rows if SETS[r["set"]].noise == "white") <= 1.1


@pytest.mark.extended  # a demonstration of the paper's stage 2, not a guard of the product: make test-extended
def test_conditional_stage_two_misses_starts_from_rest(tmp_path):
    """The cause, shown: conditioned on the step force and stage 1 (the paper's stage 2), the soft-gas set."""
    rows = _rows(tmp_path, ("W2",), SEED, ("--conditional", "--noise-model", "ar1"))
    init = [r for r in rows if r["kind"] == "initial"]
    print("\nconditional:\n" + _table(rows))
    assert sum(r["alpha_V"] for r in init) <= 2


@pytest.mark.extended  # 4-5 min on 2 cores: outside CI for its time budget, make test-extended
def test_misspecified_intervals_cover_the_pseudo_true_value(tmp_path):
    """Two-state data (eq. (1) without accumulator): what the intervals promise is the pseudo-true value, the
    eq. (9) optimum of the noise-free record weighted by the noise colour, at the true step force and flow
    coefficients (the cut keeps those where their own data put them). The window's noise scale is estimated from
    the window, so model error widens them."""
    rows = _rows(tmp_path, ("M1", "M2"), SEED)
    print("\nmisspecified (pseudo-true):\n" + _table(rows))
    for p in PARAMS:
        assert sum(r[p] for r in rows) >= _lower(len(rows)), p
    assert max(r["J_ratio"] for r in rows) <= 1.1


# ------------------------------------------------------------------------------------------------- SBC
#: SBC prior box (log-uniform), also the sampler's prior: the paper's range of α_V and p_R, widened.
SBC_ALPHA = (10.0, 300.0)
SBC_P_R = (3.0e4, 1.0e6)
SBC_REPLICATES = 40
SBC_DRAWS = 99


def _sbc_replicate(k: int) -> list[tuple[int, int]]:
    """One draw from the prior, one independent record (rest, a ramp, a reversal), the joint posterior of
    both transients; returns the ranks of the true (α_V, p_R) among 99 posterior draws, per transient."""
    from bayesdamper.core.params import DamperConstants, FlowCoefficients
    from bayesdamper.inference import joint
    from bayesdamper.inference.identify import identify_window
    from bayesdamper.inference.stage2 import StageTwoSettings
    from bayesdamper.io.dataset import TestRecord
    from bayesdamper.io.segmentation import segment_record

    rng = np.random.default_rng([2026, k])
    alpha = math.exp(rng.uniform(*np.log(SBC_ALPHA)))
    p_r = math.exp(rng.uniform(*np.log(SBC_P_R)))
    rate = float(rng.choice([100.0, 200.0, 500.0, 1000.0]))
    phi = float(rng.choice([0.0, 0.9, 0.97]))
    sd = float(rng.uniform(8.0, 25.0))
    speed = float(rng.uniform(0.8e-3, 1.5e-3))
    # flow coefficients drawn from the prior the posterior uses (stage 1's posterior of a 6-speed test)
    m = np.array(PAPER_FLOW)
    rel = np.array([0.006, 0.008, 0.017, 0.008])
    corr = np.array([[1.0, -0.97], [-0.97, 1.0]])
    cov = np.zeros((4, 4))
    cov[:2, :2] = np.outer(rel[:2] * m[:2], rel[:2] * m[:2]) * corr
    cov[2:, 2:] = np.outer(rel[2:] * m[2:], rel[2:] * m[2:]) * corr
    noise = joint.PlateauNoise(phi, sd * math.sqrt(1 - phi * phi), 10_000, 10)
    prior = joint.StageOnePrior(m, cov, np.array([np.inf, np.inf]), noise)  # dof ∞: the Gaussian itself
    flow = rng.multivariate_normal(m, prior.prior_cov)
    t_first = 1.0 + rng.uniform() / rate
    inp = triangle_input(speed, 5e-3, 0.0, t_first, cycles=0.5)
    t = np.arange(int(round((t_first + 2 * 5e-3 / speed + 0.05) * rate))) / rate
    f = simulate(inp, t, RIG_A, flow, alpha, p_r, rtol=1e-9)
    f = f + force_noise(t.size, sd, phi, [2026, k, 1])
    damper = DamperConstants(RIG_A["area"], RIG_A["v01"], RIG_A["v02"], RIG_A["b0"])
    rec = TestRecord("sbc", Path("sbc.csv"), t, inp.displacement(t), f, "0" * 64)
    seg = segment_record(rec, damper, tmax=3.0)
    # the reported (cut) posterior. SBC's ranks are uniform for the exact Bayesian posterior; the cut is wider
    # than that where the window informs Δp0 and the flow coefficients (ranks then bunch in the middle), so the
    # χ² rule also bounds how much the cut over-disperses. Measured, 40 replicates: cut α_V p = 0.259, central
    # 90 % 0.938, p_R p = 0.663, 0.912; the joint posterior (--coupling joint) α_V p = 0.152, p_R p = 0.812.
    settings = StageTwoSettings(alpha_v_bounds=SBC_ALPHA, p_r_bounds=SBC_P_R)
    out = []
    for tr in seg.transients:
        res = identify_window(tr, damper, FlowCoefficients(*m), settings, k, prior=prior)
        draws = res.chains.reshape(-1, res.chains.shape[-1])
        pick = np.random.default_rng([k, tr.index]).choice(len(draws), SBC_DRAWS, replace=False)
        d = draws[pick]
        out.append((int(np.sum(d[:, 0] < alpha)), int(np.sum(d[:, 1] < p_r)), bool(res.entry["converged"])))
    return out


def test_simulation_based_calibration():
    """Talts et al. (2018): if the posterior is right, the rank of a prior draw among posterior draws of its
    own data is uniform on 0..99. 40 replicates × 2 transients = 80 ranks per parameter, 10 bins."""
    with ProcessPoolExecutor(2) as ex:
        res = [r for rep in ex.map(_sbc_replicate, range(SBC_REPLICATES)) for r in rep]
    ranks = np.array([(a, p) for a, p, _ in res])
    conv = np.mean([c for *_, c in res])
    for j, name in enumerate(PARAMS):
        counts = np.bincount(ranks[:, j] * 10 // (SBC_DRAWS + 1), minlength=10)
        p = stats.chisquare(counts).pvalue
        inner = np.mean((ranks[:, j] >= 5) & (ranks[:, j] < 95))  # the central 90 % of the posterior
        print(f"SBC {name}: bins {counts.tolist()}, χ² p = {p:.3f}, truth inside central 90 %: {inner:.3f}")
        assert p > 0.001
        assert inner >= _lower(len(ranks)) / len(ranks)
    print(f"converged {conv:.3f}")
    assert conv >= 0.9
