"""Loading and validating a data set of displacement-force tests.

A data set is a folder holding

* ``damper.toml`` with a ``[damper]`` table of the known damper constants
  (``piston_area_m2``, ``chamber_volume_1_m3``, ``chamber_volume_2_m3``,
  ``liquid_bulk_modulus_Pa``, optional ``name``) and an optional ``[flow]`` table of known flow
  coefficients of eq. (4) (``C_L12``, ``C_Q12``, ``C_L21``, ``C_Q21``) and an optional ``[condition]`` table
  (:mod:`bayesdamper.io.damper_file`);
* one CSV file per test, with a header naming the columns ``time_s``, ``displacement_m`` and
  ``force_N`` (any order; other columns are ignored but an optional measured velocity ``velocity_m_s`` and an
  optional temperature ``temperature_C``),
  sampled at a constant rate, in SI units.

Every problem found raises :class:`~bayesdamper.core.errors.DataError` with a one-line message
``"<path>: <problem>"``. Nothing downstream re-reads the files: the returned :class:`Dataset`
carries read-only arrays and the SHA-256 of every input file for provenance.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from bayesdamper.core.errors import DataError, SettingsError
from bayesdamper.core.frozen import ReadOnlyArrays, frozen_copy
from bayesdamper.core.params import DamperConstants, FlowCoefficients
from bayesdamper.io.damper_file import DAMPER_FILE, read_damper_toml

__all__ = ["COLUMNS", "DAMPER_FILE", "VELOCITY_COLUMN", "Dataset", "TestRecord", "load_dataset", "load_history",
           "load_record"]

#: Required CSV columns, in the order the arrays are returned.
COLUMNS = ("time_s", "displacement_m", "force_N")
#: Optional CSV column: a measured piston velocity [m/s] (used by the input's reconstruction where it helps).
VELOCITY_COLUMN = "velocity_m_s"
#: Optional CSV column: a measured temperature [°C] (its mean per test is a covariate of the drift law).
TEMPERATURE_COLUMN = "temperature_C"

#: Relative deviation of one sampling interval from the median interval still accepted as jitter [-].
SAMPLE_RATE_JITTER = 0.05

#: Extra duration a record needs beyond one transient window ``tmax``: some rest or ramp before
#: the first step [s].
DURATION_MARGIN = 0.5

#: Largest plausible |displacement| [m]; above it the column is almost surely in millimetres.
MAX_DISPLACEMENT = 0.5

#: Largest plausible |force| of a damper test [N].
MAX_FORCE = 1e7


def _one_line(text: object) -> str:
    return " ".join(str(text).split())


@dataclass(frozen=True, eq=False)
class TestRecord(ReadOnlyArrays):
    """One triangular-displacement test, validated.

    Attributes
    ----------
    name : str
        File stem, e.g. ``"tri_0p50mm_s"``.
    path : Path
        The CSV file it was read from.
    time : ndarray, shape (n_samples,)
        Sample times [s], strictly increasing at a constant rate. Read-only.
    displacement : ndarray, shape (n_samples,)
        Measured piston displacement y_P [m], positive compresses chamber 1. Read-only.
    force : ndarray, shape (n_samples,)
        Measured damper force F_D [N], positive when chamber 1 is at the higher pressure. Read-only.
    sha256 : str
        SHA-256 of the file's bytes (hex).
    velocity : ndarray, shape (n_samples,), or None
        Measured piston velocity [m/s] (column ``velocity_m_s``), if the file has one. Read-only.
    temperature : ndarray, shape (n_samples,), or None
        Measured temperature [°C] (column ``temperature_C``), if the file has one: a covariate of the drift law.
        Read-only.
    """

    __test__ = False  # not a pytest test class despite its name

    name: str
    path: Path
    time: np.ndarray
    displacement: np.ndarray
    force: np.ndarray
    sha256: str
    velocity: np.ndarray | None = None
    temperature: np.ndarray | None = None

    @property
    def sample_rate(self) -> float:
        """Mean sample rate [Hz]."""
        return (self.time.size - 1) / (self.time[-1] - self.time[0])

    @property
    def duration(self) -> float:
        """Duration from the first to the last sample [s]."""
        return float(self.time[-1] - self.time[0])


@dataclass(frozen=True, eq=False)
class Dataset:
    """A validated data set: the damper's constants and its test records.

    Attributes
    ----------
    path : Path
        The data-set folder.
    name : str
        ``name`` from ``damper.toml``, else the folder name.
    damper : DamperConstants
        Known damper constants.
    records : tuple of TestRecord
        The tests, sorted by name.
    known_flow : FlowCoefficients or None
        Flow coefficients of eq. (4) if ``damper.toml`` has a ``[flow]`` table (never required).
    toml_sha256 : str
        SHA-256 of ``damper.toml`` (hex).
    condition : dict
        ``{name: value}`` of the ``[condition]`` table: the conditions the data set was recorded under (a charge
        pressure, a temperature, a valve setting), numbers in the units their names say; empty if none.
    """

    path: Path
    name: str
    damper: DamperConstants
    records: tuple[TestRecord, ...]
    known_flow: FlowCoefficients | None
    toml_sha256: str
    condition: dict = field(default_factory=dict)

    def input_hashes(self) -> dict[str, str]:
        """Return ``{file name: SHA-256}`` of every input file, ``damper.toml`` first."""
        out = {DAMPER_FILE: self.toml_sha256}
        out.update((r.path.name, r.sha256) for r in self.records)
        return out

    @property
    def sha256(self) -> str:
        """One SHA-256 over all input files' names and hashes (order independent)."""
        h = hashlib.sha256()
        for fname, digest in sorted(self.input_hashes().items()):
            h.update(f"{fname}:{digest}\n".encode())
        return h.hexdigest()

    def record(self, name: str) -> TestRecord:
        """Return the record called ``name``; raise KeyError if there is none."""
        for r in self.records:
            if r.name == name:
                return r
        raise KeyError(name)


