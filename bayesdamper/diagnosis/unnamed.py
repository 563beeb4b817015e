"""Candidates for dynamics no named effect holds, built from the residual's signature.

Part 1 (:mod:`bayesdamper.diagnosis.signature`) identifies the residual's driver, static law and poles
from the calibrated model's own signals. This module turns that into candidates of the generic effect
:mod:`bayesdamper.physics.effects.unnamed_dynamics` — a unit-DC-gain second-order filter of the driver
through the law — placed on the force output or on the flow path, so that an effect nobody named is
added to the model, fitted with intervals and reported like any other.

Two output modes are tried on each placement: the low-pass g w (its static gain moves the plateaus, so
it suits a residual that does not settle) and the transient g (w - L(u)) (zero in steady state: dynamics
that the plateaus, hence stage 1, cannot see — the usual case for a residual after a velocity step).
Search bounds come from the signature: the natural frequency within a factor 2 of the identified one,
the damping within a factor 4; the low-pass gain's magnitude within a factor 30 of the identified DC
gain with its sign held; the transient gain signed, up to 30 times the ratio of the residual's rms to
the law's rms. On the flow path a force gain is converted with the small-signal relation
ΔF ≈ -A_P ΔQ / (dQ_O/dΔp) at the median |Δp| of the transients (the orifice's static stiffness).
Real poles map to an overdamped pair: f = 1/(2π sqrt(τ_1 τ_2)), ζ = (τ_1 + τ_2)/(2 sqrt(τ_1 τ_2)).
"""

from __future__ import annotations

import math

from bayesdamper.diagnosis.candidates import CandidateSpec, SearchParam
from bayesdamper.physics.effects import unnamed_dynamics as _ud

__all__ = ["effect_reading", "library_candidates", "signature_poles", "signature_starts", "signature_thresholds",
           "unnamed_candidates"]

#: The signature's drivers the generic effect can take (time since the step is no model signal).
_DRIVER_CODE = {"dp": 0, "q": 1, "y": 2}
_LAW_CODE = {"linear": 0, "abs": 1, "deadzone": 2, "sign": 3}
_DRIVER_TEXT = {"dp": "Δp", "q": "the orifice flow", "y": "the piston displacement", "v": "the piston velocity"}
_LAW_TEXT = {"linear": "", "abs": " (magnitude)", "deadzone": " (dead zone)", "sign": " (sign)"}
#: Factors of the search boxes around part 1's estimates (module docstring).
FREQ_FACTOR, DAMPING_FACTOR, GAIN_FACTOR = 2.0, 4.0, 30.0


def _second_order(poles: list[dict]) -> tuple[float, float] | None:
    """(f [Hz], ζ) of the dominant pair of part 1's poles: the first complex pole, else the two slowest real ones.
    A single real pole τ is paired with one ten times faster, so its pair is f = √10 / (2π τ) at ζ = 1.1 √10 / 2
    ≈ 1.74 whatever τ is: a heavily damped, lag-like start, not a measured damping."""
    for p in poles:  # sysid's PoleEstimate: kind "oscillatory" (a pair) or "real"
        if p.get("kind") != "real" and p.get("frequency_hz"):
            return float(p["frequency_hz"]), float(p.get("damping") or 0.2)
    taus = sorted((float(p["time_constant_s"]) for p in poles if p.get("time_constant_s")), reverse=True)
    if not taus:
        return None
    t1, t2 = (taus[0], taus[1]) if len(taus) > 1 else (taus[0], taus[0] / 10.0)
    g = math.sqrt(t1 * t2)
    return 1.0 / (2.0 * math.pi * g), (t1 + t2) / (2.0 * g)


def signature_starts(signature: dict) -> dict[str, list[float]]:
    """Part 1's time scales as search starts: ``{"Hz": [...], "damping": [...], "s": [...]}``.

    An oscillatory pole gives its frequency, damping and period / 2π; a real pole its time constant and
    1 / (2π τ). Empty when part 1 identified nothing.
    """
    fit = signature.get("fit") or {}
    if signature.get("verdict") in (None, "none", "not identified"):
        return {}
    out: dict[str, list[float]] = {"Hz": [], "damping": [], "s": []}
    for p in fit.get("poles") or []:
        if p.get("kind") != "real" and p.get("frequency_hz"):
            f = float(p["frequency_hz"])
            out["Hz"].append(f)
            out["s"].append(1.0 / (2.0 * math.pi * f))
            if p.get("damping"):
                out["damping"].append(float(p["damping"]))
        elif p.get("time_constant_s"):
            tau = float(p["time_constant_s"])
            out["s"].append(tau)
            out["Hz"].append(1.0 / (2.0 * math.pi * tau))
    return {k: v for k, v in out.items() if v}


