"""Whole-record identification: eq. (7) driven by a measured displacement history, every parameter at once.

A record that is not a triangular test has no plateaus from which stage 1 could fix the flow
coefficients, so they are sampled jointly with α_V and p_R:

    θ = (C_L12, C_Q12, C_L21, C_Q21, log α_V, log p_R[, effect parameters][, F_0][, φ]).

Priors: α_V and p_R log-uniform on the same boxes as stage 2 (:mod:`bayesdamper.inference.priors`). The
flow coefficients are uniform on [0, U] (a flat prior on coefficients that enter the static law
linearly; C = 0 is a legitimate value — a purely laminar or purely quadratic path — which a log prior
could not reach). U is fixed from the record's scale: ``STATIC_BOX`` times the coefficient that alone
would carry the largest measured force at the largest measured flow. Effect parameters keep their
library priors; the force offset F_0 is uniform on ±``OFFSET_BOX`` times the largest |force|.

The likelihood is the one of stage 2 (:mod:`bayesdamper.inference.likelihood`) on the eq. (9) residual of
the whole (decimated) record: white or AR(1) noise with the scale marginalised. The simulation starts at
the record's first sample in the quasi-static state of its initial velocity.

Forward model: the quintic spline through the (decimated) displacement samples drives eq. (7)
(:func:`bayesdamper.physics.spline_input.solve_spline`); RODAS4 steps across the samples with its own
step-size control. The tolerances are relative to the record's pressure scale (largest |F| / A_P), so a
record's force is computed to about 1e-5 of its size whatever the damper (tests/test_whole_kernel.py:
rel. L2 error <= 1e-4 against scipy's Radau at rtol 1e-11) and the log-posterior is smooth in θ. The
solves release the GIL: a batch of walkers is evaluated on ``WHOLE_THREADS`` threads when the process is
not itself a worker of a process pool.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from bayesdamper.core.params import DamperConstants
from bayesdamper.inference.priors import ALPHA_V_BOUNDS, P_R_BOUNDS, PHI_BOUNDS, ParameterSpace, ParameterSpec
from bayesdamper.physics.effect_vector import EFFECT_SLOTS
from bayesdamper.physics.effects import EFFECTS
from bayesdamper.physics.spline_input import solve_spline, spline_coefficients

#: Upper end of the flow coefficients' uniform prior, in units of the coefficient that alone carries the
#: largest measured force at the largest measured flow: 100x leaves two decades above anything the
#: record can support while keeping the prior proper.
STATIC_BOX = 100.0
#: Half-width of the force offset's uniform prior, in units of the largest measured |force|.
OFFSET_BOX = 1.0
#: Kernel tolerances inside the whole-record likelihood: relative, and absolute in units of the record's
#: pressure scale (largest |F| / A_P). Rel. L2 error of the force 2e-6 - 1e-5 against Radau at rtol 1e-11
#: on sines and multisines at 100-1000 Hz (tests/test_whole_kernel.py). What sets them is the smoothness of
#: the log-posterior, not the force error: an adaptive solve moves by about its tolerance when a parameter
#: change shifts its steps, and on a 12 s multisine (benchmarks/whole_record.py) the log-posterior then
#: jitters by sd 0.03 at these values, 0.25 at ten times the absolute tolerance and 0.8 at ten times both,
#: which stalls emcee (no convergence in 6000 steps instead of 2200).
WHOLE_RTOL = 1e-6
WHOLE_ATOL_REL = 3e-6
#: Threads evaluating one batch of walkers (None: every core this process may use, at most 4).
WHOLE_THREADS = None
STATIC_NAMES = ("C_L12", "C_Q12", "C_L21", "C_Q21")
STATIC_UNITS = ("kg m^-4 s^-1", "kg m^-7", "kg m^-4 s^-1", "kg m^-7")
OFFSET_NAME = "offset_N"


def quasi_static_dp(flow4: np.ndarray, q: float) -> float:
    """Δp [Pa] of eq. (4) at the flow ``q`` [m^3/s] with the direction's pair of ``flow4``."""
    cl, cq = (flow4[0], flow4[1]) if q >= 0 else (flow4[2], flow4[3])
    return float(cl * q + cq * q * abs(q))