# ---------------------------------------------------------------------------------------------
# CSV


def _parse_header(path: Path, header: str) -> tuple[int, int, int]:
    names = [c.strip().strip('"').strip("'").strip() for c in header.split(",")]
    missing = [c for c in COLUMNS if c not in names]
    if missing:
        shown = ",".join(names)
        if len(shown) > 80:
            shown = shown[:77] + "..."
        raise DataError(
            f"{path}: missing column(s) {', '.join(missing)} in header line 1 "
            f"(expected {','.join(COLUMNS)}; found {shown!r})"
        )
    for c in COLUMNS:
        if names.count(c) > 1:
            raise DataError(f"{path}: column {c} appears more than once in the header")
    return tuple(names.index(c) for c in COLUMNS)  # type: ignore[return-value]


def _diagnose(path: Path, lines: list[str], cols: tuple[int, ...], names: tuple[str, ...] = COLUMNS) -> str:
    """Slow per-row scan naming the first bad cell (runs only after the fast parser failed)."""
    need = max(cols) + 1
    for lineno, line in enumerate(lines[1:], start=2):
        body = line.split("#", 1)[0]
        if not body.strip():
            continue
        cells = body.split(",")
        if len(cells) < need:
            return f"line {lineno} has {len(cells)} field(s), expected at least {need}"
        for name, c in zip(names, cols, strict=True):
            cell = cells[c].strip()
            try:
                if "_" in cell:  # float() accepts digit separators, numpy does not
                    raise ValueError(cell)
                float(cell)
            except ValueError:
                shown = cell if len(cell) <= 30 else cell[:27] + "..."
                return f"line {lineno}, column {name}: cannot read {shown!r} as a number"
    return "could not parse the numeric data"


def _lineno(lines: list[str], row: int) -> int:
    """File line number (1-based) of data row ``row`` (0-based), skipping blank and comment lines."""
    k = -1
    for lineno, line in enumerate(lines[1:], start=2):
        if line.split("#", 1)[0].strip():
            k += 1
            if k == row:
                return lineno
    return len(lines)


def _check_columns(
    path: Path, lines: list[str], time: np.ndarray, y: np.ndarray, force: np.ndarray, tmax: float
) -> None:
    for name, a in zip(COLUMNS, (time, y, force), strict=True):
        bad = ~np.isfinite(a)
        if bad.any():
            i = int(np.argmax(bad))
            raise DataError(
                f"{path}: line {_lineno(lines, i)}, column {name}: non-finite value {a[i]} (NaN/inf)"
            )
    if time.size < 3:
        raise DataError(f"{path}: only {time.size} data row(s); a test needs many samples")
    dt = np.diff(time)
    if (dt <= 0).any():
        i = int(np.argmax(dt <= 0))
        raise DataError(
            f"{path}: line {_lineno(lines, i + 1)}: time_s is not strictly increasing "
            f"({time[i + 1]:g} s after {time[i]:g} s)"
        )
    med = float(np.median(dt))
    dev = np.abs(dt - med) / med
    if (dev > SAMPLE_RATE_JITTER).any():
        i = int(np.argmax(dev))
        raise DataError(
            f"{path}: line {_lineno(lines, i + 1)}: sample rate is not constant: interval {dt[i]:g} s "
            f"differs from the median {med:g} s by {100 * dev[i]:.0f}% (tolerance "
            f"{100 * SAMPLE_RATE_JITTER:.0f}%)"
        )
    if tmax is not None:
        check_duration(path, float(time[-1] - time[0]), tmax)
    ymax = float(np.max(np.abs(y)))
    if ymax > MAX_DISPLACEMENT:
        raise DataError(
            f"{path}: displacement_m reaches {ymax:g}, over {MAX_DISPLACEMENT:g} m: looks like "
            f"millimetres, expected metres"
        )
    fmax = float(np.max(np.abs(force)))
    if fmax > MAX_FORCE:
        raise DataError(
            f"{path}: force_N reaches {fmax:g} N, over {MAX_FORCE:g} N: wrong unit or corrupt data "
            f"(expected newtons)"
        )


