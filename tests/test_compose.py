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
                             "force_acts", "force_reads", "initial", "state_atol") if hasattr(mod, h)}
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



def test_the_signals_a_force_reads_are_those_of_the_right_hand_side():
    """At an output time the kernel sets only the signals the active forces read (their ``force_reads`` level): t
    and Δp, or also the motion (``_motion_at``: input and displacement path). The motion's must equal those of the
    full right-hand side, with a displacement-path effect (actuator lag, with a state) active; with a series
    compliance the motion's level gives way to every signal (v_P then depends on dΔp/dt)."""
    from bayesdamper.physics.composed_template import FORCE_MOTION, FORCE_SIGNALS
    from bayesdamper.physics.effects.signals import AA, DP, N_SIGNALS, VA, VP, YA, YP, T

    mod = compose_mod.kernel()
    c = compose({"actuator_lag": {"time_constant_s": 0.02}, "friction": {"coulomb_N": 80.0},
                 "unnamed_dynamics": {"gain": 1e-3, "driver": 0.0, "mode": 1.0}})
    d = c.transform_input(DRIVE)
    ns = 1 + sum(len(getattr(EFFECT_MODULES[n], "STATES", ())) for n in c.names)
    base = np.array([D.piston_area, D.chamber_volume_1, D.chamber_volume_2, D.liquid_bulk_modulus, 40.0, 3e5, *FLOW,
                     0.0])
    assert mod._output_mode(c.layout, c.values, base) == FORCE_MOTION
    assert mod._output_mode(c.layout, c.values, np.r_[base[:-1], 1e-9]) == FORCE_SIGNALS
    read = [T, YA, VA, AA, YP, VP, DP]
    rng = np.random.default_rng(5)
    for t in (1.5, 3.3, 6.2, 9.9):
        a = int(np.searchsorted(d.breaks, t)) - 1
        s = np.r_[2e5 * rng.standard_normal(), 1e-5 * rng.standard_normal(ns - 1)]
        ref = np.full(N_SIGNALS, np.nan)
        assert mod._rhs(t, s, np.zeros(ns), ref, c.values, base, d.breaks, d.coefs, np.array([a, a + 1, a]), c.layout)
        sig = np.full(N_SIGNALS, np.nan)
        ya, va, aa, _ = mod._drive(t, d.breaks, d.coefs, a, a + 1, a)
        mod._motion_at(t, s, np.zeros(ns), sig, c.values, base, ya, va, aa, c.layout)
        np.testing.assert_array_equal(sig[read], ref[read])
        assert np.isfinite(ref[read]).all() and ref[VP] != va  # the lag's state moves the piston off the input


def test_forces_from_the_states_equal_those_from_every_signal():
    """A force that reads only t, Δp and its states (``force_from_state``) is evaluated at the samples from the dense
    output alone; with a force that reads the piston velocity beside it (friction: no state, nothing in the ODE) the
    kernel evaluates every signal there instead. Both must give the same force to rounding: friction's own force at
    the drive's velocity (no compliance: v_P is the drive's) is all that differs. On the full kernel (a Δp-driven
    transient filter on the force, with states) and on eq. (7)'s own kernel (a load-cell offset, no state)."""
    from bayesdamper.physics.effects.friction import friction_force

    fric = {"friction": {"coulomb_N": 150.0, "viscous_Ns_per_m": 2.0e4}}
    v = DRIVE.velocity(T_OUT)
    f_fric = friction_force(v, coulomb_N=150.0, viscous_Ns_per_m=2.0e4)
    for eff in ({"unnamed_dynamics": {"gain": 2e-3, "natural_frequency_Hz": 2.0, "damping_ratio": 0.2, "driver": 0.0,
                                      "law": 2.0, "threshold": 1.0e5, "mode": 1.0, "placement": 0.0}},
                {"load_cell_offset": {"offset_N": -120.0}}):
        f_state, status = _composed(eff, 2.0e5, 1e-3)
        assert status == STATUS_OK
        f_signals, status = _composed({**eff, **fric}, 2.0e5, 1e-3)
        assert status == STATUS_OK
        assert np.max(np.abs(f_signals - f_fric - f_state)) < 1e-9 * np.max(np.abs(f_state))
        base, _ = _composed({}, 2.0e5, 1e-3)
        assert np.max(np.abs(f_state - base)) > 10.0  # the effect acts


