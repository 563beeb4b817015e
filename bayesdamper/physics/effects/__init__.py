"""Candidate physical effects that eq. (7) lacks: one module per effect, and their registry.

Each module defines ``EFFECT``, an :class:`Effect` naming the effect's parameters (SI units,
log-uniform prior bounds, default strength, the value that switches it off, and the slot of the
augmented effect vector it fills), plus the scalar physics the forward kernel calls. The forward
model with any combination of effects is :mod:`bayesdamper.physics.augmented`.

An effect set is a ``dict[effect name -> dict[parameter name -> value]]``; :func:`complete_effects`
fills the defaults, :func:`parse_effect_spec` reads the command-line form
``NAME[:param=value,...]``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

from bayesdamper.core.errors import SettingsError
from bayesdamper.physics.effects import actuator_lag, backlash, friction, inertia, series_compliance, valve_dynamics
from bayesdamper.physics.effects.base import Effect, EffectParam

__all__ = [
    "EFFECTS",
    "EFFECT_NAMES",
    "Effect",
    "EffectParam",
    "complete_effects",
    "get_effect",
    "parse_effect_spec",
    "parse_effect_specs",
]

#: The registry: effect name -> Effect, in a fixed order.
EFFECTS: dict[str, Effect] = {
    m.EFFECT.name: m.EFFECT
    for m in (friction, backlash, actuator_lag, valve_dynamics, series_compliance, inertia)
}
#: Names of the registered effects.
EFFECT_NAMES: tuple[str, ...] = tuple(EFFECTS)


def get_effect(name: str) -> Effect:
    """The registered effect called ``name``; SettingsError listing the valid names otherwise."""
    try:
        return EFFECTS[name]
    except KeyError:
        raise SettingsError(f"unknown effect {name!r} (valid: {', '.join(EFFECT_NAMES)})") from None


def complete_effects(effects: Mapping[str, Mapping[str, float] | None] | None) -> dict[str, dict[str, float]]:
    """Check an effect set and fill every unspecified parameter with its default.

    Parameters
    ----------
    effects : dict or None
        ``{effect name: {parameter: value}}``; a value dict may be empty or None (all defaults).

    Returns
    -------
    dict
        ``{effect name: {parameter: value}}`` with every parameter of each named effect, in the
        registry's order; empty for None.
    """
    given = dict(effects or {})
    for name in given:
        get_effect(name)
    return {name: EFFECTS[name].complete(dict(given[name] or {})) for name in EFFECT_NAMES if name in given}


def parse_effect_spec(text: str) -> tuple[str, dict[str, float]]:
    """Parse ``NAME[:param=value,...]`` into ``(name, {param: value})`` with defaults filled.

    Examples: ``friction``, ``friction:coulomb_N=150``,
    ``valve_dynamics:time_constant_s=0.05,opening_pressure_Pa=2e5``.

    Raises
    ------
    SettingsError
        One line naming the problem: unknown effect or parameter, malformed ``param=value``, a value
        that is not a number or out of its admissible range, a parameter given twice.
    """
    name, sep, rest = str(text).strip().partition(":")
    name = name.strip()
    effect = get_effect(name)
    values: dict[str, float] = {}
    if sep and not rest.strip():
        raise SettingsError(f"--effect {text!r}: nothing after ':' (expected param=value,...)")
    for item in rest.split(",") if rest.strip() else ():
        key, eq, val = item.partition("=")
        key = key.strip()
        if not eq or not key or not val.strip():
            raise SettingsError(f"--effect {text!r}: expected param=value, got {item.strip()!r}")
        if key in values:
            raise SettingsError(f"--effect {text!r}: parameter {key} given twice")
        p = effect.param(key)
        try:
            v = float(val)
        except ValueError:
            raise SettingsError(f"--effect {text!r}: {key} must be a number, got {val.strip()!r}") from None
        if math.isnan(v):
            raise SettingsError(f"--effect {text!r}: {key} must be a number, got {val.strip()!r}")
        values[key] = p.check(v, name)
    return name, effect.complete(values)


def parse_effect_specs(texts: Iterable[str] | None) -> dict[str, dict[str, float]] | None:
    """Parse repeated ``--effect`` options into an effect set (None when there are none).

    Raises SettingsError for a bad spec or an effect named twice.
    """
    out: dict[str, dict[str, float]] = {}
    for text in texts or ():
        name, values = parse_effect_spec(text)
        if name in out:
            raise SettingsError(f"--effect: effect {name} given twice")
        out[name] = values
    return complete_effects(out) if out else None
