"""One damper under several conditions: the pooled elimination, shared or varying parameters, the trend against
the condition, and the checks of the inputs (fast; the whole job on generated data is in
tests/test_conditions_job.py)."""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest

from bayesdamper.diagnosis.conditions import (
    HETEROGENEITY_ALPHA,
    eliminate,
    heterogeneity,
    parameter_table,
    pooled_values,
    shared_values,
    sharing_cost,
    trend,
    union_of,
    varies,
)
from bayesdamper.diagnosis.loop import MIN_J_REDUCTION, SELECT_DELTA_BIC


def _table(sse: dict, n_eff: float = 2000.0, force_ss: float = 1e9) -> dict:
    return {"sse": sse, "n_eff": n_eff, "force_ss": force_ss}


def test_union_of_the_conditions_selections():
    # by the number of conditions that selected them, then by first selection
    assert union_of([["b"], ["a", "b"], ["c"]]) == ["b", "a", "c"]
    assert union_of([[], []]) == []


def test_an_effect_every_condition_needs_is_kept_and_one_condition_alone_is_dropped():
    """A (friction-like) lowers the SSE by 60 % at every condition; B (a one-off) by 30 % at one condition only and
    nothing elsewhere: pooled, B's J reduction is far below MIN_J_REDUCTION, so it is dropped though its ΔBIC at
    that one condition is strong."""
    t = []
    for c in range(3):
        s0 = 1e6
        s_a = 0.4 * s0
        s_b = 0.7 * s0 if c == 0 else s0
        s_ab = 0.7 * s_a if c == 0 else s_a
        t.append(_table({(): s0, ("A",): s_a, ("B",): s_b, ("A", "B"): s_ab}))
    asked = []
    kept, steps = eliminate(t, ["A", "B"], {"A": 1, "B": 2}, need=asked.append)
    assert asked == [[("A", "B"), ("B",), ("A",)], [("A",), ()]]  # the fits each step reads, asked before it
    assert kept == ["A"]
    assert steps[0]["dropped"] == "B"
    row_b = next(r for r in steps[0]["rows"] if r["effect"] == "B")
    assert row_b["delta_BIC_per_condition"][0] < SELECT_DELTA_BIC  # strong at its own condition ...
    assert row_b["J_reduction"] < MIN_J_REDUCTION  # ... but not over the damper
    assert steps[-1]["dropped"] is None


def test_nothing_is_kept_when_no_effect_helps():
    t = [_table({(): 1e6, ("A",): 0.999e6}) for _ in range(3)]
    kept, steps = eliminate(t, ["A"], {"A": 1})
    assert kept == [] and steps[0]["dropped"] == "A"


def test_cochran_q_rejects_equal_values_at_its_level():
    """Equal true values with known standard errors: Q rejects about HETEROGENEITY_ALPHA of the time (4000 seeded
    replicates: binomial sd 0.0034 at 5 %, tolerance 3 sd)."""
    rng = np.random.default_rng(7)
    sd = np.array([3.0, 4.0, 5.0])
    rej = np.mean([heterogeneity(30 + rng.normal(0, sd), sd)["p_value"] < HETEROGENEITY_ALPHA
                   for _ in range(4000)])
    assert abs(rej - HETEROGENEITY_ALPHA) < 3 * math.sqrt(HETEROGENEITY_ALPHA * (1 - HETEROGENEITY_ALPHA) / 4000)


def test_the_trend_interval_covers_the_true_slope():
    """A force offset growing with a charge pressure (slope = a rod area) estimated at three conditions: the 90 %
    interval of the weighted slope covers the truth at least as often as nominal (minus 3 binomial sd at 4000
    replicates) and at most 0.97 (the residual-heterogeneity scaling only widens it)."""
    rng = np.random.default_rng(11)
    x = np.array([2.5e5, 5e5, 1e6])
    b, sd = 1.54e-4, np.array([3.0, 4.0, 5.0])
    hits = 0
    for _ in range(4000):
        t = trend(x, 10 + b * x + rng.normal(0, sd), sd)
        hits += t["slope_lo"] <= b <= t["slope_hi"]
    assert 0.9 - 3 * math.sqrt(0.09 / 4000) <= hits / 4000 <= 0.97


def _scale(z, sd, log=False):
    return {"z": z, "sd": sd, "log": log, "sign": 1.0, "at_bound": False}