def check_duration(path: Path, duration: float, tmax: float) -> None:
    """DataError unless a record of ``duration`` [s] holds one transient window of ``tmax`` [s]."""
    if duration < tmax + DURATION_MARGIN:
        raise DataError(
            f"{path}: record lasts {duration:g} s, too short for one transient window "
            f"(tmax = {tmax:g} s plus {DURATION_MARGIN:g} s margin)"
        )


def _check_tmax(tmax: float | None) -> float | None:
    if tmax is None:  # whole-record use: no transient window to fit in
        return None
    try:
        t = float(tmax)
    except (TypeError, ValueError):
        raise SettingsError(f"tmax must be a number of seconds, got {tmax!r}") from None
    if not (math.isfinite(t) and t > 0):
        raise SettingsError(f"tmax must be a positive number of seconds, got {tmax!r}")
    return t


def _read_lines(path: Path) -> tuple[list[str], str]:
    """The non-blank-led text lines of a CSV file and its SHA-256, or a one-line DataError."""
    if not path.exists():
        raise DataError(f"{path}: no such file")
    if path.is_dir():
        raise DataError(f"{path}: is a directory, expected a CSV file")
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise DataError(f"{path}: cannot read: {_one_line(e.strerror or e)}") from None
    sha = hashlib.sha256(raw).hexdigest()
    if not raw.strip():
        raise DataError(f"{path}: empty file (expected a header {','.join(COLUMNS)} and data rows)")
    if b"\x00" in raw:
        raise DataError(f"{path}: contains NUL bytes: binary file, expected CSV text")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise DataError(
            f"{path}: not UTF-8 text (undecodable byte at offset {e.start}), expected CSV"
        ) from None
    lines = text.splitlines()
    while lines and not lines[0].strip():
        lines.pop(0)
    if not lines:
        raise DataError(f"{path}: empty file (expected a header {','.join(COLUMNS)} and data rows)")
    return lines, sha


def _numeric(path: Path, lines: list[str], cols: tuple[int, ...], names: tuple[str, ...]) -> np.ndarray:
    """The data rows' columns ``cols`` as floats, shape (n_rows, len(cols)), or a one-line DataError."""
    if not any(line.split("#", 1)[0].strip() for line in lines[1:]):
        raise DataError(f"{path}: empty file: a header but no data rows")
    try:
        data = np.loadtxt(lines[1:], delimiter=",", comments="#", usecols=cols, ndmin=2, dtype=float)
    except (ValueError, TypeError, OverflowError, IndexError):
        raise DataError(f"{path}: {_diagnose(path, lines, cols, names)}") from None
    if data.shape[0] == 0:
        raise DataError(f"{path}: empty file: a header but no data rows")
    return data


def load_record(path: str | Path, *, tmax: float | None = 3.0) -> TestRecord:
    """Read and validate one test CSV.

    Parameters
    ----------
    path : str or Path
        CSV file with columns ``time_s`` [s], ``displacement_m`` [m] and ``force_N`` [N].
    tmax : float or None
        Transient window length T_max of eq. (9) [s]; the record must last at least
        ``tmax + DURATION_MARGIN``. None: no duration rule (whole-record identification).

    Returns
    -------
    TestRecord

    Raises
    ------
    DataError
        With a one-line ``"<path>: <problem>"`` message for any unreadable or implausible file.
    """
    tmax = _check_tmax(tmax)
    path = Path(path)
    lines, sha = _read_lines(path)
    cols = _parse_header(path, lines[0])
    data = _numeric(path, lines, cols, COLUMNS)
    time, y, force = (data[:, k] for k in range(3))
    _check_columns(path, lines, time, y, force, tmax)
    return TestRecord(
        name=path.stem,
        path=path,
        time=frozen_copy(time),
        displacement=frozen_copy(y),
        force=frozen_copy(force),
        sha256=sha,
        velocity=_read_velocity(path, lines, time.size),
        temperature=_read_optional(path, lines, time.size, TEMPERATURE_COLUMN),
    )


