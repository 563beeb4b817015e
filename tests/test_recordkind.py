"""Record classification (sine / triangular / other) and the whole-record quality checks.

The synthetic signals here set the thresholds of :mod:`bayesdamper.io.recordkind`: sines (noise, offset,
up to 7 % third harmonic) have R^2 >= 0.995 and <= 16 % of their samples at a constant velocity; triangles
(rest, noise up to 30 µm, rounded corners) have R^2 <= 0.987 and >= 90 % at a constant velocity;
random-phase multisines and a sweep fit no sine (R^2 < 0.1) and have <= 16 % at a constant velocity.
The real records must agree: lab-MR are sines, rig-A triangular, and all pass the quality checks.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import chirp, savgol_filter

from bayesdamper.core.errors import DataError
from bayesdamper.io import recordkind as rk
from bayesdamper.io.dataset import TestRecord, load_record
from bayesdamper.io.recordkind import RecordKind, check_record_quality, classify_record

ROOT = Path(__file__).resolve().parents[1]
LAB_MR = sorted((ROOT / "data" / "lab-MR").glob("*.csv"))
RIG_A = sorted((ROOT / "data" / "rig-A").glob("*.csv"))


def record(t: np.ndarray, y: np.ndarray, force: np.ndarray | None = None, name: str = "synthetic") -> TestRecord:
    """A TestRecord built directly (no file), force defaulting to a viscous response with noise."""
    if force is None:
        v = np.gradient(savgol_filter(y, 7, 2), t)
        force = 100.0 + 2e4 * v + np.random.default_rng(1).normal(0, 0.5, t.size)
    return TestRecord(name, Path(f"/data/{name}.csv"), t, y, force, "0" * 64)


def via_csv(tmp_path: Path, t: np.ndarray, y: np.ndarray, force: np.ndarray, name: str) -> TestRecord:
    """Write a CSV and read it back with load_record (tmax small: records may be short)."""
    path = tmp_path / f"{name}.csv"
    np.savetxt(path, np.column_stack([t, y, force]), delimiter=",", header="time_s,displacement_m,force_N",
               comments="", fmt=["%.6f", "%.9e", "%.4f"])
    return load_record(path, tmax=0.1)


def sine(rate: float, duration: float, amp: float, freq: float, offset: float = 0.0, noise: float = 0.0,
         harmonic: float = 0.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(0.0, duration, 1.0 / rate)
    w = 2 * np.pi * freq * t + 0.3
    y = offset + amp * (np.sin(w) + harmonic * np.sin(3 * w))
    return t, y + np.random.default_rng(seed).normal(0.0, noise, t.size)


def triangle(rate: float, speed: float, amp: float = 5e-3, rest: float = 1.0, cycles: float = 1.25,
             noise: float = 0.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Rest, then a triangle of ``cycles`` cycles at ``speed`` starting upward (the rig-A protocol)."""
    period = 4 * amp / speed
    t = np.arange(0.0, rest + cycles * period, 1.0 / rate)
    u = np.clip(t - rest, 0.0, None) / period + 0.75  # phase: 0.75 = mid-rise of the wave below
    y = amp * (2 * np.abs(2 * (u - np.floor(u + 0.5))) - 1) * np.where(t < rest, 0.0, 1.0)
    return t, -y + np.random.default_rng(seed).normal(0.0, noise, t.size)


def multisine(rate: float, duration: float, f_lo: float, f_hi: float, rms: float, seed: int = 0):
    t = np.arange(0.0, duration, 1.0 / rate)
    freqs = np.arange(f_lo, f_hi + 1e-9, 1.0 / duration * 4)
    phases = np.random.default_rng(seed).uniform(0, 2 * np.pi, freqs.size)
    y = np.sum(np.sin(2 * np.pi * freqs[:, None] * t + phases[:, None]), axis=0)
    return t, y * rms / np.std(y)