def static_scales(window, area: float) -> np.ndarray:
    """The record's coefficient scales [C_L, C_Q, C_L, C_Q]: each alone carries max |F| at max |Q|."""
    q = area * np.abs(window.velocity())
    qmax = max(float(np.quantile(q, 0.99)), 1e-12)
    dpmax = max(float(np.quantile(np.abs(window.force), 0.99)) / area, 1.0)
    return np.array([dpmax / qmax, dpmax / qmax**2] * 2)


@dataclass(frozen=True)
class WholeSpace:
    """The whole-record parameter vector: names, priors, which effect slots and extras it carries."""

    space: ParameterSpace
    effect_slots: tuple = ()  # (slot index, EffectParam) per sampled effect parameter
    effects: tuple[str, ...] = ()
    has_offset: bool = False
    has_phi: bool = False

    @classmethod
    def build(cls, scales: np.ndarray, max_force: float, *, effects: tuple[str, ...] = (), offset: bool = False,
              noise_params: tuple[ParameterSpec, ...] = (), alpha_v_bounds=ALPHA_V_BOUNDS,
              p_r_bounds=P_R_BOUNDS) -> WholeSpace:
        specs = [ParameterSpec(n, u, 0.0, float(STATIC_BOX * s), log=False)
                 for n, u, s in zip(STATIC_NAMES, STATIC_UNITS, scales, strict=True)]
        specs += [ParameterSpec("alpha_V", "-", *alpha_v_bounds), ParameterSpec("p_R_Pa", "Pa", *p_r_bounds)]
        slots = []
        for name in effects:
            for p in EFFECTS[name].params:
                if p.optional:  # optional parameters stay at their default (pack_effects)
                    continue
                specs.append(ParameterSpec(f"{name}.{p.name}", p.unit, p.lower, p.upper, log=p.log))
                slots.append((EFFECT_SLOTS.index(p.slot), p))
        if offset:
            specs.append(ParameterSpec(OFFSET_NAME, "N", -OFFSET_BOX * max_force, OFFSET_BOX * max_force, log=False))
        specs += list(noise_params)
        return cls(ParameterSpace(tuple(specs)), tuple(slots), tuple(effects), offset, bool(noise_params))

    @property
    def n_model(self) -> int:
        """Parameters of the model (all but the noise model's)."""
        return self.space.ndim - (1 if self.has_phi else 0)


@dataclass(frozen=True, eq=False)
class WholeRecordProblem:
    """One record window bound to the damper: θ's model part -> computed force [N]."""

    window: object
    damper: DamperConstants
    base_effects: np.ndarray = field(default_factory=lambda: np.zeros(len(EFFECT_SLOTS)))
    rtol: float = WHOLE_RTOL
    atol: float | None = None  # [Pa]; None: WHOLE_ATOL_REL times the record's pressure scale

    def __post_init__(self) -> None:
        w = self.window
        kt = np.ascontiguousarray(w.time, dtype=float)
        object.__setattr__(self, "time", kt)
        object.__setattr__(self, "force", np.ascontiguousarray(w.force, dtype=float))
        sp_t, sp_c = spline_coefficients(kt, w.displacement)
        object.__setattr__(self, "spline", (sp_t, sp_c))
        object.__setattr__(self, "v0", float(sp_c[0, 1]))
        object.__setattr__(self, "segment_id", w.id)
        if self.atol is None:
            scale = float(np.max(np.abs(self.force))) / self.damper.piston_area if self.force.size else 0.0
            object.__setattr__(self, "atol", max(WHOLE_ATOL_REL * scale, 1e-6))

    def simulate(self, flow4: np.ndarray, alpha_v: float, p_r: float, eff: np.ndarray | None = None,
                 offset: float = 0.0) -> tuple[np.ndarray, bool]:
        """Computed force [N] at the samples and whether the solve succeeded (False: not finite)."""
        flow4 = np.ascontiguousarray(flow4, dtype=float)
        if (not np.all(np.isfinite(flow4)) or np.any(flow4 < 0) or flow4[0] + flow4[1] <= 0
                or flow4[2] + flow4[3] <= 0 or not (alpha_v > 0 and p_r > 0)):
            return np.full(self.time.shape, np.nan), False
        eff = self.base_effects if eff is None else np.ascontiguousarray(eff, dtype=float)
        d = self.damper
        dp0 = quasi_static_dp(flow4, d.piston_area * self.v0)
        sp_t, sp_c = self.spline
        force, status, _ = solve_spline(self.time, sp_t, sp_c, float(sp_t[0]), dp0, d.piston_area,
                                        d.chamber_volume_1, d.chamber_volume_2, d.liquid_bulk_modulus, flow4,
                                        float(alpha_v), float(p_r), eff, float(self.rtol), float(self.atol))
        ok = status == 0 and bool(np.all(np.isfinite(force)))
        return force + offset, ok


