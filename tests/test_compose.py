"""The composed kernel: any named effects in one compiled model, checked against the hand-written kernel.

The six effects of the fixed effect vector have two implementations: the hand-written kernel
(:mod:`bayesdamper.physics.augmented`, lag and corner filter in closed form, analytic Jacobian) and the
composed kernel (every effect state an ODE state, finite-difference Jacobian). Both are checked against
independent references elsewhere (``test_augmented``, ``test_effect_reference``); here they must agree
with each other on a record with its steps off the sample grid at an odd sample rate.
"""

from pathlib import Path

import numpy as np
import pytest

from bayesdamper.core.params import PAPER_FLOW, RIG_A_DAMPER, DynamicParameters
from bayesdamper.physics import compose as compose_mod
from bayesdamper.physics.augmented import solve_augmented
from bayesdamper.physics.compose import (
    L_ACTIVE,
    L_PRM,
    L_PRM_END,
    L_STATE,
    compose,
    kernel_source,
    layout,
    solve_composed,
)
from bayesdamper.physics.effect_vector import EFFECT_SLOTS, VECTOR_EFFECTS, pack_effects
from bayesdamper.physics.effects import EFFECT_MODULES, EFFECTS
from bayesdamper.physics.effects.backlash import backlash_knots
from bayesdamper.physics.rodas import STATUS_OK

D = RIG_A_DAMPER
FLOW = PAPER_FLOW.as_array()
DYN = DynamicParameters(40.0, 3.0e5)
#: Steps at 1.0137 s and then every 4.0 s, speed 1 mm/s; samples at 1234 Hz from the second step (a
#: reversal) so that no step falls on a sample.
KT = np.array([0.0, 1.0137, 3.0137, 7.0137, 11.0137])
KY = np.array([0.0, 0.0, 2e-3, -2e-3, 2e-3])
T_OUT = 3.0137 + np.arange(1, 2469) / 1234.0
#: Composed (rtol 1e-8) vs hand-written (rtol 1e-8): both solve the same ODE to a local error of 1e-8;
#: the global error of either is a few hundred times that on these transients (measured worst 4e-7 for
#: all five state-carrying effects together), while every effect changes the force by > 1e-3 relative.
KERNEL_RTOL = 2e-6
SIX = [{}, {"friction": {"coulomb_N": 200.0, "viscous_Ns_per_m": 1e4, "stribeck_N": 50.0}},
       {"backlash": {"gap_m": 1e-4}}, {"actuator_lag": {"time_constant_s": 0.05}},
       {"valve_dynamics": {"time_constant_s": 0.05, "opening_pressure_Pa": 1e5}},
       {"valve_dynamics": {"time_constant_s": 0.0, "opening_pressure_Pa": 1e5}},
       {"series_compliance": {"stiffness_N_per_m": 2e7}}, {"inertia": {"mass_kg": 500.0}},
       {"friction": {}, "actuator_lag": {}, "valve_dynamics": {}, "series_compliance": {}, "inertia": {},
        "backlash": {}}]


def _legacy(effects, dp0, v_prev):
    vec = pack_effects(effects)
    kt, ky = backlash_knots(KT, KY, vec[EFFECT_SLOTS.index("gap")])
    f, status = solve_augmented(T_OUT, kt, ky, KT[2], dp0, v_prev, D.piston_area, D.chamber_volume_1,
                                D.chamber_volume_2, D.liquid_bulk_modulus, FLOW, DYN.liquid_gas_ratio,
                                DYN.reference_pressure, vec, 1e-8, 1e-3)
    assert status == STATUS_OK
    return f


def _composed(effects, dp0, v_prev, **kw):
    c = compose(effects)
    kt, ky = c.transform_knots(KT, KY)
    return solve_composed(c, T_OUT, kt, ky, KT[2], dp0, v_prev, D, FLOW, DYN.liquid_gas_ratio,
                          DYN.reference_pressure, 1e-8, 1e-3, **kw)


@pytest.mark.parametrize("effects", SIX, ids=lambda e: "+".join(e) or "none")
def test_composed_equals_hand_written_kernel(effects):
    f_ref = _legacy(effects, 2.0e5, 1e-3)
    f, status = _composed(effects, 2.0e5, 1e-3)
    assert status == STATUS_OK
    assert np.max(np.abs(f - f_ref)) / np.max(np.abs(f_ref)) < KERNEL_RTOL
    if effects:  # and the effect is visible at that tolerance
        assert np.max(np.abs(f - _composed({}, 2.0e5, 1e-3)[0])) / np.max(np.abs(f_ref)) > 100 * KERNEL_RTOL


