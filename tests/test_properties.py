"""Property tests: the loaders fail only with DataError, the forward model and the log-posterior stay finite.

Hypothesis draws the inputs; example counts are modest so the default suite stays fast.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bayesdamper.core.errors import DataError
from bayesdamper.core.params import PAPER_FLOW, RIG_A_DAMPER
from bayesdamper.inference.likelihood import LogPosterior, make_noise_model
from bayesdamper.inference.priors import ALPHA_V_BOUNDS, P_R_BOUNDS, PHI_BOUNDS, ParameterSpace
from bayesdamper.inference.problem import LIKELIHOOD_ATOL, LIKELIHOOD_RTOL, WindowProblem
from bayesdamper.io.dataset import COLUMNS, DAMPER_FILE, load_dataset
from bayesdamper.physics.excitation import PiecewisePolynomial
from bayesdamper.physics.single_state import solve_single_state

#: Examples per loader property (files are tiny: each example is a few milliseconds).
LOADER_EXAMPLES = 60
#: Examples per model property (each is one or a few forward solves of a 3 s window).
MODEL_EXAMPLES = 40

HEADER = ",".join(COLUMNS)
VALID_TOML = """\
[damper]
name = "fuzz"
piston_area_m2 = 0.0042
chamber_volume_1_m3 = 0.00015
chamber_volume_2_m3 = 0.00015
liquid_bulk_modulus_Pa = 1.5e9
"""


def _valid_csv() -> str:
    t = np.arange(0.0, 6.0, 0.01)
    y = np.clip(t - 1.5, 0, None) * 1e-3
    f = 4000.0 * (t > 1.5)
    rows = "\n".join(f"{a:.6f},{b:.9e},{c:.4f}" for a, b, c in zip(t, y, f, strict=True))
    return f"{HEADER}\n{rows}\n"


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    """A data-set folder whose files each example overwrites."""
    return tmp_path_factory.mktemp("fuzz_ds")


def _only_data_error(folder: Path, toml: bytes, csv: bytes) -> None:
    (folder / DAMPER_FILE).write_bytes(toml)
    (folder / "test_a.csv").write_bytes(csv)
    try:
        load_dataset(folder, tmax=0.5)
    except DataError as e:
        msg = str(e)
        assert "\n" not in msg and msg.startswith(str(folder)), msg


_LOADER = settings(max_examples=LOADER_EXAMPLES, deadline=None,
                   suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


@_LOADER
@given(raw=st.binary(max_size=300))
def test_arbitrary_toml_bytes_only_raise_data_error(folder, raw):
    _only_data_error(folder, raw, _valid_csv().encode())


_toml_value = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10**20, 10**20).map(str),
    st.text(alphabet="abc\"'[]{}=., 0123456789", max_size=10).map(lambda s: '"' + s.replace('"', "") + '"'),
    st.sampled_from(["true", "[1, 2]", "{a = 1}", "nan", "-inf", "1e400", "0", "-1", "1_000"]),
)
_toml_key = st.sampled_from(["name", "piston_area_m2", "chamber_volume_1_m3", "chamber_volume_2_m3",
                             "liquid_bulk_modulus_Pa", "C_L12", "C_Q12", "C_L21", "C_Q21", "extra"])


@_LOADER
@given(tables=st.lists(st.tuples(st.sampled_from(["damper", "flow", "other", "damper.sub"]),
                                 st.dictionaries(_toml_key, _toml_value, max_size=10)), max_size=3))
def test_arbitrary_toml_tables_only_raise_data_error(folder, tables):
    text = "".join(f"[{name}]\n" + "".join(f"{k} = {v}\n" for k, v in kv.items()) for name, kv in tables)
    _only_data_error(folder, text.encode(), _valid_csv().encode())


@_LOADER
@given(raw=st.binary(max_size=400))
def test_arbitrary_csv_bytes_in_a_dataset_only_raise_data_error(folder, raw):
    _only_data_error(folder, VALID_TOML.encode(), raw)


_cell = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr),
                  st.text(alphabet="0123456789.eE+-naif ,\"_\t", max_size=8))


@_LOADER
@given(header=st.lists(st.sampled_from([*COLUMNS, "x", "", "time_s"]), max_size=5),
       rows=st.lists(st.lists(_cell, min_size=1, max_size=4), max_size=10))
def test_arbitrary_header_and_rows_only_raise_data_error(folder, header, rows):
    text = ",".join(header) + "\n" + "\n".join(",".join(r) for r in rows) + "\n"
    _only_data_error(folder, VALID_TOML.encode(), text.encode())


# ---------------------------------------------------------------------------------------------
# forward model

#: Sample times of a 3 s transient window at 100 Hz [s].
T_OUT = np.linspace(0.0, 3.0, 301)
#: Largest piston speed of the property [m/s] and the plateau Δp there, eq. (4), worse direction [Pa].
V_MAX = 2.0e-3
_Q = RIG_A_DAMPER.piston_area * V_MAX
DP_MAX = max(PAPER_FLOW.laminar_12 * _Q + PAPER_FLOW.quadratic_12 * _Q**2,
             PAPER_FLOW.laminar_21 * _Q + PAPER_FLOW.quadratic_21 * _Q**2)


def _solve(alpha_v: float, p_r: float, velocity: float, dp0: float, y0: float = 0.0):
    d = RIG_A_DAMPER
    knot_t = np.array([0.0, 3.0])
    knot_y = np.array([y0, y0 + 3.0 * velocity])
    return solve_single_state(T_OUT, knot_t, knot_y, float(dp0), d.piston_area, d.chamber_volume_1,
                              d.chamber_volume_2, d.liquid_bulk_modulus, PAPER_FLOW.as_array(),
                              float(alpha_v), float(p_r), 0, 0.0, LIKELIHOOD_RTOL, LIKELIHOOD_ATOL)


_MODEL = settings(max_examples=MODEL_EXAMPLES, deadline=None, derandomize=True,
                  suppress_health_check=[HealthCheck.too_slow])


@_MODEL
@given(log_alpha=st.floats(np.log(ALPHA_V_BOUNDS[0]), np.log(ALPHA_V_BOUNDS[1])),
       log_p_r=st.floats(np.log(P_R_BOUNDS[0]), np.log(P_R_BOUNDS[1])),
       speed=st.floats(0.05e-3, V_MAX), sign=st.sampled_from([1.0, -1.0]),
       dp0_fraction=st.floats(-1.0, 1.0), y0=st.floats(-5e-3, 5e-3))
def test_forward_model_succeeds_over_the_prior_box(log_alpha, log_p_r, speed, sign, dp0_fraction, y0):
    """Anywhere in the prior box, either direction, any initial Δp up to the 2 mm/s plateau: status 0."""
    dp, status, _ = _solve(np.exp(log_alpha), np.exp(log_p_r), sign * speed, dp0_fraction * DP_MAX, y0)
    assert status == 0
    assert np.all(np.isfinite(dp))
    assert np.max(np.abs(dp)) < 10 * DP_MAX  # bounded by the plateau pressures, with room for overshoot


@pytest.mark.parametrize("alpha_v", ALPHA_V_BOUNDS)
@pytest.mark.parametrize("p_r", P_R_BOUNDS)
@pytest.mark.parametrize("velocity", [V_MAX, -V_MAX])
@pytest.mark.parametrize("dp0_fraction", [-1.0, 0.0, 1.0])
def test_forward_model_succeeds_at_the_corners_of_the_prior_box(alpha_v, p_r, velocity, dp0_fraction):
    dp, status, _ = _solve(alpha_v, p_r, velocity, dp0_fraction * DP_MAX)
    assert status == 0
    assert np.all(np.isfinite(dp))


@_MODEL
@given(alpha_v=st.floats(1e-6, 1e9), p_r=st.floats(1e-3, 1e10), velocity=st.floats(-0.05, 0.05),
       dp0=st.floats(-1e9, 1e9))
def test_forward_model_output_is_finite_whenever_status_is_zero(alpha_v, p_r, velocity, dp0):
    """Far outside the prior box the solve may fail, but only by its status, never with a silent NaN."""
    dp, status, _ = _solve(alpha_v, p_r, velocity, dp0)
    assert status in (0, 1, 2, 3, 4, 5)
    if status == 0:
        assert np.all(np.isfinite(dp))


# ---------------------------------------------------------------------------------------------
# log-posterior


def _problem() -> WindowProblem:
    d = RIG_A_DAMPER
    velocity = 1.0e-3
    knot_t, knot_y = np.array([0.0, 3.0]), np.array([0.0, 3.0 * velocity])
    dp, status, _ = _solve(1 / 0.03, 3e5, velocity, 0.0)
    assert status == 0
    force = d.piston_area * dp + 20.0 * np.random.default_rng(0).standard_normal(T_OUT.size)
    return WindowProblem("fuzz_s0", T_OUT, force, 0.0, 0.0, PiecewisePolynomial.from_knots(knot_t, knot_y), d,
                         PAPER_FLOW)


PROBLEM = _problem()
POSTERIORS = {name: LogPosterior(PROBLEM, make_noise_model(name),
                                 ParameterSpace.default(make_noise_model(name).params))
              for name in ("ar1", "white")}

_any = st.floats(allow_nan=True, allow_infinity=True)
_coord = {"alpha_V": st.one_of(st.floats(np.log(ALPHA_V_BOUNDS[0]), np.log(ALPHA_V_BOUNDS[1])), _any),
          "p_R_Pa": st.one_of(st.floats(np.log(P_R_BOUNDS[0]), np.log(P_R_BOUNDS[1])), _any),
          "phi": st.one_of(st.floats(*PHI_BOUNDS), st.sampled_from([-1.0, 1.0, 0.9999999]), _any)}


@_MODEL
@given(data=st.data(), noise=st.sampled_from(["ar1", "white"]))
def test_log_posterior_is_never_nan(data, noise):
    lp = POSTERIORS[noise]
    theta = np.array([data.draw(_coord[n], label=n) for n in lp.space.names])
    value = lp(theta)
    assert isinstance(value, float)
    assert not np.isnan(value)
    assert value < np.inf
    inside = np.all(np.isfinite(theta)) and np.all((theta >= lp.space.lower) & (theta <= lp.space.upper))
    if not inside:
        assert value == -np.inf
    batch = lp.batch(np.stack([theta, (lp.space.lower + lp.space.upper) / 2]))
    assert batch.shape == (2,) and not np.any(np.isnan(batch))
    assert batch[0] == value
