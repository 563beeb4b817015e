"""What the profile search fits: a candidate (:class:`CandidateSpec`), its searched parameters (:class:`SearchParam`,
the search's transformed coordinates) and the outcome of a fit (:class:`CandidateFit`).

Shared by the search (:mod:`bayesdamper.diagnosis.candidates`) and its global stage
(:mod:`bayesdamper.diagnosis.global_stage`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

__all__ = ["GENERIC", "CandidateFit", "CandidateSpec", "SearchParam", "best_and_physical", "holds_generic",
           "search_params"]

#: The generic effect: dynamics no named effect holds, built from the residual's signature.
GENERIC = "unnamed_dynamics"


@dataclass
class CandidateFit:
    """Outcome of fitting one candidate (or several jointly): shared parameters, score, per-transient state."""

    effect: str           # label; "a+b" for a pair
    params: dict          # name -> {"median", "lo", "hi"} (physical units; "label.name" for several)
    values: dict          # name -> point estimate (the single candidate's, structure values included)
    delta_bic: float
    j_pooled: float
    sse: np.ndarray
    warm: np.ndarray
    n_evaluations: int
    effects: dict = dataclasses.field(default_factory=dict)   # effect -> values, every fitted effect
    n_new: int = 0        # parameters new to the current model (the ΔBIC penalty)
    labels: tuple = ()    # labels of the new candidates
    scales: dict = dataclasses.field(default_factory=dict)  # key of params -> {"z", "sd", "log", "sign"} (search scale)
    at_bound: list = dataclasses.field(default_factory=list)  # [{"param", "value", "bound", "side"}]: bound_flags
    cost: dict = dataclasses.field(default_factory=dict)      # stage -> {"s", "evaluations"} (module docstring)
    polish_pending: bool = False  # its refinement did not converge and its simplex polish was deferred (fit_joint)


@dataclass(frozen=True)
class SearchParam:
    """One shared parameter as the profile search sees it: bounds, log scale and a fixed sign.

    ``sign`` -1 searches a negative parameter on the log of its magnitude (a gain whose sign part 1 fixed).
    """

    name: str
    lower: float
    upper: float
    log: bool
    sign: float = 1.0


@dataclass(frozen=True)
class CandidateSpec:
    """A candidate to fit: a registered effect, optionally with data-derived search bounds and fixed values.

    Attributes
    ----------
    label : str
        Name in the diagnosis (``unnamed_dynamics@force``); the effect is the part before ``@``.
    overrides : dict
        ``{param: SearchParam}`` replacing the registry's bounds of a required parameter.
    extra : dict
        ``{param: value}`` of the effect's optional parameters held fixed (a structure found by part 1).
    reading : str
        Physical reading for the report (default: the effect's description).
    starts : dict
        ``{param: (values...)}`` added to the search grid (part 1's frequency, damping or time constant for
        a library effect's parameters of that kind: :func:`bayesdamper.diagnosis.unnamed.signature_starts`).
    poles : tuple
        ``((f [Hz], ζ), ...)``: part 1's pole pairs, starts of the global stage for an effect with a natural
        frequency and a damping ratio (:func:`global_starts`).
    thresholds : tuple
        ``(Δp [Pa], ...)``: pressures at which part 1 found the residual to set in (its dead zone in Δp), starts
        of the global stage for a threshold pressure.
    points : tuple
        ``({param: value}, ...)``: whole points added to the grid stage (a candidate's optimum in an earlier round
        of the loop, where its screen in a later round starts looking).
    """

    label: str
    overrides: dict = dataclasses.field(default_factory=dict)
    extra: dict = dataclasses.field(default_factory=dict)
    reading: str = ""
    starts: dict = dataclasses.field(default_factory=dict)
    poles: tuple = ()
    thresholds: tuple = ()
    points: tuple = ()

    @property
    def effect(self) -> str:
        return self.label.split("@", 1)[0]


def holds_generic(label: str, specs: dict) -> bool:
    """The option ``label`` (a candidate or a pair ``a+b``) holds the generic effect."""
    return any(specs[lab].effect == GENERIC for lab in label.split("+") if lab in specs)


def best_and_physical(ranked: list, specs: dict, n: int) -> list:
    """The first ``n`` of the options ``ranked`` (best first, each with its ``effect`` label) and, in their order,
    the first ``n`` of them that hold no generic effect: generic filters can take every first place, and a generic
    option is named only over the best physical ones."""
    physical = {id(c) for c in [c for c in ranked if not holds_generic(c.effect, specs)][:n]}
    return [c for i, c in enumerate(ranked) if i < n or id(c) in physical]


def search_params(spec: CandidateSpec) -> list[SearchParam]:
    """The parameters the profile search varies for ``spec``: the effect's required ones, overrides applied."""
    from bayesdamper.physics.effects import EFFECTS

    out = []
    for p in EFFECTS[spec.effect].params:
        if p.optional:
            continue
        out.append(spec.overrides.get(p.name, SearchParam(p.name, p.lower, p.upper, p.log)))
    return out


def _transform(p, x):
    return math.log(p.sign * x) if p.log else x


def _untransform(p, z):
    return p.sign * math.exp(z) if p.log else z