def test_solves_leave_no_allocation_behind():
    """The right-hand side, force and motion functions count no references (``NO_REFCOUNT``): every array a solve
    allocates must still be freed. NRT's allocation counters (on only when set before numba starts: a fresh
    process) over solves of every output level, a state effect, a chattering-prone valve and a failing solve."""
    import os
    import subprocess
    import sys

    code = """
import numpy as np
from numba.core.runtime import rtsys
from bayesdamper.core.params import PAPER_FLOW, RIG_A_DAMPER
from bayesdamper.physics.compose import compose, solve_composed
from bayesdamper.physics.excitation import PiecewisePolynomial
drive = PiecewisePolynomial.from_knots(np.array([0.0, 1.0, 3.0, 7.0]), np.array([0.0, 0.0, 2e-3, -2e-3]))
t = 1.0 + np.arange(1, 2000) / 400.0
cases = [{}, {"load_cell_offset": {"offset_N": 5.0}}, {"friction": {"coulomb_N": 50.0}},
         {"actuator_lag": {"time_constant_s": 0.02}, "friction": {"coulomb_N": 50.0}},
         {"poppet_valve": {"natural_frequency_Hz": 2.0}, "unnamed_dynamics": {"gain": 1e-3, "mode": 1.0}},
         {"series_compliance": {"stiffness_N_per_m": 2e7}, "seal_friction": {"stribeck_N": 100.0}}]
def run():
    for eff in cases:
        c = compose(eff)
        for cap in (None, 3):  # and a solve failing at its step cap
            solve_composed(c, t, c.transform_input(drive), 1.0, 0.0, 0.0, RIG_A_DAMPER, PAPER_FLOW.as_array(), 40.0,
                           3e5, 1e-6, 1.0, max_steps=cap)
run()
s0 = rtsys.get_allocation_stats()
for _ in range(20):
    run()
s1 = rtsys.get_allocation_stats()
print(s1.alloc - s0.alloc, s1.free - s0.free, s1.mi_alloc - s0.mi_alloc, s1.mi_free - s0.mi_free)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={**os.environ, "NUMBA_NRT_STATS": "1"})
    alloc, free, mi_alloc, mi_free = map(int, out.stdout.split())
    assert alloc > 0 and alloc == free and mi_alloc == mi_free, out.stdout


def test_kernels_are_compiled_once_whatever_the_callers_arrays():
    """numba types writable and read-only arrays as different arguments, and NumPy unpickles arrays writable: a
    window sent to a worker process must not make the composed kernel compile a second time. Solves with the input's
    arrays read-only (as built), writable (as NumPy unpickles a plain array) and pickled through a frozen container
    all use one compiled signature of each entry point."""
    import dataclasses
    import pickle

    mod = compose_mod.kernel()
    drive = PiecewisePolynomial.from_knots(np.array([0.0, 1.0, 3.0]), np.array([0.0, 0.0, 2e-3]))
    writable = dataclasses.replace(drive)  # then made writable in place, as an unpickled plain array is
    for name in ("breaks", "coefs", "restart"):
        object.__setattr__(writable, name, np.array(getattr(writable, name)))
    assert writable.breaks.flags.writeable
    unpickled = pickle.loads(pickle.dumps(drive))
    assert not (unpickled.breaks.flags.writeable or unpickled.coefs.flags.writeable
                or unpickled.restart.flags.writeable)
    t_ro = 1.0 + np.arange(1, 200) / 100.0
    t_ro.flags.writeable = False
    forces = []
    for eff in ({}, {"actuator_lag": {"time_constant_s": 0.02}}):
        for d, t in ((drive, t_ro), (writable, np.array(t_ro)), (unpickled, t_ro)):
            c = compose(eff)
            f, status = solve_composed(c, t, c.transform_input(d), 1.0, 0.0, 0.0, RIG_A_DAMPER,
                                       PAPER_FLOW.as_array(), 40.0, 3e5, 1e-6, 1.0)
            assert status == STATUS_OK
            forces.append(f)
    assert len(mod.solve_force_only.signatures) == 1, mod.solve_force_only.signatures
    assert len(mod.solve_composed.signatures) == 1, mod.solve_composed.signatures
    for f in forces[1:3]:
        np.testing.assert_array_equal(f, forces[0])
    for f in forces[4:]:
        np.testing.assert_array_equal(f, forces[3])
