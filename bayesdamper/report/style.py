"""The look shared by every figure: display units, colours, markers and labels.

Display units: flow rate in 10^-6 m^3/s, pressure in MPa, force in kN, piston speed in mm/s. The
multipliers from SI are the ``*_DISPLAY`` constants below, which tests use to read plotted data back.

Colours and markers are shared by all figures: colour = flow direction (12: Δp > 0, 21: Δp < 0),
marker = kind of velocity step (from rest or reversal). Figures are built without pyplot, so plotting
leaves no global state behind.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

#: Multiplier from m^3/s to the displayed flow-rate unit, 10^-6 m^3/s.
FLOW_DISPLAY = 1e6
#: Multiplier from Pa to the displayed pressure unit, MPa.
PRESSURE_DISPLAY = 1e-6
#: Multiplier from N to the displayed force unit, kN.
FORCE_DISPLAY = 1e-3
#: Multiplier from m/s to the displayed piston-speed unit, mm/s.
SPEED_DISPLAY = 1e3
#: Half-width of the Figure 3 band about the fitted curve, in standard errors of the mean curve.
STATIC_BAND_SE = 2.0
#: Colour and label of each flow direction (sign of Δp after the step).
DIRECTION_STYLE = {
    1: {"color": "C0", "label": "12 (Δp > 0)"},
    -1: {"color": "C3", "label": "21 (Δp < 0)"},
}
#: Marker of each kind of velocity step.
KIND_MARKER = {"initial": "^", "reversal": "o"}
#: Colour of transients whose sampler did not converge.
NOT_CONVERGED_COLOR = "0.6"
#: Axis label and display multiplier of each sampled parameter (unknown names: name, multiplier 1).
PARAMETER_LABELS = {
    "alpha_V": ("α_V [-]", 1.0),
    "p_R_Pa": ("p_R [MPa]", PRESSURE_DISPLAY),
    "phi": ("φ, AR(1) [-]", 1.0),
    "dp0_Pa": ("Δp at the step [kPa]", 1e-3),
}


def _figure(figsize: tuple[float, float], layout: str | None = "constrained"):
    from matplotlib.figure import Figure

    return Figure(figsize=figsize, layout=layout)


def _pct(mass: float) -> str:
    return f"{100 * mass:.0f}%"


def _param_label(name: str) -> tuple[str, float]:
    return PARAMETER_LABELS.get(name, (name, 1.0))


# --------------------------------------------------------------------------------------- Figure 9
def _plain_log_formatter(**kwargs):
    """Log-axis tick labels as plain numbers, on the ticks matplotlib's LogFormatter would label."""
    from matplotlib.ticker import LogFormatter

    class PlainLogFormatter(LogFormatter):
        def __call__(self, x, pos=None):
            return f"{x:g}" if super().__call__(x, pos) else ""

    return PlainLogFormatter(**kwargs)


def _groups(entries: Sequence[Mapping]) -> list[tuple[int, str]]:
    present = {(int(e["direction"]), str(e["kind"])) for e in entries}
    order = [(1, "initial"), (1, "reversal"), (-1, "initial"), (-1, "reversal")]
    return [g for g in order if g in present] + sorted(present - set(order))
