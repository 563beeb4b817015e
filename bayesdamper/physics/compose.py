"""Compose any named effects into one compiled forward kernel of eq. (7).

An effect is one module of :mod:`bayesdamper.physics.effects`: its ``EFFECT`` (parameters with units and
priors), its extra states (``STATES``, ``STATE_ATOL``) and numba hooks saying where it acts —
displacement path, flow path, chamber pressures (compressibility), force output — with the protocol of
:mod:`bayesdamper.physics.effects.signals`. For a combination of effects this module writes the model
half of a kernel (the right-hand side, the force, the initial state) that calls exactly those hooks,
appends it to the solver half (:mod:`bayesdamper.physics.composed_template`), and imports the result from
the kernel cache, so numba compiles one kernel per combination and caches it on disk. Adding an effect
is adding a module: nothing here names an effect.

Order of evaluation at time t (the signals of :mod:`~bayesdamper.physics.effects.signals`):

1. y_A, v_A, a_A from the measured displacement's polynomial pieces
   (:class:`~bayesdamper.physics.excitation.PiecewisePolynomial`); the displacement-path hooks in registry
   order; the series compliance: y_P = y_D - c A_P Δp;
2. Q_O(Δp) of eq. (8), then the flow-path hooks;
3. absolute pressures from a ``pressures`` hook (at most one effect) with B(p_i) of eq. (3), else eq. (6); a
   ``moduli`` hook (at most one effect) replaces these moduli; extra chamber inflows q_1, q_2;
4. dΔp/dt = [B_1/V_1 (A_P v_D - Q + q_1) + B_2/V_2 (A_P v_D - Q - q_2)] / (1 + K A_P^2 c),
   K = B_1/V_1 + B_2/V_2, v_P = v_D - c A_P dΔp/dt (with every effect off this is eq. (7));
5. the effects' state derivatives; the force F = A_P Δp + the force hooks.

The kernel cache is ``$BAYESDAMPER_KERNEL_CACHE`` or ``~/.cache/bayesdamper/kernels`` (a temporary folder
if that is not writable); a file's name is the hash of everything its text depends on.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import inspect
import math
import os
import sys
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from bayesdamper.core.errors import SettingsError
from bayesdamper.core.frozen import readonly
from bayesdamper.physics import composed_template
from bayesdamper.physics.effects import EFFECT_MODULES, complete_effects
from bayesdamper.physics.effects import signals as _signals
from bayesdamper.physics.excitation import PiecewisePolynomial

__all__ = ["ComposedEffects", "compose", "kernel", "kernel_source", "layout", "solve_composed", "warm_up"]

_PREFIX = "bayesdamper_kernel_"
#: The solver half, read once at import so that every kernel of a process is generated from the same text.
_TEMPLATE = inspect.getsource(composed_template)
#: Digests of the effect modules and the signal protocol as this process loaded them: a kernel's file name
#: depends on the code the process compiles, even if a file changes on disk while it runs.
_DIGESTS = {name: hashlib.sha256(Path(inspect.getfile(mod)).read_bytes()).hexdigest()
            for name, mod in EFFECT_MODULES.items()}
_DIGESTS[""] = hashlib.sha256(Path(inspect.getfile(_signals)).read_bytes()).hexdigest()


@dataclass(frozen=True, eq=False)
class ComposedEffects:
    """A combination of effects with parameter values, ready for the composed kernel.

    Attributes
    ----------
    names : tuple of str
        The effects, in registry order.
    values : ndarray
        Their parameters concatenated in that order (each effect's parameter order), SI units.
    """

    names: tuple[str, ...]
    values: np.ndarray

    def as_dict(self) -> dict[str, dict[str, float]]:
        """``{effect: {param: value}}``."""
        return {name: {p.name: float(v) for p, v in zip(EFFECT_MODULES[name].EFFECT.params, vals, strict=True)}
                for name, vals in self._slices()}

    def transform_input(self, drive: PiecewisePolynomial) -> PiecewisePolynomial:
        """Apply the effects' input transforms (``transform_input`` hooks, e.g. backlash) to the measured
        displacement."""
        for name, p in self._slices():
            mod = EFFECT_MODULES[name]
            if hasattr(mod, "transform_input"):
                drive = mod.transform_input(drive, p)
        return drive

    def compliance(self) -> float:
        """Total series compliance [m/N] of the effects' ``compliance`` hooks."""
        return float(sum(EFFECT_MODULES[n].compliance(p) for n, p in self._slices()
                         if hasattr(EFFECT_MODULES[n], "compliance")))

    @functools.cached_property
    def force_only(self) -> bool:
        """Every effect only adds a force (no state, no hook in the ODE): eq. (7)'s own kernel solves Δp and the
        effects' forces are added at the samples (:func:`solve_composed`)."""
        return all(not getattr(EFFECT_MODULES[n], "STATES", ()) and not any(hasattr(EFFECT_MODULES[n], h)
                                                                             for h in ODE_HOOKS)
                   for n in self.names)

    @functools.cached_property
    def layout(self) -> np.ndarray:
        """The kernel's runtime layout of these effects (:func:`layout`)."""
        return layout(self.names)[0]

    @functools.cached_property
    def kernel_inputs(self) -> tuple[np.ndarray, np.ndarray, float]:
        """What every solve of these effects hands the kernel: the values and the layout (read-only) and the
        total compliance [m/N]."""
        return readonly(self.values), readonly(self.layout, np.int64), self.compliance()

    def _slices(self):
        i = 0
        for name in self.names:
            n = len(EFFECT_MODULES[name].EFFECT.params)
            yield name, self.values[i:i + n]
            i += n


def compose(effects: Mapping[str, Mapping[str, float] | None] | None) -> ComposedEffects:
    """:class:`ComposedEffects` of ``{effect: {param: value}}`` (defaults filled, values checked)."""
    full = complete_effects(effects)
    names = tuple(n for n in EFFECT_MODULES if n in full)
    vals = [full[n][p.name] for n in names for p in EFFECT_MODULES[n].EFFECT.params]
    out = ComposedEffects(names, np.array(vals, dtype=np.float64))
    _ = out.layout  # checks the combination
    return out


#: Hooks that change the ODE or its input (an effect with none of them and no state only adds a force).
ODE_HOOKS = ("displacement", "compliance", "flow", "pressures", "moduli", "chamber_flows", "derivatives",
             "transform_input")


# ----------------------------------------------------------------------------- code generation
#: Columns of the layout array handed to the kernel: effect active, first state, first parameter, end.
L_ACTIVE, L_STATE, L_PRM, L_PRM_END = range(4)


def _rows():
    """Per registered effect: (alias, module, its number of states)."""
    return [(f"_e{i}", mod, len(getattr(mod, "STATES", ()))) for i, mod in enumerate(EFFECT_MODULES.values())]


def layout(names: tuple[str, ...]) -> tuple[np.ndarray, int]:
    """The kernel's runtime layout of the effects ``names``: an int array (one row per registered effect:
    active, state offset, parameter start, parameter end; columns ``L_*``) and the number of states."""
    unknown = [n for n in names if n not in EFFECT_MODULES]
    if unknown:
        raise SettingsError(f"unknown effect(s) {', '.join(unknown)}")
    for hook, what in (("pressures", "the chamber pressures"), ("moduli", "the chambers' bulk moduli")):
        setting = [n for n in names if hasattr(EFFECT_MODULES[n], hook)]
        if len(setting) > 1:
            raise SettingsError("effects " + ", ".join(setting) + f" all set {what}: name at most one of them")
    lay = np.zeros((len(EFFECT_MODULES), 4), dtype=np.int64)
    o, a = 1, 0
    for i, (name, mod) in enumerate(EFFECT_MODULES.items()):
        if name not in names:
            continue
        npar = len(mod.EFFECT.params)
        lay[i] = (1, o, a, a + npar)
        o += len(getattr(mod, "STATES", ()))
        a += npar
    return lay, o


def kernel_source() -> str:
    """Python source of the composed kernel: every registered effect's hooks, each called only when the
    runtime layout (:func:`layout`) marks the effect active."""
    rows = _rows()

    def z(i, n, arr="s"):
        return f"{arr}[lay[{i}, 1]:lay[{i}, 1] + {n}]"

    def p(i):
        return f"prm[lay[{i}, 2]:lay[{i}, 3]]"

    def has(mod, hook):
        return hasattr(mod, hook)

    def guarded(hook, body, skip=()):
        """For every effect with ``hook`` (but the ``skip`` hooks): ``if lay[i, 0]:`` and ``body(i, alias, n)``."""
        out = []
        for i, (alias, mod, n) in enumerate(rows):
            if has(mod, hook) and not any(has(mod, h) for h in skip):
                out += [f"    if lay[{i}, 0]:"] + ["        " + b for b in body(i, alias, n)]
        return out

    lines = ["", "", "# " + "-" * 77 + " generated model half",
             "from bayesdamper.physics.compressibility import bulk_modulus_scalar as _bulk",
             "from bayesdamper.physics.orifice import orifice_flow as _orifice",
             "from bayesdamper.physics.effects.signals import (AA, AV, BL, DDP, DP, DP1, DP2, P1, P2, PR,",
             "                                               PRESSURE_FLOOR_PA, Q, QO, T, V1, V2, VA, VP, YA, YP)"]
    for alias, mod, _ in rows:
        lines.append(f"import {mod.__name__} as {alias}")
    lines += ["", "", "@njit(cache=True)",
              "def _n_states(lay):",
              "    n = 1"]
    lines += [f"    if lay[{i}, 0]:\n        n += {n}" for i, (_, _, n) in enumerate(rows) if n]
    lines += ["    return n", "", "",
              "@njit(cache=True)",
              "def _force_mode(lay, prm):",
              "    mode = FORCE_DP"]

    def force_mode(i, a, n):
        mod = rows[i][1]
        body = [f"mode = max(mode, {a}.force_reads({p(i)}))"] if has(mod, "force_reads") else ["return FORCE_SIGNALS"]
        return [f"if {a}.force_acts({p(i)}):"] + ["    " + b for b in body] if has(mod, "force_acts") else body

    lines += guarded("force", force_mode)
    motion = ["    sig[T] = t", "    sig[YA] = ya", "    sig[VA] = va", "    sig[AA] = aa", "    sig[YP] = ya",
              "    sig[VP] = va"]

    def displacement_path(dz):
        """The input through the displacement-path effects into sig[YP], sig[VP]; their derivatives into ``dz``."""
        return guarded("displacement", lambda i, a, n: [
            f"y, v = {a}.displacement(sig, {z(i, n)}, {p(i)}, {z(i, n, dz)})", "sig[YP] = y", "sig[VP] = v"])

    lines += ["    return mode", "", "",
              "@njit(cache=True, error_model=\"numpy\", **NO_REFCOUNT)",
              "def _motion_at(t, s, scratch, sig, prm, base, ya, va, aa, lay):", *motion]
    lines += displacement_path("scratch")
    lines += ["    sig[DP] = s[0]",
              "    sig[YP] = sig[YP] - base[B_COMP] * base[B_AREA] * s[0]", "", "",
              "@njit(cache=True, error_model=\"numpy\", **NO_REFCOUNT)",
              "def _rhs_at(t, s, ds, sig, prm, base, ya, va, aa, lay):", *motion,
              "    sig[PR] = base[B_PR]",
              "    sig[AV] = base[B_ALPHA]",
              "    sig[BL] = base[B_B0]",
              "    for i in range(ds.shape[0]):",
              "        ds[i] = 0.0"]
    lines += displacement_path("ds")
    lines += ["    dp = s[0]",
              "    sig[DP] = dp",
              "    area = base[B_AREA]",
              "    comp = base[B_COMP]",
              "    y = sig[YP] - comp * area * dp",
              "    sig[YP] = y",
              "    vol1 = base[B_V01] - area * y",
              "    vol2 = base[B_V02] + area * y",
              "    if not (vol1 > 0.0 and vol2 > 0.0):",
              "        return False",
              "    sig[V1] = vol1",
              "    sig[V2] = vol2",
              "    qo = _orifice(dp, base[B_FL0], base[B_FL1], base[B_FL2], base[B_FL3])",
              "    sig[QO] = qo",
              "    sig[Q] = qo"]
    lines += guarded("flow", lambda i, a, n: [f"sig[Q] = {a}.flow(sig, {z(i, n)}, {p(i)}, {z(i, n, 'ds')})"])
    lines += ["    q = sig[Q]",
              "    b0 = base[B_B0]",
              "    alpha = base[B_ALPHA]",
              "    p_r = base[B_PR]",
              "    absolute = False",
              "    p1 = 0.0",
              "    p2 = 0.0"]
    lines += guarded("pressures", lambda i, a, n: [f"p1, p2 = {a}.pressures(sig, {z(i, n)}, {p(i)})",
                                                   "absolute = True"])
    # the moduli of eq. (3) or eq. (6), unless an active effect's moduli hook sets them (below)
    own = " or ".join(f"lay[{i}, 0]" for i, (_, mod, _) in enumerate(rows) if has(mod, "moduli")) or "False"
    lines += ["    if absolute:",
              "        sig[P1] = p1",
              "        sig[P2] = p2",
              "    b1 = 0.0",
              "    b2 = 0.0",
              f"    if not ({own}):",
              "        if absolute:",
              "            b1 = _bulk(max(p1, PRESSURE_FLOOR_PA), b0, alpha, p_r)",
              "            b2 = _bulk(max(p2, PRESSURE_FLOOR_PA), b0, alpha, p_r)",
              "        else:  # eq. (6)",
              "            loaded = _bulk(p_r + abs(dp), b0, alpha, p_r)",
              "            unloaded = _bulk(p_r, b0, alpha, p_r)",
              "            b1 = loaded if dp >= 0.0 else unloaded",
              "            b2 = unloaded if dp >= 0.0 else loaded"]
    lines += guarded("moduli", lambda i, a, n: [f"b1, b2 = {a}.moduli(sig, {z(i, n)}, {p(i)})"])
    lines += ["    q1 = 0.0", "    q2 = 0.0"]
    lines += guarded("chamber_flows", lambda i, a, n: [f"a1, a2 = {a}.chamber_flows(sig, {z(i, n)}, {p(i)})",
                                                       "q1 += a1", "q2 += a2"])
    lines += ["    g1 = b1 / vol1",
              "    g2 = b2 / vol2",
              "    vd = sig[VP]",
              "    ddp = ((g1 * (area * vd - q + q1) + g2 * (area * vd - q - q2))",
              "           / (1.0 + (g1 + g2) * area * area * comp))",
              "    vp = vd - comp * area * ddp",
              "    sig[DDP] = ddp",
              "    sig[VP] = vp",
              "    sig[DP1] = g1 * (area * vp - q + q1)",
              "    sig[DP2] = g2 * (-area * vp + q + q2)",
              "    ds[0] = ddp"]
    lines += guarded("derivatives", lambda i, a, n: [f"{a}.derivatives(sig, {z(i, n)}, {p(i)}, {z(i, n, 'ds')})"])
    lines += ["    return math.isfinite(ddp)", "", "",
              "@njit(cache=True, error_model=\"numpy\", **NO_REFCOUNT)",
              "def _force(sig, s, prm, base, lay):",
              "    f = base[B_AREA] * s[0]"]
    lines += guarded("force", lambda i, a, n: [f"f += {a}.force(sig, {z(i, n)}, {p(i)})"])
    lines += ["    return f", "", "",
              "@njit(cache=True, error_model=\"numpy\")",
              "def _init(t0, ya0, v_prev, dp0, sig, s, prm, base, lay):",
              "    for i in range(s.shape[0]):",
              "        s[i] = 0.0",
              "    s[0] = dp0",
              "    scratch = np.zeros(s.shape[0])",
              "    sig[T] = t0",
              "    sig[YA] = ya0",
              "    sig[VA] = v_prev",
              "    sig[AA] = 0.0",
              "    sig[YP] = ya0",
              "    sig[VP] = v_prev",
              "    sig[DP] = dp0",
              "    sig[PR] = base[B_PR]",
              "    sig[AV] = base[B_ALPHA]",
              "    sig[BL] = base[B_B0]"]
    lines += guarded("displacement", lambda i, a, n: ([f"{a}.initial(sig, {p(i)}, {z(i, n)})"]
                                                      if has(rows[i][1], "initial") else [])
                     + [f"y, v = {a}.displacement(sig, {z(i, n)}, {p(i)}, {z(i, n, 'scratch')})",
                        "sig[YP] = y", "sig[VP] = v"])
    lines += ["    sig[YP] = sig[YP] - base[B_COMP] * base[B_AREA] * dp0",
              "    qo = _orifice(dp0, base[B_FL0], base[B_FL1], base[B_FL2], base[B_FL3])",
              "    sig[QO] = qo",
              "    sig[Q] = qo"]
    lines += guarded("initial", lambda i, a, n: [f"{a}.initial(sig, {p(i)}, {z(i, n)})"], skip=("displacement",))
    lines += ["    for i in range(s.shape[0]):",
              "        if not math.isfinite(s[i]):",
              "            return False",
              "    return True", "", "",
              "@njit(cache=True, error_model=\"numpy\")",
              "def _atol(prm, atol, out, lay):"]
    body = []
    for i, (alias, mod, n) in enumerate(rows):
        if n == 0:
            continue
        if has(mod, "state_atol"):
            body += [f"    if lay[{i}, 0]:", f"        {alias}.state_atol({p(i)}, atol, {z(i, n, 'out')})"]
        else:
            consts = tuple(float(c) for c in mod.STATE_ATOL)
            if len(consts) != n:
                raise SettingsError(f"effect {mod.EFFECT.name}: STATE_ATOL needs one value per state")
            body.append(f"    if lay[{i}, 0]:")
            body += [f"        out[lay[{i}, 1] + {j}] = {c!r}" for j, c in enumerate(consts)]
    lines += body or ["    return"]
    return _TEMPLATE + "\n".join(lines) + "\n"


def _cache_dir() -> Path:
    env = os.environ.get("BAYESDAMPER_KERNEL_CACHE")
    for cand in ([Path(env)] if env else []) + [Path.home() / ".cache" / "bayesdamper" / "kernels",
                                                 Path(tempfile.gettempdir()) / "bayesdamper-kernels"]:
        try:
            cand.mkdir(parents=True, exist_ok=True)
            if os.access(cand, os.W_OK):
                return cand
        except OSError:
            continue
    raise SettingsError("no writable folder for the composed kernels (set BAYESDAMPER_KERNEL_CACHE)")


@functools.cache
def kernel():
    """The imported composed kernel module (written to the cache and compiled on first use, once per machine)."""
    src = kernel_source()
    digest = hashlib.sha256()
    digest.update(src.encode())
    for name in (*EFFECT_MODULES, ""):
        digest.update(_DIGESTS[name].encode())
    digest.update(numba.__version__.encode())
    mod_name = _PREFIX + digest.hexdigest()[:20]
    if mod_name in sys.modules:
        return sys.modules[mod_name]
    folder = _cache_dir()
    path = folder / f"{mod_name}.py"
    if not path.exists() or path.read_text() != src:
        fd, tmp = tempfile.mkstemp(dir=folder, suffix=".tmp")
        with os.fdopen(fd, "w") as fh:
            fh.write(src)
        os.replace(tmp, path)
    spec = importlib.util.spec_from_file_location(mod_name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[mod_name] = module
    spec.loader.exec_module(module)
    return module


def solve_composed(composed: ComposedEffects, t_out: np.ndarray, drive: PiecewisePolynomial, t0: float, dp0: float,
                   v_prev: float, damper, flow4: np.ndarray, alpha_v: float, p_r: float, rtol: float, atol: float, *,
                   from_force: bool = False, max_steps: int | None = None, record: bool = False,
                   replay: np.ndarray | None = None) -> tuple:
    """Force [N] at ``t_out`` and the status code of the composed kernel of ``composed``.

    ``drive`` is the measured displacement, already through :meth:`ComposedEffects.transform_input` and covering
    ``[t0, t_out[-1]]``; ``damper`` a :class:`~bayesdamper.core.params.DamperConstants`; effects that only add a
    force (:attr:`ComposedEffects.force_only`, eq. (7) itself included) take eq. (7)'s own kernel for Δp;
    ``flow4`` the eq. (8) coefficients; ``from_force``: ``dp0`` is the measured step force [N]
    (Δp0 solved from it, see :func:`~bayesdamper.physics.composed_template.solve_composed`); ``max_steps``:
    accepted steps after which the solve fails (None: ``composed_template.MAX_STEPS``).

    ``record``: also return the end times of the accepted steps (``(force, status, steps)``; ``steps`` None where
    eq. (7)'s own kernel solved or the record overflowed). ``replay``: such steps, taken as they are instead of
    by error control (internal numerical differentiation: the force at perturbed parameters on the steps of the
    solve it is differenced against); where they do not fit this solve it is solved again with error control.
    """
    mod = kernel()
    values, lay, comp = composed.kernel_inputs
    flow4 = np.asarray(flow4, dtype=float)
    base = np.array((damper.piston_area, damper.chamber_volume_1, damper.chamber_volume_2,
                     damper.liquid_bulk_modulus, alpha_v, p_r, flow4[0], flow4[1], flow4[2], flow4[3], comp))
    if not (np.isfinite(base).all() and alpha_v > 0 and p_r > 0 and comp >= 0 and math.isfinite(dp0)):
        return np.full(np.shape(t_out), np.nan), 5
    # the kernels' inputs are read-only whatever the caller's arrays are: one numba type each, one compilation
    t_out = readonly(t_out)
    base.flags.writeable = False
    if composed.force_only and t_out.size and t0 <= t_out[0] and t_out[-1] <= drive.end:
        w = drive.window(t0, float(max(t_out[-1], t0 + 1e-9)))  # eq. (7) starts at the input's first break
        force, status = mod.solve_force_only(t_out, readonly(w.breaks), readonly(w.coefs),
                                             readonly(w.restart, bool), float(dp0), float(v_prev), base, values,
                                             float(rtol), float(atol), bool(from_force), lay)
        return (force, status, None) if record else (force, status)
    cap = int(composed_template.MAX_STEPS if max_steps is None else max_steps)
    rec = np.empty(min(cap, RECORD_PER_SAMPLE * t_out.size + RECORD_BASE) if record else 0)
    args = (t_out, readonly(drive.breaks), readonly(drive.coefs), readonly(drive.restart, bool), float(t0),
            float(dp0), float(v_prev), base, values, float(rtol), float(atol), bool(from_force), lay, cap, rec)
    if replay is not None and replay.size:
        force, status, n = mod.solve_composed(*args, readonly(replay))
        if status != composed_template.STATUS_REPLAY:
            return (force, status, replay[:n] if n == replay.size else None) if record else (force, status)
    force, status, n = mod.solve_composed(*args, _NO_STEPS)
    if not record:
        return force, status
    return force, status, (rec[:n].copy() if n < rec.size else None)


#: Room for the recorded steps of a solve (``record``): this many per output sample and this many more; a solve that
#: takes more (a record that overflows) returns none and is not replayed.
RECORD_PER_SAMPLE, RECORD_BASE = 4, 1000
_NO_STEPS = readonly(np.empty(0))


def warm_up() -> None:
    """Compile (or load) the composed kernel's two entry points in this process with tiny solves: eq. (7) with
    force-only effects, and the composed ODE.

    Call it before forking worker processes: they inherit the compiled code instead of each compiling it.
    """
    from bayesdamper.core.params import PAPER_FLOW, RIG_A_DAMPER

    drive = PiecewisePolynomial.from_knots(np.array([0.0, 1.0]), np.array([0.0, 1e-3]))
    with_ode = next(c for c in (compose({n: None}) for n in EFFECT_MODULES) if not c.force_only)
    for composed in (compose({}), with_ode):  # eq. (7)'s force-only path, and the composed ODE's
        solve_composed(composed, np.array([0.5]), drive, 0.0, 0.0, 0.0, RIG_A_DAMPER, PAPER_FLOW.as_array(),
                       40.0, 3.0e5, 1e-6, 1.0)
