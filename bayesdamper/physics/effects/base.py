"""The description of one candidate effect: its parameters, their units and priors.

An :class:`Effect` is pure metadata: name, one-line physical reading and an ordered tuple of
:class:`EffectParam`. The physics lives in the effect's own module (the numba hooks the composed kernel of
:mod:`bayesdamper.physics.compose` calls).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from bayesdamper.core.errors import SettingsError

__all__ = ["Effect", "EffectParam"]


@dataclass(frozen=True)
class EffectParam:
    """One parameter of an effect, in SI units.

    Attributes
    ----------
    name : str
        Name used in outputs and on the command line, unit suffixed (``coulomb_N``).
    unit : str
        Physical unit.
    lower, upper : float
        Prior bounds [unit]; the prior is log-uniform when ``log`` (then ``lower > 0``). A parameter
        with ``lower < 0`` is signed (an offset, a gain): negative values are admissible.
    default : float
        Value taken when the effect is switched on without this parameter [unit]: a clearly
        visible but plausible value on rig A, or ``off`` for an optional parameter.
    log : bool
        Log-uniform (true) or uniform (false) prior between the bounds.
    description : str
        One-line physical meaning.
    optional : bool
        The diagnosis may leave this parameter at ``off`` and fit only the others.
    off : float
        Value at which the parameter has no effect [unit] (``inf`` for a stiffness).
    reciprocal : bool
        A stiffness whose hook uses ``1 / value`` (a compliance): admissible values are > 0, ``inf`` = off.
    inf_ok : bool
        ``inf`` is admissible (an off value: an infinitely fast servo, an infinite span).
    physical_limits : bool
        The bounds are physical limits (a polytropic exponent between isothermal 1 and adiabatic 1.4): an estimate
        on one is the physics at that limit, not a sign that the form does not fit.
    """

    name: str
    unit: str
    lower: float
    upper: float
    default: float
    log: bool
    description: str
    optional: bool = False
    off: float = 0.0
    reciprocal: bool = False
    inf_ok: bool = False
    physical_limits: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lower) and math.isfinite(self.upper) and self.lower < self.upper):
            raise SettingsError(f"effect parameter {self.name}: need finite lower < upper")
        if self.log and self.lower <= 0:
            raise SettingsError(f"effect parameter {self.name}: a log-uniform prior needs lower > 0")
        if not (self.lower <= self.default <= self.upper or self.default == self.off):
            raise SettingsError(f"effect parameter {self.name}: default outside the prior and not off")

    @property
    def signed(self) -> bool:
        """Negative values are admissible (``lower < 0``)."""
        return self.lower < 0.0

    def check(self, value: float, effect: str) -> float:
        """Return ``value`` as a float if it is admissible, else raise a one-line SettingsError.

        Admissible: finite and >= 0 (any finite value for a signed parameter); for a reciprocal parameter
        > 0 (``inf`` = off).
        """
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise SettingsError(f"effect {effect}: {self.name} must be a number, got {value!r}") from None
        if self.reciprocal:
            if not v > 0:
                raise SettingsError(f"effect {effect}: {self.name} must be > 0 [{self.unit}] (inf = off), "
                                    f"got {value!r}")
        elif self.inf_ok and v == math.inf:
            pass
        elif self.signed:
            if not math.isfinite(v):
                raise SettingsError(f"effect {effect}: {self.name} must be finite [{self.unit}], got {value!r}")
        elif not (math.isfinite(v) and v >= 0):
            raise SettingsError(f"effect {effect}: {self.name} must be finite and >= 0 [{self.unit}], "
                                f"got {value!r}")
        return v


@dataclass(frozen=True)
class Effect:
    """A candidate physical effect that eq. (7) lacks.

    Attributes
    ----------
    name : str
        Name used in outputs and on the command line (``friction``, ``backlash``, ...).
    description : str
        One-line physical reading.
    params : tuple of EffectParam
        The effect's parameters, all shared across the tests of a data set.
    candidate : bool
        The diagnosis offers it as an explanation of a residual (false for a base-model variant kept for the
        model comparison only, such as the constant bulk modulus).
    """

    name: str
    description: str
    params: tuple[EffectParam, ...]
    candidate: bool = True

    @property
    def param_names(self) -> tuple[str, ...]:
        """Names of the parameters, in order."""
        return tuple(p.name for p in self.params)

    @property
    def required(self) -> tuple[EffectParam, ...]:
        """The parameters that are not optional (what a minimal fit of the effect varies)."""
        return tuple(p for p in self.params if not p.optional)

    def param(self, name: str) -> EffectParam:
        """The parameter called ``name``; SettingsError naming the valid ones if there is none."""
        for p in self.params:
            if p.name == name:
                return p
        raise SettingsError(f"effect {self.name}: unknown parameter {name!r} "
                            f"(valid: {', '.join(self.param_names)})")

    def defaults(self) -> dict[str, float]:
        """``{param: default}``: the effect switched on at its default strength."""
        return {p.name: p.default for p in self.params}

    def off_values(self) -> dict[str, float]:
        """``{param: off}``: the effect present but without any influence (eq. (7) exactly)."""
        return {p.name: p.off for p in self.params}

    def complete(self, values: dict[str, float] | None = None) -> dict[str, float]:
        """All parameters: the given values (checked) with the defaults for the rest."""
        out = self.defaults()
        for k, v in (values or {}).items():
            out[k] = self.param(k).check(v, self.name)
        return out
