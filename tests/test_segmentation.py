"""Tests of bayesdamper.io.segmentation on synthetic triangles with known corners and on rig-A."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from bayesdamper.core.errors import DataError, SettingsError
from bayesdamper.core.params import RIG_A_DAMPER
from bayesdamper.io.dataset import load_dataset, load_record
from bayesdamper.io.segmentation import PLATEAU_FRACTION, PLATEAU_MARGIN, segment_dataset, segment_record

RIG_A = Path(__file__).resolve().parents[1] / "data" / "rig-A"
AREA = RIG_A_DAMPER.piston_area

#: Step times are continuous (line intersections): noise-free corners come out exact, so a quarter of
#: a sample interval is far better than any sample-picking rule ...
STEP_TIME_TOL_SAMPLES = 0.25
#: ... plus a noise term: two least-squares lines over a few seconds of ramp meet with a time error of
#: about 1.5 sigma_y / (|v| sqrt(fs * 1 s)) here (measured up to 3 of these over many seeds); allow 5.
STEP_TIME_NOISE_SIGMAS = 5 * 1.5
#: Fitted ramp velocities come from least squares over seconds of data: 0.2 % even at the highest noise.
VELOCITY_RTOL = 2e-3
#: Knot displacements of the fitted model [m]: a few times the largest noise level over sqrt(n).
KNOT_ATOL = 2e-6
#: rig-A velocities must match the nominal velocity in the file name (task requirement).
RIG_A_VELOCITY_RTOL = 0.02
#: Synthetic force: steady force per unit speed [N/(m/s)], lag time constant [s], noise [N].
FORCE_PER_SPEED = 5.0e6
FORCE_LAG = 0.3
FORCE_NOISE = 10.0
#: Plateau mean force: noise 10 N over >= 100 samples, plus residual lag (zero after > 10 lags): 0.5 %.
PLATEAU_RTOL = 5e-3


def time_tol(fs: float, noise: float, speed: float) -> float:
    """Tolerance on a knot time [s] at sample rate ``fs`` [Hz] and displacement noise ``noise`` [m]."""
    return STEP_TIME_TOL_SAMPLES / fs + STEP_TIME_NOISE_SIGMAS * noise / (speed * np.sqrt(fs))


@dataclass
class Triangle:
    """A synthetic triangular test with known corners."""

    t: np.ndarray
    y: np.ndarray
    f: np.ndarray
    step_times: np.ndarray  # true velocity-step times [s]
    knot_times: np.ndarray  # all true knots, including the record ends
    knot_y: np.ndarray
    speed: float  # |V_P| [m/s]


def triangle(
    fs: float,
    *,
    noise: float = 0.0,
    rounding: float = 0.0,
    speed: float = 1.5e-3,
    amplitude: float = 5e-3,
    t_rest: float = 1.0123,
    sign: int = 1,
    seed: int = 0,
) -> Triangle:
    """rest -> +A -> -A -> +A (times ``sign``), sampled at ``fs`` [Hz] from t = 0.

    ``rounding`` [s] is the length of a centred moving average applied to the ideal displacement:
    it rounds the corners but keeps the straight parts, whose extensions still meet at the true
    corners. The record ends at the last corner, as rig-A's do.
    """
    rng = np.random.default_rng(seed)
    ramp = amplitude / speed
    corners = t_rest + np.array([0.0, ramp, 3 * ramp, 5 * ramp])
    t = np.arange(0.0, corners[-1] + 0.5 / fs, 1.0 / fs)
    t = t[t <= corners[-1] + 1e-12]
    # knots extended beyond the record so the moving average is defined at both ends
    kt = np.concatenate(([-10.0], corners, [corners[-1] + 10.0]))
    ky = sign * amplitude * np.array([0.0, 0.0, 1.0, -1.0, 1.0, 1.0 - 10.0 * speed / amplitude])
    if rounding > 0:
        # exact moving average: difference of the antiderivative of the piecewise-linear function
        seg = np.concatenate(([0.0], np.cumsum(0.5 * np.diff(kt) * (ky[1:] + ky[:-1]))))

        def antiderivative(x):
            i = np.clip(np.searchsorted(kt, x, side="right") - 1, 0, kt.size - 2)
            yx = np.interp(x, kt, ky)
            return seg[i] + 0.5 * (x - kt[i]) * (ky[i] + yx)

        y = (antiderivative(t + rounding / 2) - antiderivative(t - rounding / 2)) / rounding
    else:
        y = np.interp(t, kt, ky)
    v = np.gradient(np.interp(t, kt, ky), t)
    target = FORCE_PER_SPEED * v
    decay = np.exp(-(1.0 / fs) / FORCE_LAG)
    f = np.empty_like(t)
    f[0] = target[0]
    for k in range(1, t.size):  # first-order lag towards the steady force
        f[k] = target[k] + (f[k - 1] - target[k]) * decay
    y = y + noise * rng.standard_normal(t.size)
    f = f + FORCE_NOISE * rng.standard_normal(t.size)
    knot_times = np.concatenate(([0.0], corners[:-1], [t[-1]]))
    return Triangle(t, y, f, corners[:3], knot_times, np.interp(knot_times, kt, ky), speed)


@pytest.fixture
def load_triangle(make_dataset):
    """Write a Triangle as a one-record data set and load it back through bayesdamper.io.dataset."""

    def load(tri: Triangle, name: str = "tri", tmax: float = 3.0):
        folder = make_dataset({name: (tri.t, tri.y, tri.f)}, folder=f"ds_{name}")
        return load_record(folder / f"{name}.csv", tmax=tmax)

    return load


# ---------------------------------------------------------------------------------------------
# synthetic triangles


@pytest.mark.parametrize("fs", [50.0, 250.0, 2000.0])
@pytest.mark.parametrize("noise", [0.0, 1e-6, 5e-6])
@pytest.mark.parametrize("rounding", [0.0, 0.15])
@pytest.mark.parametrize("sign", [1, -1])
def test_synthetic_triangle(load_triangle, fs, noise, rounding, sign):
    tri = triangle(fs, noise=noise, rounding=rounding, sign=sign, seed=int(fs) + int(1e7 * noise))
    seg = segment_record(load_triangle(tri), RIG_A_DAMPER)
    tol = time_tol(fs, noise, tri.speed)

    assert [s.kind for s in seg.steps] == ["initial", "reversal", "reversal"]
    assert [s.direction for s in seg.steps] == [sign, -sign, sign]
    assert [s.index for s in seg.steps] == [0, 1, 2]
    got = np.array([s.time for s in seg.steps])
    np.testing.assert_allclose(got, tri.step_times, rtol=0, atol=tol)
    for s in seg.steps:
        assert abs(s.velocity_after) == pytest.approx(tri.speed, rel=VELOCITY_RTOL)
        assert np.sign(s.velocity_after) == s.direction
    assert seg.steps[0].velocity_before == 0.0
    assert seg.steps[1].velocity_before == pytest.approx(sign * tri.speed, rel=VELOCITY_RTOL)

    np.testing.assert_allclose(seg.knot_times, tri.knot_times, rtol=0, atol=tol)
    np.testing.assert_allclose(seg.knot_displacements, tri.knot_y, rtol=0, atol=KNOT_ATOL)
    assert len(seg.transients) == 3
    assert len(seg.plateaus) == 3


@pytest.mark.parametrize("fs", [50.0, 250.0, 2000.0])
def test_transient_windows_start_at_step(load_triangle, fs):
    tmax = 3.0
    tri = triangle(fs, noise=1e-6, rounding=0.1, seed=4)
    rec = load_triangle(tri)
    seg = segment_record(rec, RIG_A_DAMPER, tmax=tmax)
    dt = 1.0 / fs
    for step, tr in zip(seg.steps, seg.transients, strict=True):
        assert tr.t_step == step.time
        assert tr.id == f"tri_s{step.index}"
        assert re.fullmatch(r"[A-Za-z0-9_.-]+", tr.id)
        assert (tr.kind, tr.direction, tr.index) == (step.kind, step.direction, step.index)
        assert tr.velocity == abs(step.velocity_after)
        assert tr.t_step <= tr.time[0] < tr.t_step + dt
        assert tr.t_step + tmax - dt < tr.time[-1] <= tr.t_step + tmax
        assert np.all(np.diff(tr.time) > 0)
        assert tr.time.size == tr.force.size == tr.displacement.size
        in_window = (rec.time >= tr.time[0]) & (rec.time <= tr.time[-1])
        np.testing.assert_array_equal(tr.force, rec.force[in_window])
        np.testing.assert_array_equal(tr.displacement, rec.displacement[in_window])
        # the record's input is the fitted piecewise-linear displacement through every knot
        np.testing.assert_array_equal(tr.drive.breaks, seg.knot_times)
        assert tr.drive.degree == 1 and tr.drive.restart.all()  # every knot a velocity step
        # the window's own input runs from the step to the last sample
        local = tr.local_drive
        assert local.start == tr.t_step
        assert local.end == pytest.approx(tr.time[-1], abs=1e-9)
        assert tr.duration == pytest.approx(tmax, abs=dt)
        np.testing.assert_allclose(local.displacement(local.breaks), seg.fitted_displacement(local.breaks), rtol=0,
                                   atol=1e-12)
        # the fitted line in the window moves at the step's velocity
        assert local.coefs[:, 1] == pytest.approx(step.velocity_after, rel=1e-9)
        assert tr.dp0 == pytest.approx(step.force / AREA)
        for a in (tr.time, tr.displacement, tr.force, tr.drive.breaks, tr.drive.coefs):
            assert not a.flags.writeable


def test_step_force_is_a_local_mean_before_the_step(load_triangle):
    tri = triangle(250.0, noise=1e-6, seed=5)
    seg = segment_record(load_triangle(tri), RIG_A_DAMPER)
    steady = FORCE_PER_SPEED * tri.speed
    # 0.15 s of 10 N noise at 250 Hz: standard error 2.6 N; 15 N is ~6 sigma
    assert seg.steps[0].force == pytest.approx(0.0, abs=15.0)
    assert seg.steps[1].force == pytest.approx(steady, abs=15.0)
    assert seg.steps[2].force == pytest.approx(-steady, abs=15.0)
    assert seg.transients[1].dp0 == pytest.approx(steady / AREA, abs=15.0 / AREA)


def test_plateau_rule_defaults(load_triangle):
    fs = 250.0
    tri = triangle(fs, noise=1e-6, rounding=0.1, seed=6)
    seg = segment_record(load_triangle(tri), RIG_A_DAMPER)
    ends = tri.knot_times  # ramp k runs from knot k+1 to knot k+2
    steady_dp = FORCE_PER_SPEED * tri.speed / AREA
    for k, p in enumerate(seg.plateaus):
        ta, tb = ends[k + 1], ends[k + 2]
        assert p.index == k
        assert p.test == "tri"
        assert p.direction == [1, -1, 1][k]
        assert p.velocity == pytest.approx(tri.speed, rel=VELOCITY_RTOL)
        assert p.flow_rate == pytest.approx(AREA * p.velocity)
        # last PLATEAU_FRACTION of the ramp, ending PLATEAU_MARGIN before its end (within a sample)
        assert tb - PLATEAU_MARGIN - 1 / fs <= p.t_end <= tb - PLATEAU_MARGIN
        start = tb - PLATEAU_MARGIN - PLATEAU_FRACTION * (tb - ta)
        assert start <= p.t_start <= start + 1 / fs
        assert p.n == pytest.approx(PLATEAU_FRACTION * (tb - ta) * fs, abs=1.5)
        # magnitude: positive in both directions, the steady force over the area
        assert p.pressure_drop == pytest.approx(steady_dp, rel=PLATEAU_RTOL)
        assert p.pressure_drop_std == pytest.approx(FORCE_NOISE / AREA, rel=0.25)


def test_plateau_rule_is_settable(load_triangle):
    fs = 250.0
    tri = triangle(fs, seed=7)
    seg = segment_record(load_triangle(tri), RIG_A_DAMPER, plateau_fraction=0.5, plateau_margin=0.5)
    tb = tri.knot_times[2]
    ta = tri.knot_times[1]
    p = seg.plateaus[0]
    assert tb - 0.5 - 1 / fs <= p.t_end <= tb - 0.5
    assert tb - 0.5 - 0.5 * (tb - ta) <= p.t_start <= tb - 0.5 - 0.5 * (tb - ta) + 1 / fs


def test_outlier_sample_does_not_move_steps(load_triangle):
    fs = 250.0
    tri = triangle(fs, noise=1e-6, seed=8)
    tri.y[int(2.5 * fs)] += 2e-4  # one 0.2 mm spike in the first ramp
    seg = segment_record(load_triangle(tri), RIG_A_DAMPER)
    got = np.array([s.time for s in seg.steps])
    np.testing.assert_allclose(got, tri.step_times, rtol=0, atol=time_tol(fs, 1e-6, tri.speed))


def test_stop_is_a_knot_but_not_a_step(make_dataset):
    fs = 250.0
    t = np.arange(0.0, 12.0, 1 / fs)
    y = 1e-3 * np.clip(t - 1.3, 0, 5.0)  # rest, 1 mm/s ramp from 1.3 s, stop at 6.3 s, rest
    folder = make_dataset({"stop": (t, y, 4000.0 * ((t > 1.3) & (t < 6.3)))})
    seg = segment_record(load_record(folder / "stop.csv"), RIG_A_DAMPER)
    assert [s.kind for s in seg.steps] == ["initial"]
    np.testing.assert_allclose(seg.knot_times[1:3], [1.3, 6.3], atol=STEP_TIME_TOL_SAMPLES / fs)
    assert len(seg.plateaus) == 1
    assert seg.plateaus[0].t_end <= 6.3 - PLATEAU_MARGIN
    # a window longer than the ramp ends at the stop: the samples from the start to the stop's knot, no further
    long = segment_record(seg.record, RIG_A_DAMPER, tmax=5.5).transients[0]
    stop = float(seg.knot_times[2])
    assert long.time[-1] <= stop < long.time[-1] + 1 / fs
    assert long.time[0] >= long.t_step and long.time.size == np.count_nonzero((t >= long.t_step) & (t <= stop))


def test_segment_dataset_runs_every_record(make_dataset):
    a, b = triangle(250.0, seed=9), triangle(100.0, speed=1e-3, sign=-1, seed=10)
    folder = make_dataset({"b": (b.t, b.y, b.f), "a": (a.t, a.y, a.f)})
    segs = segment_dataset(load_dataset(folder))
    assert [s.name for s in segs] == ["a", "b"]
    assert segs[1].steps[0].direction == -1
    assert segs[1].transients[0].velocity == pytest.approx(1e-3, rel=VELOCITY_RTOL)


# ---------------------------------------------------------------------------------------------
# records that cannot be segmented


def _assert_data_error(call, path: Path, *words: str) -> None:
    with pytest.raises(DataError) as info:
        call()
    msg = str(info.value)
    assert msg.startswith(f"{path}: ") and "\n" not in msg, msg
    for w in words:
        assert re.search(w, msg, flags=re.IGNORECASE), f"{w!r} not in {msg!r}"


def test_rest_only_record_has_no_step(make_dataset):
    rng = np.random.default_rng(11)
    t = np.arange(0.0, 8.0, 0.004)
    folder = make_dataset({"rest": (t, 1e-6 * rng.standard_normal(t.size), rng.standard_normal(t.size))})
    rec = load_record(folder / "rest.csv")
    _assert_data_error(lambda: segment_record(rec, RIG_A_DAMPER), rec.path, "no velocity step")


def test_single_ramp_without_rest_has_no_step(make_dataset):
    t = np.arange(0.0, 8.0, 0.004)
    folder = make_dataset({"ramp": (t, 1e-3 * t, np.full(t.size, 4000.0))})
    rec = load_record(folder / "ramp.csv")
    _assert_data_error(lambda: segment_record(rec, RIG_A_DAMPER), rec.path, "no velocity step")


def test_window_ends_with_the_record(make_dataset):
    t = np.arange(0.0, 4.0, 0.004)
    y = 1e-3 * np.clip(t - 1.5, 0, None)  # the ramp starts 2.5 s before the end; tmax = 3 s
    folder = make_dataset({"short": (t, y, 4000.0 * (t > 1.5))})
    rec = load_record(folder / "short.csv")
    (w,) = segment_record(rec, RIG_A_DAMPER).transients
    assert w.time[-1] == t[-1]  # every sample from the step to the last one
    assert w.t_step == pytest.approx(1.5, abs=STEP_TIME_TOL_SAMPLES * 0.004)


def test_fast_test_windows_end_with_their_ramps(load_triangle):
    """A test whose ramps are shorter than T_max (2.5 mm/s over 5 mm: 2 s out, 4 s between reversals): the window
    after the start ends at the first reversal, the others after T_max; a T_max shorter than every ramp cuts none."""
    tri = triangle(250.0, speed=2.5e-3, amplitude=5e-3)
    rec = load_triangle(tri)
    seg = segment_record(rec, RIG_A_DAMPER, tmax=3.0)
    assert [w.kind for w in seg.transients] == ["initial", "reversal", "reversal"]
    first, *others = seg.transients
    assert first.time[-1] <= seg.knot_times[2] < first.time[-1] + 1 / 250.0  # the first reversal's knot
    assert seg.knot_times[2] - first.t_step == pytest.approx(2.0, abs=0.02)
    for w in others:
        assert w.time[-1] - w.t_step == pytest.approx(3.0, abs=1 / 250.0)
    assert all(w.time[-1] - w.t_step == pytest.approx(1.5, abs=1 / 250.0)
               for w in segment_record(rec, RIG_A_DAMPER, tmax=1.5).transients)


@pytest.mark.parametrize(
    "kwargs",
    [{"tmax": 0.0}, {"plateau_fraction": 0.0}, {"plateau_fraction": 1.5}, {"plateau_margin": -1.0}],
)
def test_bad_settings(load_triangle, kwargs):
    rec = load_triangle(triangle(50.0))
    with pytest.raises(SettingsError):
        segment_record(rec, RIG_A_DAMPER, **kwargs)


# ---------------------------------------------------------------------------------------------
# rig-A


@pytest.fixture(scope="module")
def rig_a():
    return segment_dataset(load_dataset(RIG_A))


def test_rig_a_segmentation(rig_a):
    assert len(rig_a) == 11
    transients = [tr for s in rig_a for tr in s.transients]
    assert len(transients) == 33
    assert len({tr.id for tr in transients}) == 33
    assert sum(len(s.plateaus) for s in rig_a) == 33
    for s in rig_a:
        nominal = float(s.name.split("_")[1].removesuffix("mm").replace("p", ".")) * 1e-3
        assert [st.kind for st in s.steps] == ["initial", "reversal", "reversal"]
        assert [st.direction for st in s.steps] == [1, -1, 1]
        assert s.steps[0].time == pytest.approx(1.0, abs=0.01)  # 1 s at rest (README)
        for tr in s.transients:
            assert tr.velocity == pytest.approx(nominal, rel=RIG_A_VELOCITY_RTOL)
            assert tr.t_step <= tr.time[0] < tr.t_step + 1 / 250
        for p in s.plateaus:
            assert p.velocity == pytest.approx(nominal, rel=RIG_A_VELOCITY_RTOL)
            assert p.pressure_drop > 0
        # the first corner is at +5 mm (README protocol)
        assert s.knot_displacements[2] == pytest.approx(5e-3, rel=0.01)
        # reversal forces: positive before the reversal to -, negative before the reversal to +
        assert s.steps[1].force > 0 > s.steps[2].force
