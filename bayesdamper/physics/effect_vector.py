"""The effect vector: the fixed-slot float array through which the augmented kernel receives any combination of effects.

Every effect parameter of :data:`bayesdamper.physics.effects.EFFECTS` owns one slot of ``EFFECT_SLOTS``; an
absent effect leaves its slots at their off values. :func:`pack_effects` and :func:`unpack_effects` convert
between ``{effect: {parameter: value}}`` and the vector.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from bayesdamper.core.errors import SettingsError
from bayesdamper.physics.effects import EFFECTS, complete_effects

#: Layout of the effect vector: slot names, in order (units of the slots in parentheses):
#: friction F_C (N), c_v (N s/m), F_S (N), v_St (m/s); backlash gap (m); actuator lag τ_a (s);
#: valve τ_v (s), p_v (Pa); series compliance 1/k_s (m/N); moving mass m (kg).
EFFECT_SLOTS = ("coulomb", "viscous", "stribeck", "stribeck_v", "gap", "lag_tau", "valve_tau", "valve_p",
                "compliance", "mass")


_SLOT_PARAM = {p.slot: (e.name, p) for e in EFFECTS.values() for p in e.params if p.slot}
#: The effects that fill slots of the vector (the others run only on the composed kernel).
VECTOR_EFFECTS = tuple(n for n, e in EFFECTS.items() if e.in_fixed_vector)


def pack_effects(effects: Mapping[str, Mapping[str, float] | None] | None) -> np.ndarray:
    """Effect vector of layout :data:`EFFECT_SLOTS` from ``{effect: {param: value}}``.

    Named effects take their defaults for unspecified parameters; effects not named are off.

    Returns
    -------
    ndarray, shape (len(EFFECT_SLOTS),)
    """
    vec = np.zeros(len(EFFECT_SLOTS))
    for name, values in complete_effects(effects).items():
        if name not in VECTOR_EFFECTS:
            raise SettingsError(f"effect {name} has no slots in the fixed effect vector: use "
                                "bayesdamper.physics.compose")
        for p in EFFECTS[name].params:
            vec[EFFECT_SLOTS.index(p.slot)] = p.to_slot(values[p.name])
    return vec


def unpack_effects(vec: np.ndarray, *, keep_off: bool = False) -> dict[str, dict[str, float]]:
    """``{effect: {param: value}}`` from an effect vector (inverse of :func:`pack_effects`).

    An effect whose slots are all 0 is left out unless ``keep_off``.
    """
    vec = np.asarray(vec, dtype=float)
    if vec.shape != (len(EFFECT_SLOTS),):
        raise SettingsError(f"effect vector must have shape ({len(EFFECT_SLOTS)},), got {vec.shape}")
    out = {}
    for name, e in EFFECTS.items():
        if name not in VECTOR_EFFECTS:
            continue
        slots = [float(vec[EFFECT_SLOTS.index(p.slot)]) for p in e.params]
        if keep_off or any(s != 0.0 for s in slots):
            out[name] = {p.name: p.from_slot(s) for p, s in zip(e.params, slots, strict=True)}
    return out
