"""A base for test doubles of :class:`bayesdamper.diagnosis.candidates.ProfileEngine`."""

from __future__ import annotations

import numpy as np


class FakeProfileEngine:
    """Subclasses give ``problems`` and ``evaluate``; the Jacobian of the residuals with respect to the shared
    parameters comes from forward differences of ``evaluate`` (a fake's residual has no (α_V, p_R) to project out,
    so ``jac`` is None for every transient)."""

    screen = None

    @property
    def jac(self) -> list:
        return [None] * len(self.problems)

    def sensitivities(self, effs, flows, hs, idx, xs, resid):
        perturbed = [self.evaluate(e, f, idx=idx)[2] for e, f in zip(effs, flows, strict=True)]
        return [None if r is None else np.column_stack([(p[i] - r) / h for p, h in zip(perturbed, hs, strict=True)])
                for i, r in enumerate(resid)]
