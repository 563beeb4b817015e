"""Unnamed dynamics: a generic second-order filter of a model signal, added where it fits best.

For a residual whose form no named effect holds, the diagnosis (part 1,
:mod:`bayesdamper.diagnosis.sysid`) identifies a driver, a static law and poles; this effect adds them
to the model so they are fitted with intervals like any other effect::

    d²w/dt² + 2 ζ ω dw/dt + ω² w = ω² L(u),    ω = 2π f

u is the driver (``driver``: 0 Δp [Pa], 1 orifice flow Q_O [m^3/s], 2 piston displacement y_P [m],
3 piston velocity v_P [m/s]); L the static law (``law``: 0 linear, 1 |u|, 2 dead zone
sign(u) max(|u| - θ, 0), 3 smooth sign tanh(u/θ)). The output o is g w (``mode`` 0: a low-pass with
static gain g) or g (w - L(u)) (``mode`` 1: the transient part only, zero in steady state, so the
plateaus and stage 1 are untouched); it acts on the force (``placement`` 0: F += o [N]) or on the flow
path (1: Q += o [m^3/s]). g is in output units per driver unit; the structure parameters (driver, law,
mode, placement) are fixed by the diagnosis, not fitted. It starts at rest at its input:
w = L(u(t0)), dw/dt = 0.
"""

from __future__ import annotations

import math

from numba import njit

from bayesdamper.physics.effects.base import Effect, EffectParam
from bayesdamper.physics.effects.signals import (
    DP,
    FORCE_READS_ANY,
    FORCE_READS_MOTION,
    FORCE_READS_STATE,
    QO,
    VP,
    YP,
    Q,
)

__all__ = ["DRIVERS", "EFFECT", "LAWS", "MODES", "PLACEMENTS", "STATES", "derivatives", "flow", "force", "force_acts",
           "force_reads", "initial", "state_atol"]

#: Codes of the structure parameters (names used in reports).
DRIVERS = ("dp", "q", "y", "v")
LAWS = ("linear", "abs", "deadzone", "sign")
PLACEMENTS = ("force", "flow")
MODES = ("low-pass", "transient")
#: States: filter output w and its rate (driver units, per second).
STATES = ("w", "w_rate")

EFFECT = Effect(
    name="unnamed_dynamics",
    description="dynamics no named effect holds: a second-order filter of a model signal, identified from the "
                "residual",
    params=(
        EffectParam("gain", "output/driver", -1.0e12, 1.0e12, 0.0, False, "static gain g of the filter"),
        EffectParam("natural_frequency_Hz", "Hz", 0.05, 200.0, 1.7, True, "natural frequency f"),
        EffectParam("damping_ratio", "-", 0.01, 3.0, 0.25, True, "damping ratio ζ"),
        EffectParam("threshold", "driver unit", 0.0, 1.0e7, 0.0, False, "dead-zone or sign threshold θ",
                    optional=True),
        EffectParam("driver", "-", 0.0, 3.0, 0.0, False, "driver code (0 Δp, 1 Q_O, 2 y_P, 3 v_P)", optional=True),
        EffectParam("law", "-", 0.0, 3.0, 0.0, False, "law code (0 linear, 1 |u|, 2 dead zone, 3 sign)",
                    optional=True),
        EffectParam("placement", "-", 0.0, 1.0, 0.0, False, "0 force output, 1 flow path", optional=True),
        EffectParam("mode", "-", 0.0, 1.0, 0.0, False, "0 low-pass output g w, 1 transient output g (w - L(u))",
                    optional=True),
    ),
)


@njit(cache=True, error_model="numpy")
def _input(sig, p):
    d = int(p[4])
    u = sig[DP] if d == 0 else (sig[QO] if d == 1 else (sig[YP] if d == 2 else sig[VP]))
    law = int(p[5])
    if law == 1:
        return abs(u)
    if law == 2:
        return math.copysign(max(abs(u) - p[3], 0.0), u)
    if law == 3:
        return math.tanh(u / p[3]) if p[3] > 0.0 else (1.0 if u > 0.0 else (-1.0 if u < 0.0 else 0.0))
    return u


@njit(cache=True, error_model="numpy")
def _output(sig, z, p):
    return p[0] * (z[0] - _input(sig, p)) if int(p[7]) == 1 else p[0] * z[0]


@njit(cache=True, error_model="numpy")
def flow(sig, z, p, dz):
    """Q + o on the flow path (placement 1)."""
    return sig[Q] + _output(sig, z, p) if int(p[6]) == 1 else sig[Q]


@njit(cache=True, error_model="numpy")
def force(sig, z, p):
    """o on the force (placement 0)."""
    return _output(sig, z, p) if int(p[6]) == 0 else 0.0


@njit(cache=True, error_model="numpy")
def force_acts(p):
    """Only at placement 0."""
    return int(p[6]) == 0


@njit(cache=True, error_model="numpy")
def force_reads(p):
    """The low-pass output g w reads the state alone; the transient one its driver besides: Δp, the motion (y_P,
    v_P) or the orifice flow (any signal)."""
    d = int(p[4])
    if int(p[7]) == 0 or d == 0:
        return FORCE_READS_STATE
    return FORCE_READS_MOTION if d >= 2 else FORCE_READS_ANY


@njit(cache=True, error_model="numpy")
def derivatives(sig, z, p, dz):
    """The filter's state derivatives."""
    w = 2.0 * math.pi * p[1]
    dz[0] = z[1]
    dz[1] = w * w * (_input(sig, p) - z[0]) - 2.0 * p[2] * w * z[1]


@njit(cache=True, error_model="numpy")
def initial(sig, p, z):
    """At rest at its input."""
    z[0] = _input(sig, p)
    z[1] = 0.0


@njit(cache=True, error_model="numpy")
def state_atol(p, atol, out):
    """Tolerances in the driver's unit: Δp's for Δp, 1e-13 m^3/s, 1e-12 m, 1e-10 m/s."""
    d = int(p[4])
    out[0] = atol if d == 0 else (1.0e-13 if d == 1 else (1.0e-12 if d == 2 else 1.0e-10))
    out[1] = out[0] * max(2.0 * math.pi * p[1], 1.0)
