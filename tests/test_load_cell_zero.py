"""The force channel's zero measured on the plateaus' intercepts, and its removal before a diagnosis."""

import shutil
from types import SimpleNamespace

import numpy as np
import pytest

from bayesdamper.core.params import PAPER_FLOW
from bayesdamper.diagnosis.summary import zero_lines
from bayesdamper.inference.stage1 import ZERO_MIN_PLATEAUS, fit_with_offset, plateau_zero
from bayesdamper.run.plan import plan_dataset, zeroed

AREA = 4.2e-3
SPEEDS = np.linspace(0.5e-3, 1.5e-3, 11)
#: Plateau scatter [Pa] typical of rig-A (the stage-1 tests' value).
NOISE_PA = 2.0e3
#: Replicates of the coverage check: the binomial sd of a coverage near 0.88 is 1.6 %.
N_REPLICATES = 400
#: Expected coverage of offset ± 1.645 se: the ratio is about Student's t with 16 degrees of freedom (two directions'
#: intercepts, each with 11 plateaus and 3 coefficients: Welch-Satterthwaite for equal variances), P(|t_16| < 1.645)
#: = 0.881; the band is ± 3 binomial sd.
COVERAGE_BAND = (0.83, 0.93)


def _plateaus(rng, offset=0.0, friction=0.0, noise=NOISE_PA, speeds=SPEEDS):
    """Both directions' plateaus (signed pressure drop per direction) of eq. (4) with an offset F_0 of the force
    channel (adds d F_0 / A_P) and a Coulomb friction (adds f / A_P to both)."""
    out = []
    for direction, cl, cq in ((1, PAPER_FLOW.laminar_12, PAPER_FLOW.quadratic_12),
                              (-1, PAPER_FLOW.laminar_21, PAPER_FLOW.quadratic_21)):
        q = AREA * speeds
        dp = cl * q + cq * q * q + (friction + direction * offset) / AREA + noise * rng.standard_normal(q.size)
        out += [SimpleNamespace(direction=direction, flow_rate=qi, pressure_drop=di)
                for qi, di in zip(q, dp, strict=True)]
    return out


@pytest.mark.parametrize("offset, friction", [(-150.0, 200.0), (120.0, 0.0), (0.0, 300.0), (80.0, -50.0)])
def test_noise_free_plateaus_give_the_offset_and_the_friction_exactly(offset, friction):
    z = plateau_zero(_plateaus(np.random.default_rng(0), offset, friction, noise=0.0), AREA)
    assert z.offset_N == pytest.approx(offset, abs=1e-6 * 300)
    assert z.friction_N == pytest.approx(friction, abs=1e-6 * 300)
    assert z.measured == (offset != 0.0)


def test_the_common_offset_fit_takes_a_friction_for_part_of_an_offset_where_the_intercepts_do_not():
    """With the paper's direction-dependent coefficients, a Coulomb friction and plateaus at different speeds in the
    two directions (a plateau left out where its force had not settled), the fit of eq. (4) with a common offset and
    no friction term is biased: the friction no longer projects out of it. The intercepts' difference is not: a
    force common to both directions cancels in it whatever speeds each direction has."""
    offset, friction = 150.0, 290.0
    plateaus = [p for p in _plateaus(np.random.default_rng(5), offset, friction, noise=0.0)
                if not (p.direction == 1 and p.flow_rate > AREA * 1.15e-3)]
    z = plateau_zero(plateaus, AREA)
    common = fit_with_offset(*[(np.array([p.flow_rate for p in plateaus if p.direction == d]),
                                np.array([p.pressure_drop for p in plateaus if p.direction == d])) for d in (1, -1)])
    assert z.offset_N == pytest.approx(offset, abs=1e-6 * 300)
    assert abs(common.force(AREA)[0] - offset) > 10.0


def test_the_offsets_standard_error_is_honest():
    """Nominal ± 1.645 se intervals of the offset cover the truth at the rate Student's t gives (COVERAGE_BAND)."""
    rng = np.random.default_rng(2)
    hits = 0
    for _ in range(N_REPLICATES):
        z = plateau_zero(_plateaus(rng, offset=-60.0, friction=100.0), AREA)
        hits += abs(z.offset_N + 60.0) <= 1.645 * z.offset_se_N
    assert COVERAGE_BAND[0] < hits / N_REPLICATES < COVERAGE_BAND[1], hits / N_REPLICATES


def test_too_few_plateaus_or_one_flow_rate_measure_nothing():
    rng = np.random.default_rng(3)
    few = [p for p in _plateaus(rng) if p.direction == 1] + \
        [p for p in _plateaus(rng) if p.direction == -1][:ZERO_MIN_PLATEAUS - 1]
    assert plateau_zero(few, AREA) is None
    assert plateau_zero(_plateaus(rng, speeds=np.full(6, 1e-3)), AREA) is None


def _copy_with_offset(src, dst, offset):
    dst.mkdir()
    shutil.copy(src / "damper.toml", dst / "damper.toml")
    for f in sorted(src.glob("*.csv")):
        lines = f.read_text().splitlines()
        out = [lines[0]] + [",".join([*ln.split(",")[:2], repr(float(ln.split(",")[2]) + offset)]) for ln in lines[1:]]
        (dst / f.name).write_text("\n".join(out) + "\n")


def test_an_unzeroed_copy_of_rig_a_is_zeroed_back_and_rig_a_itself_is_left_alone(tmp_path):
    """rig-A's plateaus measure no zero (its offset within 3 se of 0): the plan is returned as it was. A copy with
    120 N added to every force is planned again with the measured zero removed: the same offset within 3 se of
    rig-A's own plus 120 N, and every window's force the original's within that difference."""
    from pathlib import Path

    rig = Path(__file__).resolve().parents[1] / "data" / "rig-A"
    plan = plan_dataset(rig, 3.0)
    same = zeroed(plan, 3.0)
    assert not same.zero_removed and same.windows is plan.windows and not same.zero.measured
    _copy_with_offset(rig, tmp_path / "unzeroed", 120.0)
    shifted = zeroed(plan_dataset(tmp_path / "unzeroed", 3.0), 3.0)
    z = shifted.zero
    assert shifted.zero_removed and z.measured
    assert abs(z.offset_N - (same.zero.offset_N + 120.0)) < 3 * z.offset_se_N
    assert abs(z.friction_N - same.zero.friction_N) < 3 * z.friction_se_N
    assert [w.id for w in shifted.windows] == [w.id for w in plan.windows]
    for a, b in zip(shifted.windows, plan.windows, strict=True):
        np.testing.assert_allclose(a.force - b.force, 120.0 - z.offset_N, atol=1e-6)
    assert shifted.as_dict()["load_cell_zero"]["removed"] is True


def test_the_report_says_a_removed_zero_and_nothing_of_one_left_in():
    zero = {"offset_N": -131.2, "offset_se_N": 6.8, "friction_N": -3.2, "friction_se_N": 6.8, "measured": True,
            "removed": True}
    (line,) = zero_lines({"load_cell_zero_N": zero})
    assert "F_0 = -131.2 ± 6.8 N" in line and "removed" in line
    assert zero_lines({"load_cell_zero_N": {**zero, "measured": False, "removed": False}}) == []
    assert zero_lines({}) == []