class WholeLogPosterior:
    """Log-posterior of a whole record; -inf outside the prior and for a failed solve, never NaN."""

    def __init__(self, problem: WholeRecordProblem, wspace: WholeSpace):
        self.problem = problem
        self.wspace = wspace
        self.space = wspace.space
        self._lower, self._upper = self.space.lower, self.space.upper

    def unpack(self, theta: np.ndarray) -> tuple[np.ndarray, float, float, np.ndarray, float]:
        """(flow4, α_V, p_R, effect vector, offset) of a transformed vector."""
        theta = np.asarray(theta, dtype=float)
        flow4 = theta[:4]
        alpha_v, p_r = math.exp(theta[4]), math.exp(theta[5])
        eff = self.problem.base_effects.copy()
        k = 6
        for (slot, p), spec in zip(self.wspace.effect_slots, self.space.specs[6:], strict=False):
            eff[slot] = p.to_slot(math.exp(theta[k]) if spec.log else float(theta[k]))
            k += 1
        offset = float(theta[k]) if self.wspace.has_offset else 0.0
        return flow4, alpha_v, p_r, eff, offset

    def simulate(self, theta: np.ndarray) -> tuple[np.ndarray, bool]:
        flow4, a, p, eff, off = self.unpack(theta)
        return self.problem.simulate(flow4, a, p, eff, off)

    def residual(self, theta: np.ndarray) -> np.ndarray | None:
        f, ok = self.simulate(theta)
        return f - self.problem.force if ok else None

    def __call__(self, theta: np.ndarray) -> float:
        theta = np.asarray(theta, dtype=float)
        if not (np.all(np.isfinite(theta)) and np.all(theta >= self._lower) and np.all(theta <= self._upper)):
            return -np.inf
        r = self.residual(theta)
        if r is None:
            return -np.inf
        n = r.size
        if self.wspace.has_phi:
            phi = float(theta[-1])
            e = r[1:] - phi * r[:-1]
            s = (1.0 - phi * phi) * r[0] * r[0] + float(e @ e)
            ll = 0.5 * math.log1p(-phi * phi) - 0.5 * n * math.log(s) if s > 0 else -np.inf
        else:
            s = float(r @ r)
            ll = -0.5 * n * math.log(s) if s > 0 else -np.inf
        return float(ll) if np.isfinite(ll) else -np.inf

    def batch(self, thetas: np.ndarray) -> np.ndarray:
        """Row by row (emcee ``vectorize=True``), on :func:`batch_threads` threads (the solves release the
        GIL; the rows are independent, so the result does not depend on the number of threads)."""
        rows = np.atleast_2d(thetas)
        pool = _pool()
        if pool is None or len(rows) < 2:
            return np.array([self(t) for t in rows])
        return np.array(list(pool.map(self, rows)))

    def cost(self, theta: np.ndarray) -> float:
        """Eq. (9) J of the whole record at ``theta`` (inf for a failed solve)."""
        r = self.residual(theta)
        if r is None:
            return math.inf
        f = self.problem.force
        return float(np.sqrt(r @ r) / np.sqrt(f @ f))


_POOL: list = []


def batch_threads() -> int:
    """Threads for one batch of walkers: ``WHOLE_THREADS``, else the cores this process may use (at most 4),
    and 1 inside a worker process of a pool (its siblings already use the cores)."""
    if WHOLE_THREADS is not None:
        return max(1, int(WHOLE_THREADS))
    if mp.parent_process() is not None:
        return 1
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        n = os.cpu_count() or 1
    return max(1, min(n, 4))


def _pool() -> ThreadPoolExecutor | None:
    n = batch_threads()
    if n <= 1:
        return None
    if not _POOL or _POOL[0][0] != n:
        _POOL.clear()
        _POOL.append((n, ThreadPoolExecutor(max_workers=n, thread_name_prefix="whole-batch")))
    return _POOL[0][1]


def phi_spec() -> ParameterSpec:
    return ParameterSpec("phi", "-", *PHI_BOUNDS, log=False)