def test_registry_is_every_module_with_an_effect():
    folder = Path(compose_mod.__file__).parent / "effects"
    modules = {p.stem for p in folder.glob("*.py") if p.stem not in ("__init__", "base", "signals")}
    assert set(EFFECT_MODULES) == {EFFECT_MODULES[n].EFFECT.name for n in EFFECT_MODULES}
    assert {m.__name__.rsplit(".", 1)[1] for m in EFFECT_MODULES.values()} == modules
    assert list(EFFECTS)[:6] == list(VECTOR_EFFECTS)


def _guarded_calls(src: str) -> dict[str, set[str]]:
    """{alias: hooks it calls} of the generated source, checking each call sits under its ``if lay[i, 0]:``."""
    import re

    calls: dict[str, set[str]] = {}
    guard = None
    for line in src.split("# " + "-" * 77 + " generated model half")[1].splitlines():
        g = re.match(r"    if lay\[(\d+), 0\]:", line)
        if g:
            guard = f"_e{g.group(1)}"
            continue
        for alias, hook in re.findall(r"(_e\d+)\.(\w+)\(", line):
            assert line.startswith("        ") and alias == guard, line
            calls.setdefault(alias, set()).add(hook)
        if not line.startswith("        "):
            guard = None
    return calls


def test_kernel_source_names_no_effect_and_guards_every_hook():
    """The composer is generic: its source names no effect; the one kernel calls each effect's hooks only
    when the runtime layout marks it active, and the layout gives each active effect its own states."""
    text = Path(compose_mod.__file__).read_text()
    for name in EFFECTS:
        assert f'"{name}"' not in text and f"'{name}'" not in text
    calls = _guarded_calls(kernel_source())
    names = list(EFFECT_MODULES)
    for i, name in enumerate(names):
        mod = EFFECT_MODULES[name]
        hooks = {h for h in ("displacement", "flow", "pressures", "chamber_flows", "derivatives", "force", "force_acts",
                             "initial", "state_atol") if hasattr(mod, h)}
        assert calls.get(f"_e{i}", set()) == hooks, name
    lay, n_states = layout(("friction", "valve_dynamics", "inertia"))
    active = [names[i] for i in np.flatnonzero(lay[:, L_ACTIVE])]
    assert active == ["friction", "valve_dynamics", "inertia"]
    sizes = {n: len(getattr(EFFECT_MODULES[n], "STATES", ())) for n in active}
    assert n_states == 1 + sum(sizes.values())
    offsets = sorted((lay[names.index(n), L_STATE], sizes[n]) for n in active if sizes[n])
    assert offsets[0][0] == 1 and all(a + k == b for (a, k), (b, _) in zip(offsets[:-1], offsets[1:], strict=True))
    n_par = [len(EFFECTS[n].params) for n in active]
    assert [lay[names.index(n), L_PRM_END] - lay[names.index(n), L_PRM] for n in active] == n_par


def test_step_cap_fails_the_solve_and_is_counted_in_accepted_steps():
    """``max_steps`` (the diagnosis's search cap) turns a solve needing more accepted steps into a failure."""
    from bayesdamper.physics.rodas import STATUS_MAX_STEPS

    eff = {"valve_dynamics": {"time_constant_s": 0.05, "opening_pressure_Pa": 1e5}}
    f, status = _composed(eff, 2.0e5, 1e-3)
    assert status == STATUS_OK
    _, capped = _composed(eff, 2.0e5, 1e-3, max_steps=5)
    assert capped == STATUS_MAX_STEPS
    lo, hi = 5, 100_000
    while hi - lo > 1:  # the fewest accepted steps that succeed
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if _composed(eff, 2.0e5, 1e-3, max_steps=mid)[1] == STATUS_OK else (mid, hi)
    f2, status2 = _composed(eff, 2.0e5, 1e-3, max_steps=hi)
    assert status2 == STATUS_OK and np.array_equal(f, f2) and _composed(eff, 2.0e5, 1e-3, max_steps=hi - 1)[1] \
        == STATUS_MAX_STEPS
