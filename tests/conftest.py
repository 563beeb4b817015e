"""Fixtures that write small data sets (damper.toml + CSV files) to a temporary folder."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np
import pytest

#: A valid damper.toml (rig-A's constants).
DAMPER_TOML = """\
[damper]
name = "test-damper"
piston_area_m2 = 0.0042
chamber_volume_1_m3 = 0.00015
chamber_volume_2_m3 = 0.00015
liquid_bulk_modulus_Pa = 1.5e9
"""

HEADER = "time_s,displacement_m,force_N"

Columns = tuple[np.ndarray, np.ndarray, np.ndarray]


def _write_csv(path: Path, t: np.ndarray, y: np.ndarray, f: np.ndarray, header: str = HEADER) -> Path:
    data = np.column_stack([t, y, f])
    np.savetxt(path, data, delimiter=",", header=header, comments="", fmt=["%.6f", "%.9e", "%.4f"])
    return path


@pytest.fixture
def damper_toml() -> str:
    """The text of a valid damper.toml (rig-A's constants, name "test-damper")."""
    return DAMPER_TOML


@pytest.fixture
def write_csv() -> Callable[..., Path]:
    """``write_csv(path, t, y, f, header=HEADER) -> path``: write one test CSV."""
    return _write_csv


@pytest.fixture
def valid_columns() -> Columns:
    """A short valid record: 1.5 s rest, then a 1 mm/s ramp; 200 Hz, 6 s, light noise (seeded)."""
    rng = np.random.default_rng(1)
    t = np.arange(0, 6.0, 0.005)
    y = np.clip(t - 1.5, 0, None) * 1e-3 + 1e-7 * rng.standard_normal(t.size)
    f = 4000.0 * (t > 1.5) + 5.0 * rng.standard_normal(t.size)
    return t, y, f


@pytest.fixture
def make_dataset(tmp_path: Path, valid_columns: Columns) -> Callable[..., Path]:
    """``make_dataset(records=None, toml=DAMPER_TOML, folder="ds") -> folder``.

    ``records`` maps a test name to its columns ``(t, y, f)`` or to raw CSV text or bytes; by default
    one valid record ``"test_a"``. ``toml=None`` writes no damper.toml.
    """

    def make(
        records: Mapping[str, Columns | str | bytes] | None = None,
        toml: str | None = DAMPER_TOML,
        folder: str = "ds",
    ) -> Path:
        root = tmp_path / folder
        root.mkdir(parents=True, exist_ok=True)
        if toml is not None:
            (root / "damper.toml").write_text(toml)
        for name, content in (records if records is not None else {"test_a": valid_columns}).items():
            path = root / f"{name}.csv"
            if isinstance(content, bytes):
                path.write_bytes(content)
            elif isinstance(content, str):
                path.write_text(content)
            else:
                _write_csv(path, *content)
        return root

    return make
