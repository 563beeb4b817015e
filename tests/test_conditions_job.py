"""One damper at three charge pressures, diagnosed together, on data bayesdamper did not make (slow).

The data (tests/record_coverage.py ``make_conditions``, the scipy-Radau eq. (7) of tests/independent.py with the
effects added by the generator's own code): a small gas-charged damper at 0.25, 0.5 and 1 MPa; a gas force on the
rod p_c A_rod + k y (38.5, 77 and 154 N of offset, the charge-dependent part) and a rig effect the same at every
charge (Coulomb friction 30 N, tanh(v / 1 mm/s)); sines that start at speed, 200 Hz, 2 N force noise, 5 µm
displacement noise. The joint diagnosis must give the damper one explanation (friction and a force offset) at
every condition, and recover the offset's trend with the charge: its slope is the rod area A_rod.
"""

from __future__ import annotations

import json
import math

import pytest
from record_coverage import ROD_AREA, make_conditions

from bayesdamper.cli import main
from bayesdamper.report.html import render_report

CASES = {
    # CI: the effects that act as a force at the output (the fast path: friction, offset, gas spring, seal friction)
    # and a 400-step sampling budget (the assertions read least-squares optima and posterior medians, not
    # convergence); about 4 min on 2 cores
    "ci": {"effects": "friction,load_cell_offset,gas_spring,seal_friction", "max_steps": 400,
           "marks": pytest.mark.slow},
    # every effect of the library, the unnamed ones included, the default sampling budget (about 18 min)
    "library": {"effects": None, "max_steps": None, "marks": pytest.mark.confusion},
}
#: Two sines per condition, 200 Hz: a 1 Hz, 8 mm one (3 cycles) and a 2 Hz, 4 mm one (4 cycles). One window per
#: condition is too little: its residual is so autocorrelated (N_eff of a few) that the condition's own loop cannot
#: call even the 154 N offset (ΔBIC_eff -10 at 1 MPa).
MOTIONS = ((8e-3, 1.0, 3), (4e-3, 2.0, 4))


@pytest.mark.parametrize("case", [pytest.param(c, marks=v["marks"]) for c, v in CASES.items()])
def test_one_damper_at_three_charges_gets_one_explanation(tmp_path, case, capsys):
    spec = CASES[case]
    folders = make_conditions(tmp_path / "data", motions=MOTIONS, rate=200.0, seed=0)
    out = tmp_path / "out"
    argv = ["diagnose", *map(str, folders), "--out", str(out), "--workers", "2", "--no-figures"]
    if spec["effects"]:
        argv += ["--effects", spec["effects"]]
    if spec["max_steps"]:
        argv += ["--max-steps", str(spec["max_steps"])]
    assert main(argv) == 0
    r = json.loads((out / "conditions.json").read_text())
    with capsys.disabled():
        print(f"\n[conditions {case}] own {r['own_selection']}, kept {r['kept']}, {r['wall_time_s']:.0f} s")
        print("\n".join(r["summary_lines"]))
        print("\n".join(f"  {b['dataset']} {b['condition']}: J {b['J_before']:.4f} -> {b['J_after']:.4f}"
                        for b in r["by_condition"]))
    # one explanation for the damper, and it is the injected one (the offset read by the library's offset effect)
    assert {"friction", "load_cell_offset"} <= set(r["kept"])
    for c in r["conditions"]:
        d = json.loads((out / c["folder"] / "diagnosis.json").read_text())
        assert d["selected"] == r["kept"]  # the same effects at every condition
        assert d["final"]["J_pooled"] <= 0.5 * d["baseline"]["J_pooled"]
    # the offset moves with the charge; its slope [N/Pa] is the rod's area
    off = r["parameters"]["load_cell_offset.offset_N"]
    assert not off["shared"]
    t = off["trend"]["charge_pressure_Pa"]
    assert t["slope_lo"] < ROD_AREA < t["slope_hi"] and t["slope_lo"] > 0
    for v, c in zip(off["values"], r["conditions"], strict=True):  # each offset near p_c A_rod (+ k y, averaging 0)
        truth = c["condition"]["charge_pressure_Pa"] * ROD_AREA
        assert math.isclose(v["median"], truth, rel_tol=0.15), (v, truth)
    # the friction is the same at every charge: shared (its per-condition values do not earn their place)
    assert r["parameters"]["friction.coulomb_N"]["shared"]
    # the report page of a condition carries the joint account
    summary = {"dataset": r["conditions"][0]["dataset"], "segments": []}
    d0 = json.loads((out / r["conditions"][0]["folder"] / "diagnosis.json").read_text())
    (tmp_path / "page").mkdir()
    page = render_report(summary, d0, tmp_path / "page").read_text()
    assert "One damper under several conditions" in page and "varies with the condition" in page
