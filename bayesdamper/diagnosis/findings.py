"""The diagnosis's findings as report lines: parameters that end on a bound of their search and the test speeds
that got worse after the selected effects were added (the data of :mod:`bayesdamper.diagnosis.summary`)."""

from __future__ import annotations

__all__ = ["findings_text"]


def findings_text(diagnosis: dict) -> list[str]:
    """The findings as report lines: each selected effect's parameter on its bound
    (:func:`bayesdamper.diagnosis.summary.bound_findings`), and
    which test speeds (and kinds of step) got worse after the selected effects were added, or that none did
    (:func:`bayesdamper.diagnosis.summary.j_by_speed`). Nothing on speeds when no effect was selected."""
    lines = [f["text"] + "." for f in diagnosis.get("findings") or []]
    rows = diagnosis.get("J_by_speed") or []
    if not diagnosis.get("selected") or not rows:
        return lines
    added = ", ".join(diagnosis["selected"])

    def fmt(r, kind=False):
        return (f"{r['speed_mm_s']:.2f} mm/s" + (f" ({r['kind']})" if kind else "")
                + f" ({r['J_before']:.4f} -> {r['J_after']:.4f})")

    worse = [r for r in rows if r["kind"] == "all" and r["worse"]]
    worse_speeds = {r["speed_mm_s"] for r in worse}
    by_kind = [r for r in rows if r["kind"] != "all" and r["worse"] and r["speed_mm_s"] not in worse_speeds]
    if worse:
        lines.append(f"J got worse after adding {added} at {len(worse)} of "
                     f"{sum(r['kind'] == 'all' for r in rows)} test speeds (at the posterior medians): "
                     + ", ".join(fmt(r) for r in worse) + ".")
    else:
        lines.append(f"No test speed got worse after adding {added} (J per speed at the posterior medians, before "
                     "-> after: " + ", ".join(fmt(r) for r in rows if r["kind"] == "all") + ").")
    if by_kind:
        lines.append("By kind of step, also worse: " + ", ".join(fmt(r, True) for r in by_kind) + ".")
    return lines