def signature_poles(signature: dict) -> list[tuple[float, float]]:
    """Part 1's poles as (f [Hz], ζ) pairs: each oscillatory pair, and the overdamped pair of the real poles
    (:func:`_second_order` of the real poles alone). Empty when part 1 identified nothing."""
    fit = signature.get("fit") or {}
    if signature.get("verdict") in (None, "none", "not identified"):
        return []
    poles = list(fit.get("poles") or [])
    out = [(float(p["frequency_hz"]), float(p["damping"])) for p in poles
           if p.get("kind") != "real" and p.get("frequency_hz") and p.get("damping")]
    real = _second_order([p for p in poles if p.get("kind") == "real"])
    if real is not None:
        out.append(real)
    return out


def signature_thresholds(signature: dict) -> list[float]:
    """The Δp [Pa] at which part 1 found the residual to set in: its dead zone's threshold when the residual is
    driven by Δp through a dead zone (the residual's onset in |Δp|), else nothing."""
    fit = signature.get("fit") or {}
    if signature.get("verdict") in (None, "none", "not identified") or fit.get("driver") != "dp" \
            or fit.get("law") != "deadzone" or not fit.get("threshold"):
        return []
    return [abs(float(fit["threshold"]))]


#: The load-cell offset effect and its parameter, started at stage 1's offset (:func:`library_candidates`).
OFFSET, OFFSET_PARAM = "load_cell_offset", "offset_N"


def library_candidates(names: list[str], signature: dict, offset_n: float | None = None) -> list[CandidateSpec]:
    """The library's effects as candidates, their frequency, damping-ratio and time-constant parameters
    started also at part 1's values (:func:`signature_starts`): a coarse grid alone misses the narrow
    optimum of a lightly damped valve. An effect with narrow-basin parameters
    (:func:`bayesdamper.diagnosis.candidates.narrow_kind`) also takes part 1's pole pairs (:func:`signature_poles`)
    and the residual's onset in Δp (:func:`signature_thresholds`) for the search's global stage.

    ``offset_n``: the constant force offset [N] stage 1 found in the plateaus, or the plateaus' estimate of one
    (:meth:`bayesdamper.inference.stage1.StaticFit.offset_force`,
    :func:`bayesdamper.inference.stage1.offset_estimate`), a start of ``load_cell_offset``: the grid of a
    one-parameter effect has six points over its range (±1, ±3, ±5 kN for the offset), and an offset of a few hundred
    newtons lies between them, where a screen by the grid alone cannot find it."""
    from bayesdamper.diagnosis.candidates import narrow_kind
    from bayesdamper.physics.effects import EFFECTS

    found = signature_starts(signature)
    poles, onsets = tuple(signature_poles(signature)), tuple(signature_thresholds(signature))
    out = []
    for name in names:
        starts = {}
        kinds = set()
        for prm in EFFECTS[name].params:
            kind = "Hz" if prm.unit == "Hz" else "damping" if "damping_ratio" in prm.name else \
                "s" if prm.unit == "s" else None
            if kind in found and not prm.optional:
                starts[prm.name] = tuple(found[kind])
            if not prm.optional:
                kinds.add(narrow_kind(name, prm.name))
            if name == OFFSET and prm.name == OFFSET_PARAM and offset_n is not None and math.isfinite(offset_n):
                starts[prm.name] = (float(offset_n),)
        out.append(CandidateSpec(name, starts=starts,
                                 poles=poles if kinds & {"frequency", "damping"} else (),
                                 thresholds=onsets if "threshold" in kinds else ()))
    return out


#: Drivers also tried on the flow path (transient mode, linear law) with part 1's poles when part 1 chose
#: another: the model signals flow-path dynamics are driven by (a fluid inertance, a valve). Part 1 fits the
#: residual linearly on the *baseline's* signals; when that baseline is far off (the reference inertance case:
#: J 0.35, α_V and p_R at their bounds) its driver can be a kinematic one (there |y_P|), while the joint refit
#: of a candidate re-calibrates (α_V, p_R) with the effect in place.
FLOW_DRIVERS = ("dp", "q")


