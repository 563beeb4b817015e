"""Coverage of the 90 % credible intervals over seeded synthetic replicates (slow; run in CI).

Each replicate is one initial transient of eq. (7) data (3 s at 250 Hz, rig-A damper, Fig. 3 flow
coefficients) with fresh noise: white, or AR(1)-coloured with φ = 0.8. The default noise model (AR(1),
scale marginalised) must give 90 % intervals that contain the truth in 80-97 % of replicates for both
α_V and p_R, on both noise types.
"""

from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest

from bayesdamper.core.params import PAPER_FLOW, RIG_A_DAMPER, DynamicParameters
from bayesdamper.inference.stage2 import StageTwoSettings, identify_transient
from bayesdamper.io.segments import Transient
from bayesdamper.io.synthetic import coloured_noise
from bayesdamper.physics.excitation import PiecewiseLinear
from bayesdamper.physics.single_state import simulate_single_state

#: Replicates per noise type (the issue asks for at least 40).
N_REPLICATES = 40
#: Accepted coverage of nominal 90 % intervals: with 40 replicates the binomial sd is 4.7 %, so
#: 80-97 % is about -2 to +1.5 sd around 90 %.
COVERAGE_BAND = (0.80, 0.97)
NOISE_N = 20.0
TRUTH = DynamicParameters(1 / 0.03, 3.0e5)
SPEEDS = (0.5e-3, 1.0e-3, 1.5e-3)


def replicate(args):
    k, phi, noise_model = args if len(args) == 3 else (*args, "ar1")
    rng = np.random.default_rng(1000 + k + (5000 if phi else 0))
    v = SPEEDS[k % len(SPEEDS)]
    t = np.arange(0.0, 3.0, 1 / 250)
    exc = PiecewiseLinear(np.array([0.0, 3.0]), np.array([0.0, 3.0 * v]))
    dp = simulate_single_state(t, exc, RIG_A_DAMPER, PAPER_FLOW, TRUTH, dp0=0.0)
    f = RIG_A_DAMPER.piston_area * dp + coloured_noise(t.size, NOISE_N, phi, rng)
    tr = Transient(f"rep{k}_s0", f"rep{k}", 0, "initial", 1, v, 0.0, t, exc.displacement(t), f, 0.0,
                   exc.knot_times, exc.knot_displacements)
    e = identify_transient(tr, RIG_A_DAMPER, PAPER_FLOW, StageTwoSettings(noise_model=noise_model), seed=k).entry
    return (e["alpha_V"]["lo"] <= TRUTH.liquid_gas_ratio <= e["alpha_V"]["hi"],
            e["p_R_Pa"]["lo"] <= TRUTH.reference_pressure <= e["p_R_Pa"]["hi"], e["converged"])


@pytest.mark.slow
@pytest.mark.parametrize("phi", [0.0, 0.8], ids=["white", "ar1"])
def test_coverage_of_90_percent_intervals(phi):
    with ProcessPoolExecutor(2) as ex:
        res = np.array(list(ex.map(replicate, [(k, phi) for k in range(N_REPLICATES)])))
    cov = res[:, :2].mean(axis=0)
    print(f"phi={phi}: coverage alpha_V {cov[0]:.3f}, p_R {cov[1]:.3f}, converged {res[:, 2].mean():.3f}")
    assert res[:, 2].mean() >= 0.9
    assert COVERAGE_BAND[0] <= cov[0] <= COVERAGE_BAND[1]
    assert COVERAGE_BAND[0] <= cov[1] <= COVERAGE_BAND[1]


@pytest.mark.slow
def test_white_noise_model_is_overconfident_on_coloured_noise():
    """Why AR(1) is the default: on φ = 0.8 noise the white model's 90 % intervals cover less."""
    with ProcessPoolExecutor(2) as ex:
        res = np.array(list(ex.map(replicate, [(k, 0.8, "white") for k in range(N_REPLICATES)])))
    cov = res[:, :2].mean(axis=0)
    print(f"white model on phi=0.8 noise: coverage alpha_V {cov[0]:.3f}, p_R {cov[1]:.3f}")
    # with φ = 0.8 the white model's intervals are ~sqrt((1-φ)/(1+φ)) = 1/3 as wide as they should be
    assert cov[0] < COVERAGE_BAND[0] and cov[1] < COVERAGE_BAND[0]