SINES = {
    "100Hz_1Hz_12mm_offset": dict(rate=100, duration=30, amp=12e-3, freq=1.0, offset=12e-3),
    "100Hz_0.84Hz_quantised": dict(rate=100, duration=20, amp=8e-3, freq=0.84, offset=7e-3, noise=3e-6),
    "1kHz_5Hz_1mm_noise": dict(rate=1000, duration=4, amp=1e-3, freq=5.0, noise=2e-5),
    "1kHz_0.3Hz_20mm": dict(rate=1000, duration=10, amp=20e-3, freq=0.3, offset=-5e-3, noise=1e-6),
    "100Hz_2Hz_5pc_harmonic": dict(rate=100, duration=10, amp=5e-3, freq=2.0, harmonic=0.05),
    "250Hz_1.5_cycles": dict(rate=250, duration=1.5, amp=3e-3, freq=1.0, noise=1e-6),
    "100Hz_2Hz_7pc_harmonic": dict(rate=100, duration=10, amp=5e-3, freq=2.0, harmonic=0.07),
}


@pytest.mark.parametrize("case", sorted(SINES))
def test_sine_is_sine(case):
    p = SINES[case]
    t, y = sine(**p)
    kind = classify_record(record(t, y))
    assert kind.kind == "sine", kind.description
    d = kind.details
    assert d["frequency_Hz"] == pytest.approx(p["freq"], rel=2e-3)
    assert d["amplitude_m"] == pytest.approx(p["amp"], rel=0.01)
    assert d["offset_m"] == pytest.approx(p.get("offset", 0.0), abs=0.01 * p["amp"] + 1e-5)
    assert d["n_cycles"] == pytest.approx(p["freq"] * p["duration"], rel=0.02)
    assert rk.SINE_R2 <= d["fit_r2"] <= 1.0
    assert kind.description.startswith("sine, amplitude ") and "\n" not in kind.description
    json.dumps(d)
    check_record_quality(record(t, y))


def test_sine_through_csv_with_rest(tmp_path):
    t, y = sine(rate=100, duration=12, amp=6e-3, freq=1.1, offset=6e-3)
    y[t < 2.0] = y[t >= 2.0][0]  # at rest for 2 s before the motion, as the lab-MR records
    f = 100 + 2e4 * np.gradient(y, t)
    kind = classify_record(via_csv(tmp_path, t, y, f, "rest_sine"))
    assert (kind.name, kind.kind) == ("rest_sine", "sine")
    assert kind.details["n_cycles"] == pytest.approx(1.1 * 10, rel=0.03)


#: (triangle() arguments, expected reversals)
TRIANGLES = {
    "rigA_0.5mm_s": (dict(rate=250, speed=0.5e-3), 2),
    "rigA_1.5mm_s_noise1um": (dict(rate=250, speed=1.5e-3, noise=1e-6), 2),
    "1kHz_20mm_s_noise1um": (dict(rate=1000, speed=20e-3, amp=2e-3, cycles=3.0, noise=1e-6), 6),
    "100Hz_no_rest": (dict(rate=100, speed=10e-3, amp=10e-3, rest=0.0, cycles=2.5, noise=1e-6), 5),
    "noise_free_many_cycles": (dict(rate=250, speed=5e-3, amp=5e-3, rest=0.5, cycles=10.0), 20),
    "rigA_0.5mm_s_noise30um": (dict(rate=250, speed=0.5e-3, noise=30e-6), 2),
}


@pytest.mark.parametrize("case", sorted(TRIANGLES))
def test_triangle_is_triangular(case):
    p, reversals = TRIANGLES[case]
    t, y = triangle(**p)
    kind = classify_record(record(t, y))
    assert kind.kind == "triangular", kind.description
    d = kind.details
    assert d["speeds_m_s"] == pytest.approx([p["speed"]], rel=0.01)
    assert d["n_reversals"] == reversals
    assert d["fraction_constant_velocity"] >= 0.9
    assert rk._analyse(record(t, y)).sine[3] < rk.SINE_R2  # never a sine
    assert kind.description == f"triangular, speeds {d['speeds_m_s'][0] * 1e3:.2f} mm/s"
    json.dumps(d)
    check_record_quality(record(t, y))


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("rate", [100, 1000])
def test_multisine_is_other(seed, rate):
    t, y = multisine(rate, 30.0, 0.2, 3.0, rms=5e-3, seed=seed)
    kind = classify_record(record(t, y))
    assert kind.kind == "other", kind.description
    lo, hi = kind.details["band_Hz"]
    assert 0.1 <= lo <= 0.4 and 2.5 <= hi <= 3.3
    assert kind.details["rms_velocity_m_s"] == pytest.approx(np.std(np.gradient(y, t)), rel=0.1)
    assert kind.description.startswith("other (broadband: ")
    json.dumps(kind.details)
    check_record_quality(record(t, y))


