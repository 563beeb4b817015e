"""The paper's stage 2: Nelder-Mead on eq. (9), one point estimate per transient.

Multi-start in log parameters over the prior box, so the result does not hinge on one initial guess
(the eq. (9) surface has long ridges). This is the baseline every Bayesian result is compared with,
and where the sampler's walkers start.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from bayesdamper.inference.priors import ParameterSpace
from bayesdamper.inference.problem import WindowProblem

#: Start grid of the multi-start search (α_V [-], p_R [Pa]), spanning the default prior box.
START_ALPHA_V = (5.0, 50.0, 500.0)
START_P_R = (1.0e4, 1.0e5, 1.0e6)
#: Nelder-Mead stopping tolerances on log-parameters and on J.
NM_XATOL = 1e-4
NM_FATOL = 1e-9


@dataclass(frozen=True)
class PointFit:
    """Nelder-Mead optimum of eq. (9) for one transient.

    Attributes
    ----------
    alpha_v : float
        Liquid-gas volume ratio α_V [-].
    p_r : float
        Reference pressure p_R [Pa].
    cost : float
        Eq. (9) J at the optimum [-].
    n_solves : int
        Forward solves spent.
    """

    alpha_v: float
    p_r: float
    cost: float
    n_solves: int


def _cost(problem: WindowProblem, space: ParameterSpace, x: np.ndarray, counter: list) -> float:
    counter[0] += 1
    if np.any(x < space.lower[:2]) or np.any(x > space.upper[:2]):
        return 1e3 + float(np.sum(np.maximum(space.lower[:2] - x, 0) + np.maximum(x - space.upper[:2], 0)))
    force, ok = problem.simulate_force(np.exp(x[0]), np.exp(x[1]))
    if not ok:
        return 1e3
    r = force - problem.force
    return float(np.sqrt(r @ r) / np.sqrt(problem.force @ problem.force))


def fit_point(problem: WindowProblem, space: ParameterSpace | None = None,
              starts: tuple[tuple[float, float], ...] | None = None) -> PointFit:
    """Multi-start Nelder-Mead minimisation of eq. (9) in (log α_V, log p_R).

    Every start is polished by Nelder-Mead; the best end point is polished once more from a fresh
    simplex, which guards against Nelder-Mead's premature collapse on ridges.
    """
    space = space or ParameterSpace.default()
    starts = starts or tuple(itertools.product(START_ALPHA_V, START_P_R))
    counter = [0]

    def f(x):
        return _cost(problem, space, x, counter)

    opts = {"xatol": NM_XATOL, "fatol": NM_FATOL, "maxiter": 400}
    results = [minimize(f, np.log(s), method="Nelder-Mead", options=opts) for s in starts]
    best = min(results, key=lambda r: r.fun)
    best = min(best, minimize(f, best.x, method="Nelder-Mead", options=opts), key=lambda r: r.fun)
    x = np.clip(best.x, space.lower[:2], space.upper[:2])
    return PointFit(float(np.exp(x[0])), float(np.exp(x[1])), float(best.fun), counter[0])
