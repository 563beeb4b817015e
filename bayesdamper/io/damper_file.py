"""The damper description of a data set: ``damper.toml``.

``[damper]`` holds the known damper constants (``piston_area_m2``, ``chamber_volume_1_m3``, ``chamber_volume_2_m3``,
``liquid_bulk_modulus_Pa``, optional ``name``); an optional ``[flow]`` table known flow coefficients of eq. (4)
(``C_L12``, ``C_Q12``, ``C_L21``, ``C_Q21``); an optional ``[condition]`` table the conditions the data set was
recorded under, one number each (``charge_pressure_Pa = 2e5``, ``temperature_C = 40``), read and validated
(:attr:`bayesdamper.io.dataset.Dataset.condition`).
"""

from __future__ import annotations

import hashlib
import math
import tomllib
from pathlib import Path

from bayesdamper.core.errors import DataError, SettingsError
from bayesdamper.core.params import DamperConstants, FlowCoefficients

__all__ = ["DAMPER_FILE", "read_damper_toml"]

#: Name of the damper description inside a data-set folder.
DAMPER_FILE = "damper.toml"

#: ``damper.toml`` keys -> (DamperConstants field, unit, plausible range [lo, hi]).
_DAMPER_KEYS: dict[str, tuple[str, str, float, float]] = {
    "piston_area_m2": ("piston_area", "m^2", 1e-6, 1.0),
    "chamber_volume_1_m3": ("chamber_volume_1", "m^3", 1e-8, 1.0),
    "chamber_volume_2_m3": ("chamber_volume_2", "m^3", 1e-8, 1.0),
    "liquid_bulk_modulus_Pa": ("liquid_bulk_modulus", "Pa", 1e7, 1e11),
}

#: ``[flow]`` keys -> (FlowCoefficients field, unit).
_FLOW_KEYS: dict[str, tuple[str, str]] = {
    "C_L12": ("laminar_12", "kg m^-4 s^-1"),
    "C_Q12": ("quadratic_12", "kg m^-7"),
    "C_L21": ("laminar_21", "kg m^-4 s^-1"),
    "C_Q21": ("quadratic_21", "kg m^-7"),
}




def _one_line(text: object) -> str:
    return " ".join(str(text).split())


def _number(path: Path, table: str, key: str, value: object, unit: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise DataError(f"{path}: [{table}] {key} must be a number in {unit}, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise DataError(f"{path}: [{table}] {key} must be finite, got {v!r}")
    return v


def read_damper_toml(path: Path) -> tuple[DamperConstants, FlowCoefficients | None, str, str | None, dict]:
    """``(constants, known flow or None, SHA-256 of the file, name or None, {condition: value})``; DataError with one
    line ``"<path>: <problem>"`` for anything unreadable or implausible."""
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise DataError(f"{path}: cannot read: {_one_line(e.strerror or e)}") from None
    sha = hashlib.sha256(raw).hexdigest()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise DataError(f"{path}: not UTF-8 text (undecodable byte at offset {e.start})") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise DataError(f"{path}: TOML syntax error: {_one_line(e)}") from None

    damper = doc.get("damper")
    if damper is None:
        raise DataError(f"{path}: missing [damper] table (needs {', '.join(_DAMPER_KEYS)})")
    if not isinstance(damper, dict):
        raise DataError(f"{path}: 'damper' must be a table [damper], got {type(damper).__name__}")
    values: dict[str, float] = {}
    for key, (fname, unit, lo, hi) in _DAMPER_KEYS.items():
        if key not in damper:
            raise DataError(f"{path}: [damper] is missing key {key} [{unit}]")
        v = _number(path, "damper", key, damper[key], unit)
        if v <= 0:
            raise DataError(f"{path}: [damper] {key} must be positive (in {unit}), got {v:g}")
        if not lo <= v <= hi:
            raise DataError(
                f"{path}: [damper] {key} = {v:g} is outside the plausible range "
                f"[{lo:g}, {hi:g}] {unit}; expected a value in {unit}"
            )
        values[fname] = v
    name = damper.get("name")
    if name is not None and not isinstance(name, str):
        raise DataError(f"{path}: [damper] name must be a string, got {name!r}")
    constants = DamperConstants(**values, name=name or "")

    flow = doc.get("flow")
    known_flow = None
    if flow is not None:
        if not isinstance(flow, dict):
            raise DataError(f"{path}: 'flow' must be a table [flow], got {type(flow).__name__}")
        coeffs: dict[str, float] = {}
        for key, (fname, unit) in _FLOW_KEYS.items():
            if key not in flow:
                raise DataError(f"{path}: [flow] is missing key {key} [{unit}] (give all four or no [flow])")
            v = _number(path, "flow", key, flow[key], unit)
            if v < 0:
                raise DataError(f"{path}: [flow] {key} must be >= 0 (in {unit}), got {v:g}")
            coeffs[fname] = v
        try:
            known_flow = FlowCoefficients(**coeffs)
        except SettingsError as e:
            raise DataError(f"{path}: [flow] {_one_line(e)}") from None
    condition = doc.get("condition") or {}
    if not isinstance(condition, dict):
        raise DataError(f"{path}: 'condition' must be a table [condition], got {type(condition).__name__}")
    condition = {str(k): _number(path, "condition", k, v, "the unit its name says") for k, v in condition.items()}
    return constants, known_flow, sha, name, condition