def test_parameter_table_pools_and_trends_and_sharing_is_decided_by_the_fit():
    conditions = [{"charge_pressure_Pa": 2.5e5}, {"charge_pressure_Pa": 5e5}, {"charge_pressure_Pa": 1e6}]
    per = [{"friction.coulomb_N": _scale(math.log(30.2), 0.02, True), "load_cell_offset.offset_N": _scale(38.0, 1.5)},
           {"friction.coulomb_N": _scale(math.log(29.7), 0.02, True), "load_cell_offset.offset_N": _scale(78.0, 1.5)},
           {"friction.coulomb_N": _scale(math.log(30.0), 0.02, True), "load_cell_offset.offset_N": _scale(153.0, 1.5)}]
    table = parameter_table(per, conditions)
    fr, off = table["friction.coulomb_N"], table["load_cell_offset.offset_N"]
    assert 29.5 < fr["pooled"]["median"] < 30.3
    assert fr["pooled"]["lo"] < fr["pooled"]["median"] < fr["pooled"]["hi"]
    assert not fr["heterogeneity"]["heterogeneous"] and off["heterogeneity"]["heterogeneous"]
    t = off["trend"]["charge_pressure_Pa"]
    assert t["slope_lo"] < 1.54e-4 < t["slope_hi"]
    # the decision is the fit's: a pooled value that costs more than the C - 1 values it saves is not shared
    n = [1000.0] * 3
    assert sharing_cost([100.0] * 3, [100.1] * 3, n) < 0  # 3 per mille of fit against 2 log(1000)
    assert sharing_cost([100.0] * 3, [100.0, 100.0, 150.0], n) > 0
    # ... and varying must also pay in J, as an added effect must: a few per mille is "significant" at N = 1000s
    assert not varies([100.0] * 3, [100.2, 100.5, 101.0], n)
    assert varies([100.0] * 3, [100.0, 300.0, 800.0], n)
    fr["shared"], off["shared"] = True, False
    fixed = shared_values(table, {"friction": {"coulomb_N": 31.0, "v_eps": 1e-5},
                                  "load_cell_offset": {"offset_N": 78.0}})
    assert fixed["friction"]["coulomb_N"] == pytest.approx(fr["pooled"]["median"])
    assert fixed["friction"]["v_eps"] == 1e-5 and fixed["load_cell_offset"]["offset_N"] == 78.0
    trial = pooled_values(table, {"load_cell_offset": {"offset_N": 78.0}}, ["load_cell_offset.offset_N"])
    assert trial["load_cell_offset"]["offset_N"] == pytest.approx(off["pooled"]["median"])


def test_one_damper_needs_the_same_constants_and_condition_names(tmp_path):
    """Several data sets go through one diagnosis only as one damper: the check names the file and the problem;
    data sets sharing a [damper] name are written to their folders' names."""
    from bayesdamper.io.dataset import load_dataset
    from bayesdamper.run.conditions import one_damper
    from bayesdamper.run.identify import dataset_folders

    src = tmp_path / "a"
    shutil.copytree("data/rig-A", src)
    toml = (src / "damper.toml").read_text()
    (src / "damper.toml").write_text(toml + "\n[condition]\ntemperature_C = 20.0\n")
    b = tmp_path / "b"
    shutil.copytree(src, b)
    (b / "damper.toml").write_text(toml + "\n[condition]\ntemperature_C = 40.0\n")
    dsa, dsb = load_dataset(src), load_dataset(b)
    assert one_damper([dsa, dsb]) is None
    assert dataset_folders([dsa, dsb]) == ["a", "b"]
    c = tmp_path / "c"
    shutil.copytree(src, c)
    (c / "damper.toml").write_text(toml.replace("piston_area_m2", "piston_area_m2 = 0.005 #", 1)
                                   + "\n[condition]\ntemperature_C = 30.0\n")
    assert "damper constants differ" in one_damper([dsa, load_dataset(c)])
    d = tmp_path / "d"
    shutil.copytree(src, d)
    (d / "damper.toml").write_text(toml + "\n[condition]\ncharge_pressure_Pa = 1e6\n")
    assert "[condition] names" in one_damper([dsa, load_dataset(d)])
    (d / "damper.toml").write_text(toml)
    assert "no [condition] table" in one_damper([dsa, load_dataset(d)])


def test_diagnose_of_two_different_dampers_is_one_line_and_writes_nothing(tmp_path, capsys):
    from bayesdamper.cli import main

    src = tmp_path / "a"
    shutil.copytree("data/rig-A", src)
    toml = (src / "damper.toml").read_text()
    (src / "damper.toml").write_text(toml + "\n[condition]\ntemperature_C = 20.0\n")
    c = tmp_path / "c"
    shutil.copytree(src, c)
    (c / "damper.toml").write_text(toml.replace("piston_area_m2", "piston_area_m2 = 0.005 #", 1)
                                   + "\n[condition]\ntemperature_C = 30.0\n")
    out = tmp_path / "out"
    assert main(["diagnose", str(src), str(c), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("bayesdamper: error: ") and "damper constants differ" in err[0]
    assert not out.exists()
