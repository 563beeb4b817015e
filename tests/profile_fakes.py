"""A base for test doubles of :class:`bayesdamper.diagnosis.candidates.ProfileEngine`, and of its problems."""

from __future__ import annotations

import contextlib
from types import SimpleNamespace

import numpy as np

from bayesdamper.inference.problem import INNER_BOX


def fake_problem(force: np.ndarray) -> SimpleNamespace:
    """A stand-in for a window's :class:`~bayesdamper.inference.problem.EffectsProblem`: its measured ``force`` [N]
    and the box of its own parameters (log α_V, log p_R), the one the engine reads to know which of them a re-fit
    can move."""
    return SimpleNamespace(force=np.asarray(force, dtype=float), inner_box=lambda: INNER_BOX)


class FakeProfileEngine:
    """Subclasses give ``problems`` (:func:`fake_problem`) and ``evaluate``; the Jacobian of the residuals with
    respect to the shared parameters comes from forward differences of ``evaluate`` (a fake's residual has no
    (α_V, p_R) to project out, so ``jac`` is None for every transient)."""

    screen = None

    @property
    def jac(self) -> list:
        return [None] * len(self.problems)

    def restart(self) -> None:
        """Nothing is carried from one search to the next."""

    def remembering(self):
        """No outcome is re-used."""
        return contextlib.nullcontext(self)

    def sensitivities(self, base, effs, flows, hs, idx, xs, resid):
        perturbed = [self.evaluate(e, f, idx=idx)[2] for e, f in zip(effs, flows, strict=True)]
        return [None if r is None else np.column_stack([(p[i] - r) / h for p, h in zip(perturbed, hs, strict=True)])
                for i, r in enumerate(resid)]


def loop_fit(labels: tuple, score: float, j: float) -> SimpleNamespace:
    """A stand-in for a :class:`~bayesdamper.diagnosis.spec.CandidateFit` of the options ``labels`` at ΔBIC_eff
    ``score`` and pooled J ``j``, as the select-and-refit loop reads one."""
    return SimpleNamespace(labels=labels, effect="+".join(labels), delta_bic=score, j_pooled=j, params={},
                           effects={lab.split("@")[0]: {} for lab in labels}, n_evaluations=0, polish_pending=False,
                           warm=None, cost={})


def table_search(table: dict):
    """A stand-in for :func:`bayesdamper.diagnosis.two_state_pairs.search_option` that looks each option up in
    ``table`` (``{labels: (ΔBIC_eff, J)}``); a later round's screens (``grid_only``) improve on nothing."""
    def search(engine, specs, start, fixed, *a, new=None, grid_only=False, **k):
        labels = tuple(new) if new else tuple(s.label for s in specs)
        return loop_fit(labels, +5.0, 0.031) if grid_only else loop_fit(labels, *table[labels])

    return search
