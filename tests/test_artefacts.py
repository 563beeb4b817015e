"""Stage 1 on triangular tests with load-cell artefacts: an 80 N offset and 40 N of 50 Hz mains hum on a two-state
damper (:func:`record_coverage.make_triangle_artefacts`, an independent generator).

The offset adds +80 N / A_P to the plateau pressure drops of one direction and takes it from the other's, which
turns the backward direction's C_L negative in eq. (4) alone. Stage 1 accepts the data: it holds that coefficient at
0 (the coefficients the windows' model, which has no offset, needs to meet the measured plateaus), and reports the
offset that explains it, estimated with the four coefficients in one linear least-squares fit (identifiable with
plateaus in both directions). Plateaus that eq. (4) fits with non-negative coefficients get eq. (4) alone.
"""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
from record_coverage import make_triangle_artefacts

from bayesdamper.core.params import PAPER_FLOW
from bayesdamper.inference.stage1 import fit_static, fit_with_offset
from bayesdamper.run.check import run_check
from bayesdamper.run.plan import plan_dataset

#: Three speeds [m/s]: both ends of rig-A's range and its middle; three plateaus per direction at least.
SPEEDS = (0.5e-3, 1.0e-3, 1.5e-3)
TRUE_OFFSET_N = 80.0
FLOW_KEYS = ("C_L12", "C_Q12", "C_L21", "C_Q21")
#: Tolerance in standard errors of the five-unknown fit. The standard error of the offset is s sqrt([(X^T X)^-1]_55),
#: s being the plateau points' scatter about the fit: the plateau noise (10 N white noise and what is left of the hum,
#: each averaged over a plateau's hundreds of samples) together with whatever eq. (4) misses on the plateaus of a
#: two-state damper. It is about 4 N here, on n - 5 = 3 degrees of freedom; 5 standard errors: a Student-t with 3
#: dof exceeds that with probability 1.5 %.
TOL_SE = 5.0
#: ... and the offset's standard error must stay below this [N], so that the tolerance cannot swallow the offset.
MAX_OFFSET_SE_N = 10.0


@pytest.fixture(scope="module")
def artefacts(tmp_path_factory):
    folder = make_triangle_artefacts(tmp_path_factory.mktemp("artefacts") / "tri", seed=0, speeds=SPEEDS)
    return folder, plan_dataset(folder, 3.0), json.loads((folder / "truth.json").read_text())


def _clean(plateaus, area):
    """The plateaus with the true offset removed (what the diagnosis' ``load_cell_offset`` refit of stage 1 sees)."""
    return [SimpleNamespace(direction=p.direction, flow_rate=p.flow_rate,
                            pressure_drop=p.pressure_drop - p.direction * TRUE_OFFSET_N / area) for p in plateaus]


def test_stage_one_accepts_the_data_and_reports_the_offset(artefacts):
    folder, plan, truth = artefacts
    static = plan.static
    assert truth["effects"]["offset"]["offset_N"] == TRUE_OFFSET_N
    est = static.coefficients.as_array()  # FlowCoefficients: finite and >= 0, else it raises
    assert np.all(np.isfinite(est)) and np.all(est >= 0)
    assert static.constrained == ["C_L21"]  # eq. (4) alone: the offset made it negative
    offset, offset_se = static.offset_force(plan.ds.damper.piston_area)
    assert 0.0 < offset_se < MAX_OFFSET_SE_N
    assert abs(offset - TRUE_OFFSET_N) < TOL_SE * offset_se, (offset, offset_se)
    # with the offset, the plateaus of a two-state damper at steady flow follow the orifice law: the true coefficients
    off = static.offset
    true = np.array([truth[k] for k in FLOW_KEYS])
    assert np.all(off.coefficients > 0)
    assert np.all(np.abs(off.coefficients - true) < TOL_SE * off.standard_errors[:4]), off.coefficients / true


def test_without_the_offset_stage_one_is_eq4_alone(artefacts):
    """The same plateaus with the true offset removed: eq. (4) alone fits them with positive coefficients and no
    offset is reported; those coefficients agree with the fit that estimated the offset."""
    _, plan, _ = artefacts
    plateaus = [p for s in plan.segs for p in s.plateaus]
    clean = fit_static(_clean(plateaus, plan.ds.damper.piston_area))
    assert clean.constrained == [] and clean.offset is None
    off = plan.static.offset
    assert np.all(np.abs(clean.coefficients.as_array() - off.coefficients) < TOL_SE * off.standard_errors[:4])


