"""Check valves: a mass-spring check valve with a cracking pressure for each flow direction on the flow path.

A check valve opens for one direction of flow only, so the path holds one for each direction, alike (the
parameters of :mod:`bayesdamper.physics.effects.poppet_valve`). The lift x_+ [-] of the valve that passes flow from
chamber 1 to chamber 2 (0 closed, 1 fully open) and the lift x_- of the other are damped oscillators, each driven
towards the steady opening of its own direction's pressure difference::

    d²x_±/dt² + 2 ζ_v ω_v dx_±/dt + ω_v² x_± = ω_v² s(±Δp),    s(u) = clip((u - p_c) / p_s, 0, 1)

and the path's flow goes through the valve of its direction (x = x_+, s = s(Δp) for Δp >= 0; x = x_-,
s = s(-Δp) otherwise)::

    Q = Q_O(Δp) (ε + clip(x, 0, 1)) / (ε + s)

with ε the bleed past the closed valve. On every steady plateau it is eq. (8), and after a start from rest it is the
poppet valve's response. After a reversal it is not: the flow meets its new direction's valve closed on its seat,
which opens from rest, while the valve that carried it closes with its own dynamics (the poppet valve's one lift,
driven by |Δp|, is still open then). Q is continuous where Δp changes sign (Q_O(0) = 0). Inside its span a valve
chatters when ε p_s < |Δp| + p_c, as the poppet valve does.

It is a variant of the poppet valve (:data:`VARIANT_OF`), not a candidate of its own: wherever the diagnosis selects
the poppet valve it searches the check valves in its place and keeps the better
(:func:`bayesdamper.diagnosis.basins.search_variants`). As a candidate beside it, the second valve form took the
screen's places from other library effects and gave a generic option a second valve rival it could not tell apart.
"""

from __future__ import annotations

import math

from numba import njit

from bayesdamper.physics.effects import poppet_valve
from bayesdamper.physics.effects.base import Effect
from bayesdamper.physics.effects.poppet_valve import steady_lift
from bayesdamper.physics.effects.signals import DP, Q

__all__ = ["EFFECT", "STATES", "VARIANT_OF", "flow", "initial", "state_atol"]

#: States: the lift x_+ [-] of the valve that passes flow from chamber 1 to chamber 2 and its rate [1/s], then the
#: other valve's.
STATES = ("lift", "lift_rate_per_s", "reverse_lift", "reverse_lift_rate_per_s")

EFFECT = Effect(
    name="check_valves",
    description="a mass-spring check valve with a cracking pressure for each flow direction: the flow lags the "
                "pressure, a valve rings at its own frequency once the pressure across it exceeds the cracking "
                "pressure, and after a reversal the flow meets the other direction's valve closed",
    params=poppet_valve.EFFECT.params,
    candidate=False,
)
#: The effect this one is a structural variant of (the same parameters): searched in its place where it is selected.
VARIANT_OF = "poppet_valve"


@njit(cache=True, error_model="numpy")
def flow(sig, z, p, dz):
    """Flow through the valve of the flow's direction and both lifts' derivatives (hook of
    :mod:`bayesdamper.physics.effects.signals`)."""
    w = 2.0 * math.pi * p[0]
    c = 2.0 * p[1] * w
    dp = sig[DP]
    s_fwd = steady_lift(max(dp, 0.0), p[2], p[3])  # s of each direction's own Δp (p_c >= 0)
    s_rev = steady_lift(max(-dp, 0.0), p[2], p[3])
    dz[0] = z[1]
    dz[1] = w * w * (s_fwd - z[0]) - c * z[1]
    dz[2] = z[3]
    dz[3] = w * w * (s_rev - z[2]) - c * z[3]
    if dp >= 0.0:
        x, s = z[0], s_fwd
    else:
        x, s = z[2], s_rev
    return sig[Q] * (p[4] + min(max(x, 0.0), 1.0)) / (p[4] + s)


@njit(cache=True, error_model="numpy")
def initial(sig, p, z):
    """Both valves at rest at their steady lifts (the one of the other direction closed)."""
    z[0] = steady_lift(max(sig[DP], 0.0), p[2], p[3])
    z[1] = 0.0
    z[2] = steady_lift(max(-sig[DP], 0.0), p[2], p[3])
    z[3] = 0.0


@njit(cache=True, error_model="numpy")
def state_atol(p, atol, out):
    """Tolerances of the lifts [-] and their rates [1/s]."""
    rate = 1.0e-7 * max(2.0 * math.pi * p[0], 1.0)
    out[0] = 1.0e-7
    out[1] = rate
    out[2] = 1.0e-7
    out[3] = rate