def unnamed_candidates(signature: dict, area: float, flow_slope: float, gain_scale: float,
                       other_scales: dict | None = None) -> list[CandidateSpec]:
    """Candidates of the generic effect from part 1's signature (empty when there is nothing to add).

    Parameters
    ----------
    signature : dict
        :func:`bayesdamper.diagnosis.signature.residual_signature`'s result.
    area : float
        A_P [m^2].
    flow_slope : float
        dQ_O/dΔp at the median |Δp| of the transients [m^3/(s Pa)].
    gain_scale : float
        rms of the residual over rms of the law applied to the driver [N per driver unit] (transient mode).
    other_scales : dict, optional
        ``{driver: rms of the residual / rms of the driver}`` for :data:`FLOW_DRIVERS` (one more flow-path
        transient candidate, linear law, for each driver other than part 1's).
    """
    fit = signature.get("fit")
    if not fit or signature.get("verdict") in (None, "none", "not identified"):
        return []
    driver, law = fit.get("driver"), fit.get("law")
    if driver not in _DRIVER_CODE or law not in _LAW_CODE or not fit.get("dc_gain"):
        return []
    pair = _second_order(list(fit.get("poles") or []))
    if pair is None:
        return []
    f, zeta = pair
    lo_f, hi_f = max(f / FREQ_FACTOR, 0.05), min(f * FREQ_FACTOR, 200.0)
    lo_z, hi_z = max(zeta / DAMPING_FACTOR, 0.01), min(zeta * DAMPING_FACTOR, 3.0)
    threshold = fit.get("threshold") if law == "deadzone" else fit.get("eps") if law == "sign" else 0.0
    extra = {"driver": float(_DRIVER_CODE[driver]), "law": float(_LAW_CODE[law]),
             "threshold": float(threshold or 0.0)}
    to_flow = -flow_slope / area
    dynamics = {"natural_frequency_Hz": SearchParam("natural_frequency_Hz", lo_f, hi_f, True),
                "damping_ratio": SearchParam("damping_ratio", lo_z, hi_z, True)}
    # the searches also start at part 1's estimate: its poles, and a gain of its DC gain (low-pass) or of the
    # rms scale of the residual over the driver's law, either sign (transient); the boxes' coarse grid (3 points
    # per axis: 0 and +-30 times the scale for a transient gain) can miss a narrow optimum
    poles = {"natural_frequency_Hz": (f,), "damping_ratio": (zeta,)}
    out = []
    for placement, unit in (("force", 1.0), ("flow", to_flow)):
        where = f"acting on the {placement}" + (" path" if placement == "flow" else "")
        for mode in _ud.MODES:
            if mode == "low-pass":
                gain = float(fit["dc_gain"]) * unit
                if not (math.isfinite(gain) and gain != 0.0):
                    continue
                sign = math.copysign(1.0, gain)
                g = SearchParam("gain", sign * abs(gain) / GAIN_FACTOR, sign * abs(gain) * GAIN_FACTOR, True, sign)
                g0 = (gain,)
            else:
                top = GAIN_FACTOR * gain_scale * abs(unit)
                if not (math.isfinite(top) and top > 0.0):
                    continue
                g = SearchParam("gain", -top, top, False)
                g0 = (-top / GAIN_FACTOR, top / GAIN_FACTOR)
            code = {"placement": float(_ud.PLACEMENTS.index(placement)), "mode": float(_ud.MODES.index(mode))}
            out.append(CandidateSpec(f"unnamed_dynamics@{placement}:{mode}", {"gain": g, **dynamics},
                                     {**extra, **code},
                                     f"driven by {_DRIVER_TEXT[driver]}{_LAW_TEXT[law]}, {where} ({mode})",
                                     {"gain": g0, **poles}))
    for other, scale in (other_scales or {}).items():
        top = GAIN_FACTOR * scale * abs(to_flow)
        if other == driver or other not in FLOW_DRIVERS or not (math.isfinite(top) and top > 0.0):
            continue
        out.append(CandidateSpec(f"unnamed_dynamics@flow:transient:{other}",
                                 {"gain": SearchParam("gain", -top, top, False), **dynamics},
                                 {"driver": float(_DRIVER_CODE[other]), "law": 0.0, "threshold": 0.0,
                                  "placement": 1.0, "mode": float(_ud.MODES.index("transient"))},
                                 f"driven by {_DRIVER_TEXT[other]}, acting on the flow path (transient)",
                                 {"gain": (-top / GAIN_FACTOR, top / GAIN_FACTOR), **poles}))
    return out


def effect_reading(label: str, values: dict, description: str) -> str:
    """One line on a selected effect; for the generic effect its frequency, damping, driver and placement."""
    if not label.startswith("unnamed_dynamics"):
        return description
    driver = _ud.DRIVERS[int(values.get("driver", 0))]
    law = _ud.LAWS[int(values.get("law", 0))]
    where = _ud.PLACEMENTS[int(values.get("placement", 0))]
    mode = _ud.MODES[int(values.get("mode", 0))]
    return (f"unnamed dynamics: {values['natural_frequency_Hz']:.2f} Hz, damping {values['damping_ratio']:.2f}, "
            f"driven by {_DRIVER_TEXT[driver]}{_LAW_TEXT[law]}, acting on the {where}"
            + (" path" if where == "flow" else "") + f" ({mode})")