def test_check_prints_the_held_coefficient_and_the_offset(artefacts, capsys):
    folder, _, _ = artefacts
    run_check(str(folder), fit=False)
    out = capsys.readouterr().out
    assert "held at 0" in out and "C_L21" in out and "constant force offset F_0 =" in out


def test_offset_larger_than_the_slowest_plateau_force_is_recovered():
    """Plateaus of eq. (4) with PAPER_FLOW and a 300 N offset, down to 0.2 mm/s, where the backward force (about
    180 N) is smaller than the offset, so that plateau's pressure drop is negative: the fit keeps its sign and
    recovers the coefficients and the offset (to the 50 Pa noise's precision)."""
    area, offset = 4.2e-3, 300.0
    rng = np.random.default_rng(1)
    points = {}
    for d, cl, cq in ((1, PAPER_FLOW.laminar_12, PAPER_FLOW.quadratic_12),
                      (-1, PAPER_FLOW.laminar_21, PAPER_FLOW.quadratic_21)):
        q = area * np.linspace(0.2e-3, 1.5e-3, 6)
        points[d] = (q, cl * q + cq * q * q + d * offset / area + 50.0 * rng.standard_normal(q.size))
    assert points[-1][1].min() < 0
    fit = fit_with_offset(points[1], points[-1])
    f0, se = fit.force(area)
    assert fit.explains and se < 1.0 and abs(f0 - offset) < TOL_SE * se
    np.testing.assert_allclose(fit.coefficients, PAPER_FLOW.as_array(), rtol=0.05)


#: Effects the diagnosis may name on this data besides the artefacts: the two-state physics eq. (7) lacks (the
#: absolute-pressure state, the library's ``two_state``).
TWO_STATE_PHYSICS = {"two_state"}


@pytest.fixture(scope="module")
def diagnosed(artefacts, tmp_path_factory):
    """The whole loop on the artefacts' data (about 4 min on 2 cores): diagnosis.json."""
    from bayesdamper.cli import main

    folder, _, _ = artefacts
    out = tmp_path_factory.mktemp("artefacts-diagnosis")
    assert main(["diagnose", str(folder), "--out", str(out), "--workers", "2", "--no-figures"]) == 0
    return json.loads((out / "diagnosis.json").read_text())


@pytest.mark.confusion
def test_the_diagnosis_reports_the_offset(diagnosed, capsys):
    """The diagnosis carries stage 1's finding: the offset near 80 N (within TOL_SE standard errors), the
    coefficient eq. (4) alone had to hold at 0, and a line of the report saying so."""
    d = diagnosed
    with capsys.disabled():
        print(f"\n[artefacts] selected {d['selected']}, J {d['baseline']['J_pooled']:.4f} -> "
              f"{d['final']['J_pooled']:.4f}, {d['wall_time_s']:.0f} s\n{d['report_text']}")
    off = d["stage1_offset_N"]
    assert 0.0 < off["se"] < MAX_OFFSET_SE_N and abs(off["value"] - TRUE_OFFSET_N) < TOL_SE * off["se"], off
    assert off["held_at_zero"] == ["C_L21"]
    assert f"F_0 = {off['value']:.1f}" in d["report_text"]


@pytest.mark.confusion
@pytest.mark.xfail(strict=True, reason=(
    "the loop names the two-state physics and neither artefact: load_cell_offset, started at stage 1's 81.6 N, "
    "gains delta-BIC_eff -601 over two_state alone in round 1 and -998 in round 2 but lowers J by 16 %, under the "
    "20 % a selected effect must add (the 40 N hum, 28 N rms of the 29.9 N plateau noise, is much of what is "
    "left); mains_interference reaches -246 (J -7 %) alone in round 1, and round 2's screen by the grid alone "
    "leaves it at a grid point, (-333, 333) N, far from its optimum near (-39, 6) N"))
def test_the_diagnosis_names_the_offset_and_the_hum(diagnosed):
    """The whole loop on the artefacts' data: both artefacts are findings (the offset as ``load_cell_offset`` near
    80 N, within TOL_SE of its stage-1 standard error or 10 %; the hum as ``mains_interference``), nothing else but the
    two-state physics, and the pooled J at least halved."""
    d = diagnosed
    assert {"load_cell_offset", "mains_interference"} <= set(d["selected"])
    assert set(d["selected"]) <= {"load_cell_offset", "mains_interference"} | TWO_STATE_PHYSICS
    offset = d["selected_params"]["load_cell_offset"]["offset_N"]
    assert abs(offset - TRUE_OFFSET_N) < max(TOL_SE * MAX_OFFSET_SE_N, 0.1 * TRUE_OFFSET_N), offset
    assert d["final"]["J_pooled"] <= 0.5 * d["baseline"]["J_pooled"]