def test_rounded_triangle_is_triangular():
    t, y = triangle(rate=250, speed=1e-3)
    y = np.convolve(y, np.ones(125) / 125, mode="same")[200:-200]  # corners rounded over 0.5 s
    assert classify_record(record(t[200:-200], y)).kind == "triangular"


def test_distorted_sine_is_not_sine():
    t, y = sine(rate=100, duration=10, amp=5e-3, freq=2.0, harmonic=0.08)  # R^2 = 1 / (1 + 0.08^2) < 0.995
    assert classify_record(record(t, y)).kind == "other"


def test_ramp_is_not_a_sine():
    t = np.arange(0.0, 2.0, 0.001)  # a straight line fits a very slow sine; R^2 is taken about the best line
    rec = record(t, 1e-3 * t, 100 + 10 * np.sin(t))
    assert classify_record(rec).kind != "sine"
    check_record_quality(rec)  # a ramp is no "less than one cycle" sine


def test_drifting_sine_is_sine():
    t, y = sine(rate=100, duration=20, amp=5e-3, freq=1.2, offset=5e-3)
    kind = classify_record(record(t, y + 1e-4 * t))  # mean creeps 2 mm, as lab-MR ensaio10
    assert kind.kind == "sine" and kind.details["fit_r2"] > 0.9999
    assert kind.details["offset_m"] == pytest.approx(5e-3 + 1e-4 * t[-1] / 2, rel=0.01)


def test_sweep_is_other():
    t = np.arange(0.0, 40.0, 0.005)
    y = 5e-3 * chirp(t, 0.5, 40.0, 5.0)
    kind = classify_record(record(t, y))
    assert kind.kind == "other", kind.description
    lo, hi = kind.details["band_Hz"]
    assert 0.3 <= lo <= 0.8 and 4.0 <= hi <= 5.5


@pytest.mark.parametrize("path", LAB_MR, ids=lambda p: p.stem)
def test_lab_mr_is_sine(path):
    rec = load_record(path)
    kind = classify_record(rec)
    assert isinstance(kind, RecordKind) and kind.name == path.stem
    assert kind.kind == "sine", kind.description
    assert 0.8 <= kind.details["frequency_Hz"] <= 1.25
    assert 5e-3 <= kind.details["amplitude_m"] <= 13e-3
    assert kind.details["n_cycles"] > 20
    check_record_quality(rec)


@pytest.mark.parametrize("path", RIG_A, ids=lambda p: p.stem)
def test_rig_a_is_triangular(path):
    rec = load_record(path)
    kind = classify_record(rec)
    assert kind.kind == "triangular", kind.description
    speed = float(path.stem.split("_")[1].replace("p", ".").replace("mm", "")) * 1e-3
    assert kind.details["speeds_m_s"] == pytest.approx([speed], rel=0.02)
    assert kind.details["n_reversals"] == 2
    check_record_quality(rec)


def test_real_data_found():
    assert len(LAB_MR) == 5 and len(RIG_A) == 11


# --------------------------------------------------------------------------------------------------
# quality errors: one line, starting with the file path


def raises_one_line(rec: TestRecord, *words: str) -> str:
    with pytest.raises(DataError) as info:
        check_record_quality(rec)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith(f"{rec.path}: "), msg
    for w in words:
        assert w in msg, msg
    return msg


