"""Tests of bayesdamper.io.dataset: loading a data set and rejecting every class of bad input."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bayesdamper.core.errors import DataError, SettingsError
from bayesdamper.core.params import DamperConstants, FlowCoefficients
from bayesdamper.io.dataset import COLUMNS, Dataset, TestRecord, load_dataset, load_record

HEADER = ",".join(COLUMNS)
RIG_A = Path(__file__).resolve().parents[1] / "data" / "rig-A"


def _csv_text(t, y, f, header: str = HEADER) -> str:
    rows = "\n".join(f"{a:.6f},{b:.9e},{c:.4f}" for a, b, c in zip(t, y, f, strict=True))
    return f"{header}\n{rows}\n"


def assert_data_error(call, path: Path, *words: str) -> str:
    """Run ``call``; assert a one-line DataError naming ``path`` and containing every word."""
    with pytest.raises(DataError) as info:
        call()
    msg = str(info.value)
    assert "\n" not in msg, msg
    assert msg.startswith(f"{path}: "), msg
    for w in words:
        assert re.search(w, msg, flags=re.IGNORECASE), f"{w!r} not in {msg!r}"
    return msg


# ---------------------------------------------------------------------------------------------
# good data


def test_valid_dataset_loads(make_dataset, valid_columns):
    t, y, f = valid_columns
    folder = make_dataset({"b_test": (t, y, f), "a_test": (t, 2 * y, f)})
    ds = load_dataset(folder)
    assert isinstance(ds, Dataset)
    assert ds.name == "test-damper"
    assert ds.damper == DamperConstants(0.0042, 0.00015, 0.00015, 1.5e9, "test-damper")
    assert ds.known_flow is None
    assert [r.name for r in ds.records] == ["a_test", "b_test"]
    rec = ds.records[1]
    assert isinstance(rec, TestRecord)
    assert rec.path == folder / "b_test.csv"
    np.testing.assert_allclose(rec.time, t, atol=1e-9)
    np.testing.assert_allclose(rec.displacement, y, rtol=1e-8)
    np.testing.assert_allclose(rec.force, f, atol=1e-4)
    assert rec.sample_rate == pytest.approx(200.0)
    for a in (rec.time, rec.displacement, rec.force):
        assert not a.flags.writeable
        with pytest.raises(ValueError):
            a[0] = 1.0
    assert set(ds.input_hashes()) == {"damper.toml", "a_test.csv", "b_test.csv"}
    assert all(len(h) == 64 for h in ds.input_hashes().values())
    assert len(ds.sha256) == 64


def test_dataset_hash_changes_with_any_file(make_dataset, valid_columns):
    t, y, f = valid_columns
    folder = make_dataset()
    h1 = load_dataset(folder).sha256
    assert load_dataset(folder).sha256 == h1
    make_dataset({"test_a": (t, y, f + 1.0)})
    assert load_dataset(folder).sha256 != h1


def test_name_falls_back_to_folder_and_flow_is_read(make_dataset, damper_toml):
    toml = damper_toml.replace('name = "test-damper"\n', "") + (
        "\n[flow]\nC_L12 = 2.4e10\nC_Q12 = 4.3e16\nC_L21 = 0.86e10\nC_Q21 = 5.1e16\n"
    )
    ds = load_dataset(make_dataset(toml=toml, folder="my-rig"))
    assert ds.name == "my-rig"
    assert ds.damper.name == "my-rig"
    assert ds.known_flow == FlowCoefficients(2.4e10, 4.3e16, 0.86e10, 5.1e16)


def test_integer_constants_are_accepted(make_dataset, damper_toml):
    toml = damper_toml.replace("1.5e9", "1500000000")
    assert load_dataset(make_dataset(toml=toml)).damper.liquid_bulk_modulus == 1.5e9


def test_column_order_and_extra_columns(make_dataset, valid_columns):
    t, y, f = valid_columns
    rows = "\n".join(f"{c:.3f},{a:.6f},7,{b:.9e}" for a, b, c in zip(t, y, f, strict=True))
    folder = make_dataset({"x": f"force_N,time_s,temperature_C,displacement_m\n{rows}\n"})
    rec = load_dataset(folder).records[0]
    np.testing.assert_allclose(rec.time, t, atol=1e-9)
    np.testing.assert_allclose(rec.displacement, y, rtol=1e-8)
    np.testing.assert_allclose(rec.force, f, atol=1e-3)


def _with_velocity(t, y, f, v, header: str = HEADER + ",velocity_m_s") -> str:
    rows = "\n".join(f"{a:.6f},{b:.9e},{c:.4f},{d}" for a, b, c, d in zip(t, y, f, v, strict=True))
    return f"{header}\n{rows}\n"


def test_velocity_column_is_read_when_present(make_dataset, valid_columns):
    """An optional ``velocity_m_s`` column (a measured velocity channel) is read into ``TestRecord.velocity``
    (read-only); a record without one has None."""
    t, y, f = valid_columns
    v = np.gradient(y, t)
    folder = make_dataset({"with_v": _with_velocity(t, y, f, [f"{x:.9e}" for x in v]), "without": (t, y, f)})
    ds = load_dataset(folder)
    rec = ds.record("with_v")
    np.testing.assert_allclose(rec.velocity, v, rtol=1e-8, atol=1e-15)
    assert not rec.velocity.flags.writeable
    assert ds.record("without").velocity is None


@pytest.mark.parametrize("bad, words", [("nan", ("velocity_m_s", "finite")), ("inf", ("velocity_m_s", "finite")),
                                        ("fast", ("velocity_m_s", "not a number"))])
def test_velocity_column_must_hold_finite_numbers(make_dataset, valid_columns, bad, words):
    t, y, f = valid_columns
    v = [f"{x:.9e}" for x in np.gradient(y, t)]
    v[40] = bad
    _bad_csv(make_dataset, _with_velocity(t, y, f, v), *words)


def test_sample_jitter_within_tolerance_is_accepted(make_dataset, valid_columns):
    t, y, f = valid_columns
    rng = np.random.default_rng(3)
    jitter = 0.005 * 0.01 * rng.uniform(-1, 1, t.size)  # 1 % of the 5 ms interval, within SAMPLE_RATE_JITTER
    rec = load_record(make_dataset({"j": (t + jitter, y, f)}) / "j.csv")
    assert rec.sample_rate == pytest.approx(200.0, rel=1e-3)


def test_comments_blank_lines_and_crlf_are_tolerated(make_dataset, valid_columns):
    text = _csv_text(*valid_columns).replace("\n", "\r\n", 5)
    lines = text.split("\n")
    lines.insert(3, "")
    lines.insert(7, "# operator note")
    rec = load_record(make_dataset({"c": "\n".join(lines)}) / "c.csv")
    assert rec.time.size == valid_columns[0].size


def test_rig_a_loads():
    ds = load_dataset(RIG_A)
    assert len(ds.records) == 11
    assert ds.records[0].name == "tri_0p50mm_s"
    assert all(r.sample_rate == pytest.approx(250.0) for r in ds.records)
    assert ds.damper.piston_area == 0.0042


# ---------------------------------------------------------------------------------------------
# bad folder or damper.toml


def test_missing_folder(tmp_path):
    missing = tmp_path / "nope"
    assert_data_error(lambda: load_dataset(missing), missing, "no such")


def test_folder_is_a_file(tmp_path):
    p = tmp_path / "file.txt"
    p.write_text("x")
    assert_data_error(lambda: load_dataset(p), p, "not a directory")


def test_no_csv(make_dataset):
    folder = make_dataset(records={})
    assert_data_error(lambda: load_dataset(folder), folder, "no CSV")


def test_missing_damper_toml(make_dataset):
    folder = make_dataset(toml=None)
    assert_data_error(lambda: load_dataset(folder), folder / "damper.toml", "missing")


def test_toml_syntax_error(make_dataset):
    folder = make_dataset(toml="[damper]\npiston_area_m2 = = 3\n")
    assert_data_error(lambda: load_dataset(folder), folder / "damper.toml", "TOML syntax", "line 2")


def test_toml_missing_damper_table(make_dataset):
    folder = make_dataset(toml="[pump]\nx = 1\n")
    assert_data_error(lambda: load_dataset(folder), folder / "damper.toml", r"missing \[damper\]")


@pytest.mark.parametrize(
    "key", ["piston_area_m2", "chamber_volume_1_m3", "chamber_volume_2_m3", "liquid_bulk_modulus_Pa"]
)
def test_toml_missing_key(make_dataset, key, damper_toml):
    toml = "\n".join(line for line in damper_toml.splitlines() if not line.startswith(key))
    folder = make_dataset(toml=toml)
    assert_data_error(lambda: load_dataset(folder), folder / "damper.toml", "missing key", key)


@pytest.mark.parametrize(
    ("value", "words"),
    [
        ('"0.0042"', ["must be a number", r"m\^2"]),
        ("true", ["must be a number"]),
        ("nan", ["finite"]),
        ("0.0", ["positive"]),
        ("-0.01", ["positive"]),
        ("2.0", ["plausible", r"m\^2"]),  # 2 m^2: absurd
        ("4.2e-8", ["plausible", r"m\^2"]),  # mm^2 typed as m^2
        ("[1, 2]", ["must be a number"]),
    ],
)
def test_toml_bad_piston_area(make_dataset, value, words, damper_toml):
    folder = make_dataset(toml=damper_toml.replace("= 0.0042", f"= {value}"))
    assert_data_error(lambda: load_dataset(folder), folder / "damper.toml", "piston_area_m2", *words)


@pytest.mark.parametrize("value", ["2.0", "1e-9"])
def test_toml_absurd_volume(make_dataset, value, damper_toml):
    toml = damper_toml.replace("chamber_volume_2_m3 = 0.00015", f"chamber_volume_2_m3 = {value}")
    folder = make_dataset(toml=toml)
    assert_data_error(lambda: load_dataset(folder), folder / "damper.toml", "chamber_volume_2_m3", r"m\^3")


@pytest.mark.parametrize("value", ["1.5", "1.5e12"])  # GPa typed as Pa; or far too stiff
def test_toml_absurd_bulk_modulus(make_dataset, value, damper_toml):
    folder = make_dataset(toml=damper_toml.replace("1.5e9", value))
    assert_data_error(
        lambda: load_dataset(folder), folder / "damper.toml", "liquid_bulk_modulus_Pa", "plausible", "Pa"
    )


def test_toml_bad_name(make_dataset, damper_toml):
    folder = make_dataset(toml=damper_toml.replace('"test-damper"', "3"))
    assert_data_error(lambda: load_dataset(folder), folder / "damper.toml", "name must be a string")


@pytest.mark.parametrize(
    ("flow", "words"),
    [
        ("C_L12 = 1e10\nC_Q12 = 1e16\nC_L21 = 1e10\n", ["missing key C_Q21"]),
        ("C_L12 = -1e10\nC_Q12 = 1e16\nC_L21 = 1e10\nC_Q21 = 1e16\n", ["C_L12", ">= 0"]),
        ('C_L12 = "a"\nC_Q12 = 1e16\nC_L21 = 1e10\nC_Q21 = 1e16\n', ["C_L12", "must be a number"]),
        ("C_L12 = 0\nC_Q12 = 0\nC_L21 = 1e10\nC_Q21 = 1e16\n", ["both be zero"]),
    ],
)
def test_toml_bad_flow(make_dataset, flow, words, damper_toml):
    folder = make_dataset(toml=damper_toml + "\n[flow]\n" + flow)
    assert_data_error(lambda: load_dataset(folder), folder / "damper.toml", r"\[flow\]", *words)


def test_toml_binary_junk(make_dataset):
    folder = make_dataset()
    (folder / "damper.toml").write_bytes(b"\xff\xfe\x00junk")
    assert_data_error(lambda: load_dataset(folder), folder / "damper.toml", "UTF-8")


# ---------------------------------------------------------------------------------------------
# bad CSV files


def _bad_csv(make_dataset, content: str | bytes, *words: str) -> str:
    folder = make_dataset({"bad": content})
    path = folder / "bad.csv"
    msg = assert_data_error(lambda: load_dataset(folder), path, *words)
    assert_data_error(lambda: load_record(path), path, *words)
    return msg


def test_csv_missing_column(make_dataset, valid_columns):
    text = _csv_text(*valid_columns, header="time_s,displacement_m,force_kN")
    _bad_csv(make_dataset, text, "missing column", "force_N")


def test_csv_duplicate_column(make_dataset, valid_columns):
    t, y, f = valid_columns
    rows = "\n".join(f"{a},{b},{c},{c}" for a, b, c in zip(t, y, f, strict=True))
    _bad_csv(make_dataset, f"{HEADER},force_N\n{rows}\n", "force_N", "more than once")


@pytest.mark.parametrize("content", ["", "\n\n  \n"])
def test_csv_empty(make_dataset, content):
    _bad_csv(make_dataset, content, "empty")


def test_csv_header_only(make_dataset):
    _bad_csv(make_dataset, HEADER + "\n", "empty", "no data rows")


def test_csv_non_numeric_cell(make_dataset, valid_columns):
    lines = _csv_text(*valid_columns).splitlines()
    cells = lines[10].split(",")
    lines[10] = f"{cells[0]},{cells[1]},12.3kN"
    _bad_csv(make_dataset, "\n".join(lines), "line 11", "column force_N", "12.3kN")


def test_csv_short_row(make_dataset, valid_columns):
    lines = _csv_text(*valid_columns).splitlines()
    lines[20] = lines[20].rsplit(",", 1)[0]
    _bad_csv(make_dataset, "\n".join(lines), "line 21", "field")


@pytest.mark.parametrize("bad", ["nan", "inf", "-inf"])
def test_csv_non_finite(make_dataset, valid_columns, bad):
    lines = _csv_text(*valid_columns).splitlines()
    cells = lines[30].split(",")
    lines[30] = f"{cells[0]},{bad},{cells[2]}"
    _bad_csv(make_dataset, "\n".join(lines), "line 31", "displacement_m", "non-finite")


def test_csv_time_not_increasing(make_dataset, valid_columns):
    t, y, f = (a.copy() for a in valid_columns)
    t[50] = t[49]
    _bad_csv(make_dataset, _csv_text(t, y, f), "line 52", "not strictly increasing")


def test_csv_time_reversed(make_dataset, valid_columns):
    t, y, f = valid_columns
    _bad_csv(make_dataset, _csv_text(t[::-1], y, f), "not strictly increasing")


def test_csv_sample_rate_not_constant(make_dataset, valid_columns):
    t, y, f = valid_columns
    keep = np.ones(t.size, dtype=bool)
    keep[100] = False  # one dropped sample: an interval twice the others
    _bad_csv(make_dataset, _csv_text(t[keep], y[keep], f[keep]), "sample rate is not constant", "line 102")


def test_csv_too_short(make_dataset, valid_columns):
    t, y, f = (a[:500] for a in valid_columns)  # 2.5 s < tmax + margin
    _bad_csv(make_dataset, _csv_text(t, y, f), "too short", "tmax")


def test_csv_too_short_depends_on_tmax(make_dataset, valid_columns):
    path = make_dataset() / "test_a.csv"
    assert load_record(path, tmax=3.0).duration < 6.0
    assert_data_error(lambda: load_record(path, tmax=6.0), path, "too short")


def test_csv_millimetres(make_dataset, valid_columns):
    t, y, f = valid_columns
    _bad_csv(make_dataset, _csv_text(t, 1e3 * y, f), "millimetres")


def test_csv_absurd_force(make_dataset, valid_columns):
    t, y, f = valid_columns
    _bad_csv(make_dataset, _csv_text(t, y, 1e4 * f), "force_N", "N")


def test_csv_binary_junk(make_dataset):
    rng = np.random.default_rng(7)
    junk = bytes(rng.integers(128, 256, 2000, dtype=np.uint8))
    _bad_csv(make_dataset, junk, "UTF-8")


def test_csv_nul_bytes(make_dataset, valid_columns):
    raw = _csv_text(*valid_columns).encode()
    _bad_csv(make_dataset, raw[:200] + b"\x00\x00" + raw[200:], "NUL")


def test_csv_latin1_text(make_dataset, valid_columns):
    raw = _csv_text(*valid_columns, header="time_s,displacement_m,force_N,temp_°C").encode("latin-1")
    _bad_csv(make_dataset, raw, "UTF-8", "offset")


def test_load_record_missing_or_directory(tmp_path):
    missing = tmp_path / "gone.csv"
    assert_data_error(lambda: load_record(missing), missing, "no such file")
    assert_data_error(lambda: load_record(tmp_path), tmp_path, "directory")


def test_bad_tmax_is_a_settings_error(make_dataset):
    with pytest.raises(SettingsError, match="tmax"):
        load_dataset(make_dataset(), tmax=-1.0)


# ---------------------------------------------------------------------------------------------
# property: arbitrary bytes never crash the loader

#: Modest example counts keep the default suite fast.
FUZZ_EXAMPLES = 100


@pytest.fixture(scope="module")
def fuzz_file(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz") / "fuzz.csv"


def _only_data_error(path: Path, raw: bytes) -> None:
    path.write_bytes(raw)
    try:
        load_record(path, tmax=0.01)
    except DataError as e:
        msg = str(e)
        assert msg.startswith(f"{path}: ") and "\n" not in msg


@settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(raw=st.binary(max_size=400))
def test_arbitrary_bytes_only_raise_data_error(fuzz_file, raw):
    _only_data_error(fuzz_file, raw)


_cell = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.text(alphabet="0123456789.eE+-naifx ,#\"'_\t\r\x0c\u2028", max_size=8),
)


@settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rows=st.lists(st.lists(_cell, min_size=1, max_size=4), max_size=12))
def test_header_plus_arbitrary_rows_only_raise_data_error(fuzz_file, rows):
    body = "\n".join(",".join(r) for r in rows)
    _only_data_error(fuzz_file, f"{HEADER}\n{body}\n".encode())


def test_frozen_containers_stay_read_only_through_pickling(make_dataset):
    """Windows and records sent to worker processes keep their arrays read-only (one numba type for the kernels)
    and their values."""
    import pickle

    from bayesdamper.io.segmentation import segment_record

    ds = load_dataset(make_dataset())
    rec = ds.records[0]
    back = pickle.loads(pickle.dumps(rec))
    for name in ("time", "displacement", "force"):
        assert not getattr(back, name).flags.writeable
        np.testing.assert_array_equal(getattr(back, name), getattr(rec, name))
    seg = segment_record(rec, ds.damper)
    win = pickle.loads(pickle.dumps(seg.transients[0]))
    for arr, orig in ((win.time, seg.transients[0].time), (win.force, seg.transients[0].force),
                      (win.drive.coefs, seg.transients[0].drive.coefs)):
        assert not arr.flags.writeable
        np.testing.assert_array_equal(arr, orig)
