"""The composed kernel: any named effects in one compiled model driven by any input.

Eq. (7) is the composition with no effects: it must equal the hand-written eq. (7) kernel (its fast path) on a
piecewise-linear record with its steps off the sample grid at an odd sample rate and on a smooth (spline) input.
Every effect is checked against the independent scipy references elsewhere (``test_reference_effects``); here
the generator's structure, the step cap and the effects' behaviour on smooth inputs.
"""

from pathlib import Path

import numpy as np

from bayesdamper.core.params import PAPER_FLOW, RIG_A_DAMPER, DynamicParameters
from bayesdamper.physics import compose as compose_mod
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
from bayesdamper.physics.effects import _FIRST, EFFECT_MODULES, EFFECTS
from bayesdamper.physics.excitation import PiecewisePolynomial
from bayesdamper.physics.rodas import STATUS_OK
from bayesdamper.physics.single_state import solve_eq7

D = RIG_A_DAMPER
FLOW = PAPER_FLOW.as_array()
DYN = DynamicParameters(40.0, 3.0e5)
#: Steps at 1.0137 s and then every 4.0 s, speed 1 mm/s; samples at 1234 Hz from the second step (a
#: reversal) so that no step falls on a sample.
KT = np.array([0.0, 1.0137, 3.0137, 7.0137, 11.0137])
KY = np.array([0.0, 0.0, 2e-3, -2e-3, 2e-3])
T_OUT = 3.0137 + np.arange(1, 2469) / 1234.0
#: Composed (rtol 1e-8) vs the eq. (7) kernel (rtol 1e-8): both solve the same ODE to a local error of 1e-8 (the
#: composed one with a finite-difference Jacobian); their global errors are a few hundred times that on these
#: transients, while every effect changes the force by > 1e-3 relative.
KERNEL_RTOL = 2e-6
DRIVE = PiecewisePolynomial.from_knots(KT, KY)


def _composed(effects, dp0, v_prev, drive=DRIVE, t_out=T_OUT, t0=KT[2], **kw):
    c = compose(effects)
    d = c.transform_input(drive)
    return solve_composed(c, t_out, d, t0, dp0, v_prev, D, FLOW, DYN.liquid_gas_ratio, DYN.reference_pressure,
                          1e-8, 1e-3, **kw)


def _eq7(drive, t_out, t0, dp0):
    w = drive.window(t0, float(t_out[-1]))
    dp, status, _ = solve_eq7(t_out, w.breaks, w.coefs, w.restart, dp0, D.piston_area, D.chamber_volume_1,
                              D.chamber_volume_2, D.liquid_bulk_modulus, FLOW, DYN.liquid_gas_ratio,
                              DYN.reference_pressure, 0, 0.0, 1e-8, 1e-3)
    assert status == STATUS_OK
    return D.piston_area * dp


def _spline_drive(t, y):
    from scipy.interpolate import PPoly, make_interp_spline

    pp = PPoly.from_spline(make_interp_spline(t, y, k=5))
    keep = np.diff(pp.x) > 0
    brk = np.r_[pp.x[:-1][keep], pp.x[1:][keep][-1]]
    return PiecewisePolynomial(brk, pp.c[::-1, keep].T, np.zeros(brk.size, dtype=bool))


#: A smooth input: a 0.7 Hz, 3 mm sine through a quintic spline at 300 Hz, from mid-stroke at peak speed.
T_SINE = np.arange(0.0, 4.0, 1.0 / 300.0)
SINE = _spline_drive(T_SINE, 3e-3 * np.sin(2 * np.pi * 0.7 * T_SINE))


def test_eq7_is_the_composition_with_no_effects():
    f, status = _composed({}, 2.0e5, 1e-3)
    assert status == STATUS_OK
    f_ref = _eq7(DRIVE, T_OUT, KT[2], 2.0e5)
    assert np.max(np.abs(f - f_ref)) / np.max(np.abs(f_ref)) < KERNEL_RTOL
    v0 = float(SINE.velocity(0.0))
    f, status = _composed({}, 0.0, v0, drive=SINE, t_out=T_SINE, t0=0.0)
    assert status == STATUS_OK
    f_ref = _eq7(SINE, T_SINE, 0.0, 0.0)
    assert np.max(np.abs(f - f_ref)) / np.max(np.abs(f_ref)) < KERNEL_RTOL


#: Inertia on a smooth input is m a(t) exactly (the corner filter only rounds velocity steps); relative to the
#: inertial force's amplitude, the kernel's error at rtol 1e-8 and the spline's acceleration error are far below.
INERTIA_RTOL = 1e-4


def test_inertia_on_a_smooth_input_is_mass_times_acceleration():
    mass = 800.0
    v0 = float(SINE.velocity(0.0))
    f0, _ = _composed({}, 0.0, v0, drive=SINE, t_out=T_SINE, t0=0.0)
    f1, status = _composed({"inertia": {"mass_kg": mass}}, 0.0, v0, drive=SINE, t_out=T_SINE, t0=0.0)
    assert status == STATUS_OK
    inertial = mass * SINE.acceleration(T_SINE)
    assert np.max(np.abs(f1 - f0 - inertial)) < INERTIA_RTOL * np.max(np.abs(inertial))


def test_backlash_on_a_smooth_input_rests_inside_the_play_and_follows_outside():
    from bayesdamper.physics.effects.backlash import play_polynomial

    gap = 1e-3
    piston = play_polynomial(SINE, gap)
    t = np.linspace(0.0, 3.99, 4000)
    ya, yp = SINE.displacement(t), piston.displacement(t)
    assert np.all(np.abs(ya - yp) <= 0.5 * gap + 1e-12)  # the play operator's invariant
    vp = piston.velocity(t)
    moving = np.abs(vp) > 0
    assert np.allclose(np.abs(ya - yp)[moving], 0.5 * gap, atol=1e-12)  # dragged: in contact
    assert np.any(~moving)  # rests after each reversal until the play is taken up
    # velocity jumps where the actuator takes the piston along: restart breaks there
    assert piston.restart.sum() > 2


def test_registry_is_every_module_with_an_effect():
    folder = Path(compose_mod.__file__).parent / "effects"
    modules = {p.stem for p in folder.glob("*.py") if p.stem not in ("__init__", "base", "signals")}
    assert set(EFFECT_MODULES) == {EFFECT_MODULES[n].EFFECT.name for n in EFFECT_MODULES}
    assert {m.__name__.rsplit(".", 1)[1] for m in EFFECT_MODULES.values()} == modules
    assert list(EFFECTS)[:len(_FIRST)] == list(_FIRST)


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
        hooks = {h for h in ("displacement", "flow", "pressures", "moduli", "chamber_flows", "derivatives", "force",
                             "force_acts", "initial", "state_atol") if hasattr(mod, h)}
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