def test_flat_displacement(tmp_path):
    t = np.arange(0.0, 5.0, 0.01)
    y = 1e-3 + np.random.default_rng(0).normal(0, 1e-7, t.size)
    raises_one_line(via_csv(tmp_path, t, y, 100 + np.sin(t), "still"), "displacement_m hardly moves",
                    "no excitation")


def test_flat_force(tmp_path):
    t, y = sine(rate=100, duration=5, amp=5e-3, freq=1.0)
    f = 85.0 + np.random.default_rng(0).normal(0, 0.01, t.size)
    raises_one_line(via_csv(tmp_path, t, y, f, "noforce"), "force_N is flat")
    raises_one_line(record(t, y, np.zeros_like(t)), "force_N is flat")


def test_clipped_force(tmp_path):
    t, y = sine(rate=1000, duration=4, amp=5e-3, freq=1.0)
    f = np.minimum(2500 * np.sin(2 * np.pi * t + 0.3), 2000.0)
    msg = raises_one_line(via_csv(tmp_path, t, y, f, "clip"), "force_N is clipped at 2000 N", "saturated sensor")
    assert "in 4 runs" in msg


def test_clipped_displacement():
    t, y = sine(rate=100, duration=10, amp=5e-3, freq=1.0)
    raises_one_line(record(t, np.clip(y, -4e-3, 4e-3)), "displacement_m is clipped at 0.004 m")


def test_quantised_peaks_and_rest_at_an_end_are_not_clipping():
    t, y = sine(rate=100, duration=10, amp=5e-3, freq=1.0)
    check_record_quality(record(t, np.round(y / 5e-6) * 5e-6))
    t, y = triangle(rate=250, speed=5e-3, amp=5e-3, rest=1.0, cycles=1.0)  # rest at both ends, no noise
    check_record_quality(record(t, y - y.min()))


def test_too_few_samples():
    t, y = sine(rate=100, duration=1.5, amp=5e-3, freq=2.0)
    raises_one_line(record(t, y), "150 samples", "fewer than the 200")


def test_less_than_one_cycle():
    t, y = sine(rate=1000, duration=0.4, amp=5e-3, freq=1.0, noise=1e-6)
    msg = raises_one_line(record(t, y), "record lasts 0.4 s", "less than one cycle of its 1.0 Hz motion")
    assert msg.endswith("(need at least one)")
    assert classify_record(record(t, y)).kind != "sine"


@pytest.mark.parametrize("rate, freq", [(1000, 1.0), (1000, 5.0), (100, 0.5)])
def test_exactly_one_cycle_is_a_sine(rate, freq):
    """n samples of one period (the last sample one interval before the cycle closes) are one cycle, not less."""
    n = int(round(rate / freq))
    t = np.arange(n) / rate
    y = 5e-3 * np.sin(2 * np.pi * freq * t)
    rec = record(t, y)
    check_record_quality(rec)
    kind = classify_record(rec)
    assert kind.kind == "sine" and abs(kind.details["n_cycles"] - 1.0) < 1e-3, kind.details


def test_less_than_one_cycle_through_csv(tmp_path):
    t, y = sine(rate=200, duration=1.4, amp=5e-3, freq=0.5)
    raises_one_line(via_csv(tmp_path, t, y, 100 + np.cos(np.pi * t), "short"), "less than one cycle",
                    "0.50 Hz")


def test_implausible_velocity(tmp_path):
    t, y = sine(rate=10000, duration=1.0, amp=0.06, freq=100.0)
    raises_one_line(via_csv(tmp_path, t, y, 100 + 1e3 * np.sin(2 * np.pi * 100 * t), "fast"),
                    "displacement_m implies velocities up to 37", "m/s: wrong unit or time column?")


def test_inspect_record_checks_and_classifies_like_the_two_calls():
    """``inspect_record`` (one analysis) gives what check_record_quality + classify_record give."""
    from bayesdamper.io.dataset import load_dataset
    from bayesdamper.io.recordkind import inspect_record

    for folder in ("data/rig-A", "data/lab-MR"):
        for r in load_dataset(ROOT / folder, tmax=None).records[:3]:
            check_record_quality(r)
            assert inspect_record(r) == classify_record(r)
