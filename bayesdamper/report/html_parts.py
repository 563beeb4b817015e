"""Small pieces of the HTML report shared by its two-stage and whole-record sections: escaping, number and
interval formatting, tables, figure blocks and the drift table. Imports nothing of the report itself.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from html import escape
from pathlib import Path

#: Display scale and unit of the parameters in the tables.
_PARAMS = {"alpha_V": ("α<sub>V</sub> [-]", 1.0), "p_R_Pa": ("p<sub>R</sub> [kPa]", 1e-3),
           "phi": ("φ [-]", 1.0)}


def _e(x: object) -> str:
    return escape(str(x), quote=True)


def _num(x: object, fmt: str = ".4g", scale: float = 1.0) -> str:
    """A number for a table cell; '–' for a missing value, '∞' for an infinite one."""
    if x is None or isinstance(x, bool) or not isinstance(x, int | float):
        return "–" if x is None else _e(x)
    v = float(x) * scale
    if math.isnan(v):
        return "nan"
    if math.isinf(v):
        return "∞" if v > 0 else "−∞"
    return _e(format(round(v), fmt) if fmt.endswith("d") else format(v, fmt))


def _interval(d: object, fmt: str = ".4g", scale: float = 1.0) -> str:
    """``median [lo, hi]`` of a ``{median, lo, hi}`` dict."""
    if not isinstance(d, Mapping) or "median" not in d:
        return _value(d)
    lo, hi = _num(d.get("lo"), fmt, scale), _num(d.get("hi"), fmt, scale)
    return f"{_num(d['median'], fmt, scale)} [{lo}, {hi}]"


def _yes(flag: object, yes: str = "yes", no: str = "no") -> str:
    return f'<span class="ok">{yes}</span>' if flag else f'<span class="no">{no}</span>'


def _value(v: object) -> str:
    """Any JSON value, compactly (numbers formatted, nested values as JSON)."""
    if isinstance(v, bool):
        return "yes" if v else "no"
    if v is None or isinstance(v, int | float):
        return _num(v)
    if isinstance(v, str):
        return _e(v)
    return f"<code>{_e(json.dumps(v, default=str, allow_nan=True))}</code>"


def _table(header: Iterable[str], rows: Iterable[Iterable[str]], left: int = 1,
           classes: Iterable[str] | None = None) -> str:
    """An HTML table; cells are already HTML. The first ``left`` columns are left-aligned."""
    def cells(tag: str, items: Iterable[str]) -> str:
        return "".join(f'<{tag} class="l">{c}</{tag}>' if i < left else f"<{tag}>{c}</{tag}>"
                       for i, c in enumerate(items))

    classes = list(classes) if classes is not None else []
    body = []
    for i, row in enumerate(rows):
        cls = classes[i] if i < len(classes) else ""
        body.append((f'<tr class="{cls}">' if cls else "<tr>") + cells("td", row) + "</tr>")
    return f"<table><thead><tr>{cells('th', header)}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _kv_table(items: Mapping) -> str:
    return _table(["", "value"], ([_e(k), _value(v)] for k, v in items.items()))


def _figures(out_dir: Path, paths: Iterable[str] | None, caption: str, missing: str) -> str:
    """``<figure>`` blocks for the PNGs among ``paths`` that exist in ``out_dir``, with links to the rest."""
    paths = [str(p) for p in (paths or [])]
    present = [p for p in paths if (out_dir / p).is_file()]
    pngs = [p for p in present if p.lower().endswith((".png", ".svg", ".jpg", ".jpeg"))]
    if not pngs:
        return f'<p class="note">{_e(missing)}</p>'
    out = []
    for p in pngs:
        stem = p.rsplit(".", 1)[0]
        others = [q for q in present if q != p and q.rsplit(".", 1)[0] == stem]
        links = "".join(f' <a href="{_e(q)}">{_e(q.rsplit(".", 1)[1].upper())}</a>' for q in others)
        out.append(f'<figure><img src="{_e(p)}" alt="{_e(caption)}" loading="lazy">'
                   f"<figcaption>{_e(caption)} ({_e(p)}{')' if not links else ';' + links + ')'}"
                   "</figcaption></figure>")
    return "".join(out)


def _damper_table(d: Mapping) -> str:
    """The damper's known constants (``DamperConstants`` as a dict), with a sentence saying where from."""
    return ("<p>The damper's known constants (from <code>damper.toml</code>):</p>"
            + _table(["constant", "value"], [
                ["piston area A<sub>P</sub> [m<sup>2</sup>]", _num(d.get("piston_area"))],
                ["chamber volume V<sub>0,1</sub> [m<sup>3</sup>]", _num(d.get("chamber_volume_1"))],
                ["chamber volume V<sub>0,2</sub> [m<sup>3</sup>]", _num(d.get("chamber_volume_2"))],
                ["liquid bulk modulus B<sub>0</sub> [Pa]", _num(d.get("liquid_bulk_modulus"))]]))


def _drift_table(drift: Mapping | None, mass: float) -> str:
    if not drift:
        return '<p class="note">No drift fit (it needs at least three transients at two or more speeds).</p>'
    rows = []
    for name, d in drift.items():
        label, scale = _PARAMS.get(name, (_e(name), 1.0))
        rows.append([f"{label} (all)", _interval(d.get("slope_per_m_s"), ".4g", scale * 1e-3),
                     _yes(d.get("credible_nonzero")), _num(d.get("intrinsic_scatter"), ".3g", scale),
                     _num(d.get("n_transients"), "d")])
        for direction, dd in (d.get("by_direction") or {}).items():
            rows.append([f"{label} (direction {int(direction):+d})",
                         _interval(dd.get("slope_per_m_s"), ".4g", scale * 1e-3),
                         _yes(dd.get("credible_nonzero")), _num(dd.get("intrinsic_scatter"), ".3g", scale),
                         ""])
    return _table(["parameter", f"slope per mm/s, median [{mass:.0%}]", "credibly ≠ 0", "intrinsic scatter",
                   "transients"], rows, left=1)
