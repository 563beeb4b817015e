"""Plateaus whose force still approaches its settled value give stage 1 that value, or are left out
(bayesdamper.inference.settle.settled_plateaus).

Data from tests/independent.py (scipy Radau, no bayesdamper import): rig-A's damper and protocol (rest, a 5 mm
triangle for 1.25 cycles), the paper's flow coefficients. With soft gas (α_V 25, p_R 0.5 MPa) the approach to
the steady force after a start from rest outlasts the first ramp's plateau at the higher speeds; with α_V 60
it does not. Noise white 20 N at 100 Hz (the coverage harness's set W3).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from independent import PAPER_FLOW, RIG_A, make_record, quasi_static_dp, triangle_input

from bayesdamper.core.params import DamperConstants
from bayesdamper.inference.plateau_noise import noise_plateaus, plateau_noise
from bayesdamper.inference.settle import APPROACH_TAU_MAX, SETTLED_T, approach_fit, settled_plateaus
from bayesdamper.inference.stage1 import fit_static
from bayesdamper.io.dataset import TestRecord
from bayesdamper.io.segmentation import segment_record

DAMPER = DamperConstants(RIG_A["area"], RIG_A["v01"], RIG_A["v02"], RIG_A["b0"])
SPEEDS = (0.5e-3, 0.9e-3, 1.3e-3, 1.5e-3)


def _segs(alpha_v: float, p_r: float, seed: int = 4):
    out = []
    for k, v in enumerate(SPEEDS):
        t_first = 1.0 + 0.41 / 100.0
        inp = triangle_input(v, 5e-3, 0.0, t_first, cycles=1.25)
        t, y, f = make_record(inp, t_first + 5 * 5e-3 / v + 0.05, 100.0, RIG_A, PAPER_FLOW, alpha_v, p_r,
                              sd=20.0, seed=[seed, k], rtol=1e-9)
        rec = TestRecord(f"v{k}", Path(f"v{k}.csv"), t, y, f, "0" * 64)
        out.append(segment_record(rec, DAMPER, tmax=3.0))
    return out


def _steady_force(k: int) -> float:
    return RIG_A["area"] * float(quasi_static_dp(RIG_A["area"] * SPEEDS[k], PAPER_FLOW))


def test_soft_gas_first_plateaus_get_their_settled_force_and_stage_one_recovers():
    segs = _segs(25.0, 5e5)
    kept, dropped = settled_plateaus(segs)
    approached = {(p.test, p.index): p for s in kept for p in s.plateaus if p.approach_tau is not None}
    flagged = set(approached) | {(n, i) for n, i, _ in dropped}
    print("approached:", sorted(approached), "dropped:", dropped)
    # the first ramp (index 0) of the fastest test still drifts; no later ramp does
    assert ("v3", 0) in flagged
    assert all(i == 0 for _, i in flagged)
    assert all(tv > SETTLED_T for _, _, tv in dropped)
    for s0, s1 in zip(segs, kept, strict=True):
        assert {p.index for p in s1.unsettled} == {i for n, i, _ in dropped if n == s0.record.name}
        assert len(s1.plateaus) + len(s1.unsettled) == len(s0.plateaus)
    # the mean of that plateau is measurably off the steady force; the approach's settled force removes most of that
    # deficit (eq. (7) with eq. (6) does not approach along one exponential, so not all of it: two thirds asked)
    orig = {(p.test, p.index): p for s in segs for p in s.plateaus}
    p = orig[("v3", 0)]
    assert _steady_force(3) - p.pressure_drop * RIG_A["area"] > 4 * 20.0 / math.sqrt(p.n)
    assert approached, "no plateau got an approach"
    for key, q in approached.items():
        steady = _steady_force(int(key[0][1:]))
        before = abs(orig[key].pressure_drop * RIG_A["area"] - steady)
        assert abs(q.pressure_drop * RIG_A["area"] - steady) < before / 3.0, key
        assert 0.0 < q.approach_tau <= APPROACH_TAU_MAX * (q.t_end - q.t_start)
    # stage 1 on those settled forces: its 99 % intervals hold the true coefficients
    fit = fit_static([p for s in kept for p in s.plateaus])
    iv = fit.intervals(0.99)
    for name, true in zip(("CL12", "CQ12", "CL21", "CQ21"), PAPER_FLOW, strict=True):
        assert iv[name]["lo"] <= true <= iv[name]["hi"], name


def test_an_approach_is_extrapolated_and_a_line_is_not():
    """approach_fit on a known exponential approach in AR(1) noise (φ 0.5, σ_e 10 N, 400 samples over 2 s, τ 0.6 s,
    250 N still to go at the start): the settled force within 5 of its standard errors (the constant's least-squares
    standard error at the true τ, AR(1)-inflated); a pure line has no end within the plateau and gives None."""
    rng = np.random.default_rng(7)
    t = np.linspace(0.0, 2.0, 400)
    e = np.zeros(t.size)
    for k in range(1, t.size):
        e[k] = 0.5 * e[k - 1] + rng.normal(0.0, 10.0)
    f = 1000.0 - 250.0 * np.exp(-t / 0.6) + e
    settled, tau, resid = approach_fit(t, f)
    design = np.column_stack([np.ones_like(t), np.exp(-t / 0.6)])
    se = math.sqrt(np.linalg.inv(design.T @ design)[0, 0]) * (10.0 / math.sqrt(1 - 0.25)) * math.sqrt(1.5 / 0.5)
    assert abs(settled - 1000.0) < 5.0 * se, (settled, se)
    assert 0.3 < tau < 1.2
    assert resid.shape == t.shape
    assert approach_fit(t, 1000.0 + 50.0 * t + e) is None


def test_the_noise_comes_from_the_settled_plateaus():
    """An approached plateau's samples are drift, not noise: the plateaus' AR(1) noise leaves it out."""
    segs = _segs(25.0, 5e5)
    kept, _ = settled_plateaus(segs)
    settled = [(r.name, p.index) for r, p in noise_plateaus(kept)]
    approached = [(p.test, p.index) for s in kept for p in s.plateaus if p.approach_tau is not None]
    assert approached and not set(approached) & set(settled)
    assert len(settled) == sum(len(s.plateaus) for s in kept) - len(approached)
    # with the drifting plateau's samples the noise reads as more correlated
    assert plateau_noise(kept).phi < plateau_noise(segs).phi


@pytest.mark.parametrize("seed", [1, 2])
def test_settled_plateaus_are_kept(seed):
    segs = _segs(60.0, 1.5e5, seed)
    kept, dropped = settled_plateaus(segs)
    assert dropped == []
    assert all(s.unsettled == () for s in kept)
    assert all(p.approach_tau is None for s in kept for p in s.plateaus)
    assert sum(len(s.plateaus) for s in kept) == sum(len(s.plateaus) for s in segs)
    assert np.all([len(s.plateaus) == 3 for s in kept])
