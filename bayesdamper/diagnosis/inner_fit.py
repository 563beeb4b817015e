"""The per-transient re-fit inside the profile search: Gauss-Newton on (log α_V, log p_R) with a carried Jacobian.

Every evaluation of a candidate's profile objective S(ψ) re-fits each transient's two parameters by least squares on
eq. (9) (:mod:`bayesdamper.diagnosis.candidates`). scipy's trust-region ``least_squares`` estimates the 2-column
Jacobian afresh by forward differences at every iterate: 3 solves an iteration. Here a Levenberg-Marquardt iteration
carries the Jacobian instead: it starts from the one the last re-fit of the same transient ended with (the search
moves ψ a little at a time), corrects it along every step taken (Broyden's rank-one update), and re-computes it by
forward differences only when it is stale (a step failed, or the iterate moved more than :data:`JAC_REUSE` since the
last difference) or to confirm convergence. Convergence is declared when a Jacobian differenced at the iterate
predicts a Gauss-Newton step below :data:`XTOL` (log units) or a decrease below :data:`FTOL` of the sum of squares;
when a step from a Jacobian at most :data:`JAC_REUSE` old gains less than :data:`FTOL`; when a step from a Jacobian
differenced at its start gains what that Jacobian predicted to within :data:`FTOL`; or when such a step, predicted
to gain less than 10 :data:`FTOL`, fails (the noise floor of the differences and the solver). On rig-A (6 transients
x 21 points of a search) the sums of squares came within 5.3e-6 of scipy's at tolerance 1e-14, scipy's trust region
at the search's former tolerances within 6.4e-6.

The parameters live in a box; a parameter at a bound whose gradient points out of the box is held there (the
reduced problem is solved for the others), so optima on the bounds are reached as in the projected methods.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

#: Gauss-Newton step [log units] below which the fit has converged (with a fresh Jacobian).
XTOL = 1e-4
#: Relative decrease of the sum of squares below which the fit has converged (see the module docstring). Near the
#: optimum forward differences (error ~ h × curvature) and the solver's own tolerance make steps predicted to gain
#: less fail about as often as they succeed; 1e-7 cost a solve more per re-fit on rig-A for the same accuracy.
FTOL = 1e-6
#: Forward-difference step relative to max(1, |x|) (scipy's ``diff_step`` convention; the search used 1e-4).
DIFF_STEP = 1e-4
#: Distance [log units] the iterate may move from where the Jacobian was last differenced before it is stale.
JAC_REUSE = 0.02
#: Largest Levenberg-Marquardt damping (relative to the diagonal of JᵀJ) tried before a step is given up.
LAM_MAX = 1e8
#: Solves after which the iteration gives up (the caller then falls back to scipy's ``least_squares``): this many
#: per parameter plus this many, i.e. 30 for a transient's (α_V, p_R) and 66 for a window with its own start force
#: and flow coefficients (about three differenced Jacobians and their iterations either way).
MAX_SOLVES_PER_PARAMETER, MAX_SOLVES_BASE = 8, 14


@dataclass
class InnerFit:
    """Outcome of one re-fit: optimum, sum of squares, residual, the Jacobian there, solves spent, and how it ended
    (one of :data:`ENDINGS`)."""

    x: np.ndarray
    sse: float
    r: np.ndarray | None
    jac: np.ndarray | None
    n_solves: int
    converged: bool
    ending: str


#: How a re-fit ends (:attr:`InnerFit.ending`), by the rule that stopped it (module docstring): a failed solve at the
#: start; a Jacobian that could not be differenced (a perturbed solve failed); a Gauss-Newton step (from a Jacobian
#: differenced at the iterate) below ``xtol`` or predicting a gain below ``ftol``; a step the bounds cut to no
#: predicted gain; an accepted step that gained less than ``ftol`` or what its exact Jacobian predicted; a small step
#: of an exact Jacobian that failed (the noise floor of the solver and the differences); the solves ran out.
ENDINGS = ("infeasible start", "no Jacobian", "step below tolerance", "held by the bounds", "gain below tolerance",
           "noise floor", "solves ran out")


def _forward_jacobian(resid, x, r, hi, fd=None):
    """Forward-difference Jacobian at x (steps away from the upper bound); None if a perturbed solve fails.
    ``fd(x, xp)``: the residual at ``xp`` as a difference against the solve at ``x`` (its steps replayed), else
    ``resid(xp)``."""
    J = np.empty((r.size, x.size))
    for j in range(x.size):
        h = DIFF_STEP * max(1.0, abs(x[j]))
        if x[j] + h > hi[j]:
            h = -h
        xp = x.copy()
        xp[j] += h
        rp = resid(xp) if fd is None else fd(x, xp)
        if rp is None:
            return None
        J[:, j] = (rp - r) / h
    return J


#: A pivot of the step's elimination at or below this share of the system's largest diagonal element is taken as zero
#: (the system is singular, :func:`lm_step` takes least squares): an exactly dependent column leaves a pivot of the
#: order of the rounding error, 1e-16 of the diagonal, whose sign and size depend on the order of the arithmetic.
SINGULAR_PIVOT = 1e-13


@njit(cache=True)
def _lm_kernel(A, g, x, lo, hi, lam):  # pragma: no cover - compiled
    """:func:`lm_step` compiled: (dx, predicted decrease, solved). ``solved`` False: the damped reduced system is
    singular (a pivot of Gaussian elimination with partial pivoting at the rounding level, :data:`SINGULAR_PIVOT`);
    the caller then takes least squares."""
    n = x.size
    free = np.empty(n, dtype=np.int64)
    m = 0
    for i in range(n):
        if not ((x[i] <= lo[i] and g[i] > 0.0) or (x[i] >= hi[i] and g[i] < 0.0)):
            free[m] = i
            m += 1
    dx = np.zeros(n)
    M = np.empty((m, m))
    b = np.empty(m)
    for a in range(m):
        for c in range(m):
            M[a, c] = A[free[a], free[c]]
        M[a, a] += lam * A[free[a], free[a]]
        b[a] = -g[free[a]]
    scale = 0.0  # a pivot below SINGULAR_PIVOT of the largest diagonal element is rounding of a zero one
    for a in range(m):
        scale = max(scale, abs(M[a, a]))
    for c in range(m):  # forward elimination, partial pivoting
        p = c
        for a in range(c + 1, m):
            if abs(M[a, c]) > abs(M[p, c]):
                p = a
        if abs(M[p, c]) <= SINGULAR_PIVOT * scale:
            return dx, 0.0, False
        if p != c:
            for k in range(m):
                M[c, k], M[p, k] = M[p, k], M[c, k]
            b[c], b[p] = b[p], b[c]
        for a in range(c + 1, m):
            f = M[a, c] / M[c, c]
            for k in range(c, m):
                M[a, k] -= f * M[c, k]
            b[a] -= f * b[c]
    for c in range(m - 1, -1, -1):
        v = b[c]
        for k in range(c + 1, m):
            v -= M[c, k] * dx[free[k]]
        dx[free[c]] = v / M[c, c]
    for i in range(n):
        dx[i] = min(max(x[i] + dx[i], lo[i]), hi[i]) - x[i]
    quad = 0.0
    lin = 0.0
    for i in range(n):
        lin += g[i] * dx[i]
        for k in range(n):
            quad += dx[i] * A[i, k] * dx[k]
    return dx, -(2.0 * lin + quad), True


def lm_step(A: np.ndarray, g: np.ndarray, x: np.ndarray, lo: np.ndarray, hi: np.ndarray,
            lam: float) -> tuple[np.ndarray, float]:
    """Levenberg-Marquardt step of a least-squares problem with JᵀJ = ``A`` and Jᵀr = ``g`` in the box [lo, hi].

    The damping ``lam`` multiplies the diagonal of A; a parameter at a bound whose gradient points out of the box
    is held there and the reduced system solved for the others; the step is then cut to the box. Returns the step
    and the decrease of r·r the linear model predicts for it (≤ 0: the cut step cannot gain). Compiled
    (:func:`_lm_kernel`): a re-fit takes a few such steps per solve, and at two or three parameters numpy's
    per-call overhead cost as much as a tenth of the search; a singular damped system is solved by least squares.
    """
    A, g = np.ascontiguousarray(A, dtype=float), np.ascontiguousarray(g, dtype=float)
    x, lo, hi = (np.ascontiguousarray(v, dtype=float) for v in (x, lo, hi))
    dx, pred, solved = _lm_kernel(A, g, x, lo, hi, float(lam))
    if solved:
        return dx, float(pred)
    free = ~(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0)))
    dx = np.zeros_like(x)
    if free.any():
        Af = A[np.ix_(free, free)]
        Af = Af + lam * np.diag(np.diag(Af))
        dx[free] = -np.linalg.lstsq(Af, g[free], rcond=None)[0]
    dx = np.clip(x + dx, lo, hi) - x
    return dx, -float(2.0 * g @ dx + dx @ A @ dx)


def refit(resid, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray, jac: np.ndarray | None = None,
          r0: np.ndarray | None = None, xtol: float = XTOL, ftol: float = FTOL, fd=None) -> InnerFit:
    """Least-squares minimum of ``resid(x)`` (an array, or None for a failed solve) in the box [lo, hi].

    ``jac``: the Jacobian a previous fit ended with (None: differenced at ``x0``). ``r0``: ``resid(x0)`` where the
    caller has solved there already (``x0`` inside the box; counted as the fit's first solve). ``xtol``, ``ftol``: the
    convergence tolerances (module docstring; looser ones for a value that only ranks). ``fd(x, xp)``: the residual
    at ``xp`` for a forward difference at ``x`` (:func:`_forward_jacobian`; default ``resid(xp)``). Returns the best
    point
    found and ``converged`` False when the solves (:data:`MAX_SOLVES_PER_PARAMETER`) ran out or the Jacobian could
    not be differenced; an infeasible start (``resid(x0)`` None) returns ``sse`` inf and ``r`` None.
    """
    x = np.clip(np.asarray(x0, dtype=float), lo, hi)
    r = resid(x) if r0 is None else r0
    n = 1
    if r is None:
        return InnerFit(x, float("inf"), None, None, n, False, "infeasible start")
    s = float(r @ r)
    if jac is None:
        J, moved = _forward_jacobian(resid, x, r, hi, fd), 0.0
        n += x.size
        if J is None:
            return InnerFit(x, s, r, None, n, False, "no Jacobian")
    else:
        J, moved = np.array(jac, dtype=float), np.inf
    lam = 0.0
    max_solves = MAX_SOLVES_BASE + MAX_SOLVES_PER_PARAMETER * x.size
    while n < max_solves:
        A, g = J.T @ J, J.T @ r  # the step's normal equations, for every damping tried at this iterate
        dx0, pred0 = lm_step(A, g, x, lo, hi, 0.0)  # the Gauss-Newton step: has the fit converged?
        if float(np.linalg.norm(dx0)) < xtol or 0.0 <= pred0 <= ftol * s:
            if moved == 0.0:  # predicted by a Jacobian differenced here
                return InnerFit(x, s, r, J, n, True, "step below tolerance")
            J, moved, lam = _forward_jacobian(resid, x, r, hi, fd), 0.0, 0.0
            n += x.size
            if J is None:
                return InnerFit(x, s, r, None, n, False, "no Jacobian")
            continue
        dx, pred = (dx0, pred0) if lam == 0.0 else lm_step(A, g, x, lo, hi, lam)
        while pred <= 0.0 and lam < LAM_MAX:  # a step cut by the bounds that the model says cannot gain
            lam = max(4.0 * lam, 1e-3)
            dx, pred = lm_step(A, g, x, lo, hi, lam)
        if pred <= 0.0:
            return InnerFit(x, s, r, J, n, moved == 0.0, "held by the bounds")
        r_new = resid(x + dx)
        n += 1
        s_new = float(r_new @ r_new) if r_new is not None else np.inf
        if s_new < s:
            J = J + np.outer((r_new - r) - J @ dx, dx) / float(dx @ dx)  # Broyden's rank-one correction
            # converged if the step gained less than FTOL, or gained what an exact Jacobian's model predicted to
            # within FTOL (the model's error over the step bounds what a further step could gain)
            done = (s - s_new <= ftol * s and moved <= JAC_REUSE) or (moved == 0.0 and
                                                                    abs(s - s_new - pred) <= ftol * s)
            x, r, s = x + dx, r_new, s_new
            if done:
                return InnerFit(x, s, r, J, n, True, "gain below tolerance")
            moved += float(np.linalg.norm(dx))
            lam = 0.0 if lam < 1e-3 else 0.25 * lam
        elif moved == 0.0 and pred <= 10.0 * ftol * s:  # an exact Jacobian's small step failed: the noise floor
            return InnerFit(x, s, r, J, n, True, "noise floor")
        elif moved > 0.0:  # the Jacobian may be what failed: difference it here first
            J, moved = _forward_jacobian(resid, x, r, hi, fd), 0.0
            n += x.size
            if J is None:
                return InnerFit(x, s, r, None, n, False, "no Jacobian")
        else:
            lam = max(4.0 * lam, 1e-3)
    return InnerFit(x, s, r, J, n, False, "solves ran out")
