"""Where a window's fit starts when its flow coefficients have no stage 1 (no plateaus): a least-squares optimum.

A sine, sweep or random record has no plateaus, so the flow coefficients of eq. (4) are estimated with α_V,
p_R and the start's Δp from the window itself. The fit starts from the quasi-static force at speed — away from
the reversals the force follows eq. (4), which is linear in (C_L, C_Q) per direction: a non-negative least
squares — and the best of a grid of (α_V, p_R), then bounded least squares on the eq. (9) residual of all seven
parameters. Its optimum is where the noise is measured (:mod:`bayesdamper.inference.noise`) and where the
posterior's sampler starts.
"""

from __future__ import annotations

import math

import numpy as np

#: Grid of (α_V, p_R) from which the least-squares fit starts (the best of them on eq. (9)).
START_ALPHA_V = (10.0, 40.0, 150.0, 600.0)
START_P_R = (3e4, 1e5, 3e5, 1e6)
#: Samples with |v| above this fraction of the window's largest |v| enter the quasi-static start of the flow
#: coefficients (away from the reversals, where compressibility dominates the force).
QUASI_STATIC_SPEED = 0.3
#: Kernel tolerances of the least-squares fit: those of the MAP fit (:data:`bayesdamper.inference.joint.FIT_RTOL`).
FIT_RTOL, FIT_ATOL = 1e-7, 1e-2
#: Relative finite-difference step of the least-squares Jacobian (solver noise 1e-5 of the difference).
FD_STEP = 1e-3
#: Evaluations of the least-squares fit.
MAX_NFEV = 400


def quasi_static_flow(time: np.ndarray, force: np.ndarray, velocity: np.ndarray, area: float,
                      scales: np.ndarray) -> np.ndarray:
    """Flow coefficients [C_L12, C_Q12, C_L21, C_Q21] from a non-negative least-squares fit of the force against
    eq. (4) at the window's fast samples (|v| >= QUASI_STATIC_SPEED of its largest), per direction; a direction
    with too few samples gets half its scale."""
    from scipy.optimize import nnls

    fast = np.abs(velocity) >= QUASI_STATIC_SPEED * np.max(np.abs(velocity))
    flow4 = np.empty(4)
    for k, sel in enumerate((fast & (velocity > 0), fast & (velocity < 0))):
        q, dp = area * np.abs(velocity[sel]), np.abs(force[sel]) / area
        if q.size < 3 or not np.any(dp > 0):
            flow4[2 * k:2 * k + 2] = 0.5 * scales[2 * k:2 * k + 2]
            continue
        # columns scaled to the pressure scale, so NNLS sees numbers of order one
        a = np.column_stack([q * scales[2 * k], q * q * scales[2 * k + 1]]) / np.max(dp)
        c, _ = nnls(a, dp / np.max(dp))
        flow4[2 * k:2 * k + 2] = np.maximum(c, 1e-3) * scales[2 * k:2 * k + 2]  # strictly inside the box
    return flow4


def residual_sse(jp, theta) -> float:
    """Sum of squares of a :class:`~bayesdamper.inference.joint.JointProblem`'s residual (pre-step samples included)
    at ``theta``; inf where the solve fails or is not finite."""
    r = jp.residual(np.asarray(theta, dtype=float))
    return float(r @ r) if r is not None and np.all(np.isfinite(r)) else math.inf


def least_squares_start(jp, space, hint: dict | None = None) -> tuple[np.ndarray, float, bool]:
    """Least-squares optimum of eq. (9) over (log α_V, log p_R, Δp0, C_L12, C_Q12, C_L21, C_Q21) of a
    :class:`~bayesdamper.inference.joint.JointProblem` (pre-step samples included), its J over the window, and
    whether it started from ``hint``.

    ``hint``: a further start beside the grid's, physical ``alpha_V``, ``p_R_Pa`` and, where known,
    ``start_force_N`` [N] (else the window's Δp0 estimate) and ``flow`` (4,) (else the quasi-static estimate);
    the fit starts from the best of the grid and the hint.

    Raises
    ------
    RuntimeError
        If no start gives a finite solution.
    """
    from scipy.optimize import least_squares

    area = jp.damper.piston_area
    lo, hi = space.lower[:7], space.upper[:7]
    v = jp.drive.velocity(jp.time)
    scales = (hi[3:7] - lo[3:7]) / 100.0
    flow4 = np.clip(quasi_static_flow(jp.time, jp.force, v, area, scales), lo[3:7], hi[3:7])
    dp0 = float(np.clip(jp.dp0_estimate, lo[2], hi[2]))
    fmag = float(np.sqrt(np.mean(jp.force ** 2)))
    n_rows = jp.pre_force.size + jp.force.size

    def resid(x):
        r = jp.residual(x, FIT_RTOL, FIT_ATOL)
        return r if r is not None else np.full(n_rows, 10.0 * fmag)

    best, best_s = None, math.inf
    for a in START_ALPHA_V:
        for p in START_P_R:
            th = np.r_[math.log(a), math.log(p), dp0, flow4]
            s = residual_sse(jp, th)
            if s < best_s:
                best, best_s = th, s
    hinted = False
    if hint is not None:
        th = np.r_[math.log(hint["alpha_V"]), math.log(hint["p_R_Pa"]),
                   hint["start_force_N"] / area if "start_force_N" in hint else dp0,
                   np.asarray(hint["flow"], dtype=float) if "flow" in hint else flow4]
        th = np.clip(th, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
        s = residual_sse(jp, th)
        if s < best_s:
            best, best_s, hinted = th, s, True
    if best is None:
        raise RuntimeError(f"{jp.segment_id}: no start of the least-squares fit gives a finite solution")
    eps = 1e-9 * (hi - lo)
    x0 = np.clip(best, lo + eps, hi - eps)
    scale = np.r_[0.1, 0.1, max(abs(dp0), 0.01 * (hi[2] - lo[2])), np.maximum(np.abs(x0[3:7]), 1e-3 * (hi - lo)[3:7])]
    sol = least_squares(resid, x0, bounds=(lo, hi), x_scale=scale, diff_step=FD_STEP, max_nfev=MAX_NFEV)
    x = sol.x if residual_sse(jp, sol.x) <= best_s else best
    f, ok = jp.simulate_window(x)
    j = float(np.linalg.norm(f - jp.force) / np.linalg.norm(jp.force)) if ok else math.inf
    return x, j, hinted
