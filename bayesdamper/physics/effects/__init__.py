"""Candidate physical effects that eq. (7) lacks: one module per effect, and their registry.

Each module defines ``EFFECT``, an :class:`Effect` naming the effect's parameters (SI units, prior
bounds, default strength, the value that switches it off), its extra states and the numba hooks that say
where it acts (protocol: :mod:`bayesdamper.physics.effects.signals`). The registry is every module of
this package that defines ``EFFECT``: adding an effect is adding a module. Any combination of effects
runs on the composed kernel (:mod:`bayesdamper.physics.compose`), driven by any displacement input.

An effect set is a ``dict[effect name -> dict[parameter name -> value]]``; :func:`complete_effects`
fills the defaults, :func:`parse_effect_spec` reads the command-line form
``NAME[:param=value,...]``.
"""

from __future__ import annotations

import importlib
import math
import pkgutil
from collections.abc import Iterable, Mapping
from types import ModuleType

from bayesdamper.core.errors import SettingsError
from bayesdamper.physics.effects.base import Effect, EffectParam

__all__ = [
    "EFFECTS",
    "EFFECT_MODULES",
    "EFFECT_NAMES",
    "Effect",
    "EffectParam",
    "complete_effects",
    "get_effect",
    "parse_effect_spec",
    "parse_effect_specs",
]

#: The first library effects, in this order (outputs and the kernel's layout keep it); the others follow by name.
_FIRST = ("friction", "backlash", "actuator_lag", "valve_dynamics", "series_compliance", "inertia")


def _discover() -> dict[str, ModuleType]:
    found = {}
    for info in pkgutil.iter_modules(__path__):
        if info.name in ("base", "signals") or info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{__name__}.{info.name}")
        effect = getattr(mod, "EFFECT", None)
        if isinstance(effect, Effect):
            if effect.name in found:  # pragma: no cover - a packaging error
                raise ImportError(f"two effect modules are called {effect.name}")
            found[effect.name] = mod
    order = [n for n in _FIRST if n in found] + sorted(n for n in found if n not in _FIRST)
    return {n: found[n] for n in order}


#: The registry's modules: effect name -> module, :data:`_FIRST` first, then by name.
EFFECT_MODULES: dict[str, ModuleType] = _discover()
#: The registry: effect name -> Effect, in the order of :data:`EFFECT_MODULES`.
EFFECTS: dict[str, Effect] = {n: m.EFFECT for n, m in EFFECT_MODULES.items()}
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