def load_history(path: str | Path) -> TestRecord:
    """Read and validate a displacement history to drive a calibrated damper (``bayesdamper predict``).

    The CSV needs ``time_s`` [s] and ``displacement_m`` [m] at a constant rate; a ``force_N`` column, if present,
    is the measured force the prediction is compared with, and ``velocity_m_s`` a measured velocity. The checks
    and one-line errors are those of :func:`load_record`, with no duration rule.

    Returns
    -------
    TestRecord
        Its ``force`` is the measured force, or all NaN when the file has none.
    """
    path = Path(path)
    lines, sha = _read_lines(path)
    names = [c.strip().strip('"').strip("'").strip() for c in lines[0].split(",")]
    if "force_N" in names:
        return load_record(path, tmax=None)
    need = ("time_s", "displacement_m")
    missing = [c for c in need if c not in names]
    if missing:
        shown = ",".join(names)
        shown = shown if len(shown) <= 80 else shown[:77] + "..."
        raise DataError(f"{path}: missing column(s) {', '.join(missing)} in header line 1 (expected "
                        f"time_s,displacement_m[,force_N][,velocity_m_s]; found {shown!r})")
    data = _numeric(path, lines, tuple(names.index(c) for c in need), need)
    time, y = data[:, 0], data[:, 1]
    _check_columns(path, lines, time, y, np.zeros_like(time), None)
    return TestRecord(name=path.stem, path=path, time=frozen_copy(time), displacement=frozen_copy(y),
                      force=frozen_copy(np.full(time.size, np.nan)), sha256=sha,
                      velocity=_read_velocity(path, lines, time.size),
                      temperature=_read_optional(path, lines, time.size, TEMPERATURE_COLUMN))


def _read_velocity(path: Path, lines: list[str], n: int) -> np.ndarray | None:
    """The optional measured velocity column [m/s], or None; a column that is not all finite numbers is an error."""
    return _read_optional(path, lines, n, VELOCITY_COLUMN)


def _read_optional(path: Path, lines: list[str], n: int, column: str) -> np.ndarray | None:
    """An optional numeric column, or None; a column that is not all finite numbers is an error."""
    names = [c.strip().strip('"').strip("'").strip() for c in lines[0].split(",")]
    if column not in names:
        return None
    try:
        v = np.loadtxt(lines[1:], delimiter=",", comments="#", usecols=(names.index(column),), ndmin=1)
    except (ValueError, TypeError, OverflowError, IndexError):
        raise DataError(f"{path}: column {column} holds something that is not a number") from None
    if v.size != n or not np.all(np.isfinite(v)):
        raise DataError(f"{path}: column {column} must hold a finite number in every row")
    return frozen_copy(v)


def _csv_files(folder: Path) -> list[Path]:
    files = [p for p in folder.iterdir() if p.suffix.lower() == ".csv" and p.is_file()]
    return sorted(files, key=lambda p: (p.stem, p.name))


def load_dataset(path: str | Path, *, tmax: float | None = 3.0) -> Dataset:
    """Read and validate a data-set folder: ``damper.toml`` plus one CSV per test.

    Parameters
    ----------
    path : str or Path
        The folder.
    tmax : float
        Transient window length T_max [s], passed to :func:`load_record`.

    Returns
    -------
    Dataset
        Records sorted by name.

    Raises
    ------
    DataError
        With a one-line ``"<path>: <problem>"`` message naming the folder or the faulty file.
    """
    tmax = _check_tmax(tmax)
    folder = Path(path)
    if not folder.exists():
        raise DataError(f"{folder}: no such data-set folder")
    if not folder.is_dir():
        raise DataError(f"{folder}: not a directory; a data set is a folder with {DAMPER_FILE} and CSV files")
    toml_path = folder / DAMPER_FILE
    if not toml_path.is_file():
        raise DataError(f"{toml_path}: missing; a data set needs {DAMPER_FILE} with a [damper] table")
    csvs = _csv_files(folder)
    if not csvs:
        raise DataError(f"{folder}: no CSV files (*.csv) in the data-set folder")
    damper, known_flow, toml_sha, name, condition = read_damper_toml(toml_path)
    if not name:
        damper = replace(damper, name=folder.resolve().name)
    _check_unique(folder, (p.stem for p in csvs))
    records = tuple(load_record(p, tmax=tmax) for p in csvs)
    return Dataset(
        path=folder,
        name=damper.name,
        damper=damper,
        records=records,
        known_flow=known_flow,
        toml_sha256=toml_sha,
        condition=condition,
    )


def _check_unique(folder: Path, stems: Iterable[str]) -> None:
    seen: set[str] = set()
    for s in stems:
        if s in seen:
            raise DataError(f"{folder}: two CSV files share the test name {s!r}")
        seen.add(s)
