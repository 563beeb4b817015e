"""RODAS4 shared by the compiled kernels: coefficients, step-size control, tolerances and status codes.

RODAS4 (Hairer & Wanner, Solving ODEs II, sec. IV.7; coefficients of rodas.f, METH=1): six stages, order
4(3), L-stable and stiffly accurate, with the order-3 dense output of rodas.f and the Gustafsson step
predictor. Both the eq. (7) kernel (:mod:`~bayesdamper.physics.single_state`) and the composed kernel of any
effects (:mod:`~bayesdamper.physics.composed_template`) take their stage arithmetic, dense output and step control
from here.

Status codes of the kernels (``STATUS_MESSAGES`` maps them to text): 0 success (output finite),
1 non-finite state, 2 step-size underflow, 3 maximum number of steps exceeded, 4 a chamber volume
<= 0 on the excitation, 5 invalid input (times, tolerances or parameters), 6 recorded steps that do not fit a
replaying solve (the composed kernel's internal numerical differentiation).
"""

from __future__ import annotations

from numba import njit

#: Default relative tolerance of the kernel: rel. L2 error <= 6e-6 over the prior box (benchmarks/forward.py).
DEFAULT_RTOL = 1e-6
#: Default absolute tolerance of the kernel [Pa] (4e-5 N on rig A; dominates only for |Δp| < 1e4 Pa).
DEFAULT_ATOL = 1e-2
#: Maximum number of accepted steps of one kernel solve: a 30 s window of a 5 Hz sine takes some 30 000 at rtol
#: 1e-7; the budget stops a pathological parameter set (a solve that would never finish) within a second.
MAX_STEPS = 200_000
STATUS_OK, STATUS_NONFINITE, STATUS_STEP_UNDERFLOW = 0, 1, 2
STATUS_MAX_STEPS, STATUS_VOLUME, STATUS_BAD_INPUT = 3, 4, 5
#: The composed kernel could not replay the steps it was given (they do not fit its restart intervals, or a step
#: failed): its caller solves again with error control.
STATUS_REPLAY = 6
STATUS_MESSAGES = {
    STATUS_OK: "success",
    STATUS_NONFINITE: "the pressure difference became non-finite",
    STATUS_STEP_UNDERFLOW: "the step size underflowed",
    STATUS_MAX_STEPS: f"more than {MAX_STEPS} steps were needed",
    STATUS_VOLUME: "a chamber volume is <= 0 on the excitation",
    STATUS_BAD_INPUT: "invalid times, tolerances or parameters",
    STATUS_REPLAY: "the recorded steps did not fit this solve",
}


# RODAS4 coefficients (rodas.f, METH = 1); _E2j, _E3j are its dense-output D2j, D3j.
_GAMMA, _C2, _C3, _C4 = 0.25, 0.386, 0.21, 0.63
_D1, _D2, _D3, _D4 = 0.25, -0.1043, 0.1035, -0.03620000000000023
_A21, _A31, _A32 = 1.544, 0.9466785280815826, 0.2557011698983284
_A41, _A42, _A43 = 3.314825187068521, 2.896124015972201, 0.9986419139977817
_A51, _A52, _A53, _A54 = 1.221224509226641, 6.019134481288629, 12.53708332932087, -0.687886036105895
_C21, _C31, _C32 = -5.6688, -2.430093356833875, -0.2063599157091915
_C41, _C42, _C43 = -0.1073529058151375, -9.594562251023355, -20.47028614809616
_C51, _C52, _C53, _C54 = 7.496443313967647, -10.24680431464352, -33.99990352819905, 11.7089089320616
_C61, _C62, _C63 = 8.083246795921522, -7.981132988064893, -31.52159432874371
_C64, _C65 = 16.31930543123136, -6.058818238834054
_E21, _E22, _E23 = 10.12623508344586, -7.487995877610167, -34.80091861555747
_E24, _E25 = -7.992771707568823, 1.025137723295662
_E31, _E32, _E33 = -0.6762803392801253, 6.087714651680015, 16.43084320892478
_E34, _E35 = 24.76722511418386, -6.594389125716872


# Step-size control of rodas.f: h_new / h in [1/5, 6], safety factor 0.9.
_FAC_SHRINK, _FAC_GROW, _SAFE = 5.0, 1.0 / 6.0, 0.9


@njit(cache=True)
def step_factor(err):
    """Step-size divisor h / h_new from the scaled local error of an order-4(3) step (clamped)."""
    return max(_FAC_GROW, min(_FAC_SHRINK, err**0.25 / _SAFE))


@njit(cache=True)
def predictive_step(h, fac, err, h_acc, err_acc):
    """Next step after an accepted one: Gustafsson's predictive controller (Hairer & Wanner IV.8),
    never larger than the standard controller's ``h / fac``. ``h_acc``, ``err_acc``: previous accepted
    step and its error."""
    fac_g = max(_FAC_GROW, min(_FAC_SHRINK, (h_acc / h) * (err * err / err_acc) ** 0.25 / _SAFE))
    return h / max(fac, fac_g)


# ----------------------------------------------------------------------------- stage arithmetic
# Written once for every kernel. Each helper works on one state component, so a kernel with n states calls
# it per component; ``inline="always"`` makes numba inline them, and the literal stage number folds away.


@njit(cache=True, inline="always")
def stage_time(i, t, h):
    """Time of stage ``i`` (2..6) of the step (t, h)."""
    if i == 2:
        return t + _C2 * h
    if i == 3:
        return t + _C3 * h
    if i == 4:
        return t + _C4 * h
    return t + h


@njit(cache=True, inline="always")
def stage_point(i, x, k1, k2, k3, k4):
    """State at which stage ``i`` (2..5) evaluates the right-hand side: x + sum_j a_ij k_j."""
    if i == 2:
        return x + _A21 * k1
    if i == 3:
        return x + _A31 * k1 + _A32 * k2
    if i == 4:
        return x + _A41 * k1 + _A42 * k2 + _A43 * k3
    return x + _A51 * k1 + _A52 * k2 + _A53 * k3 + _A54 * k4


@njit(cache=True, inline="always")
def stage_rhs(i, f, h, ft, k1, k2, k3, k4, k5):
    """Right-hand side of the linear system of stage ``i`` (1..6): f + h d_i dF/dt + sum_j c_ij k_j / h.

    The stage increment is then k_i = (1/(h γ) - J)^-1 times this; ``ft`` is the explicit time derivative
    of the component's right-hand side (0 where it has none)."""
    if i == 1:
        return f + h * _D1 * ft
    if i == 2:
        return f + h * _D2 * ft + (_C21 * k1) / h
    if i == 3:
        return f + h * _D3 * ft + (_C31 * k1 + _C32 * k2) / h
    if i == 4:
        return f + h * _D4 * ft + (_C41 * k1 + _C42 * k2 + _C43 * k3) / h
    if i == 5:
        return f + (_C51 * k1 + _C52 * k2 + _C53 * k3 + _C54 * k4) / h
    return f + (_C61 * k1 + _C62 * k2 + _C63 * k3 + _C64 * k4 + _C65 * k5) / h


@njit(cache=True, inline="always")
def dense_coefficients(k1, k2, k3, k4, k5):
    """The two coefficients of the order-3 dense output of rodas.f on an accepted step."""
    cd3 = _E21 * k1 + _E22 * k2 + _E23 * k3 + _E24 * k4 + _E25 * k5
    cd4 = _E31 * k1 + _E32 * k2 + _E33 * k3 + _E34 * k4 + _E35 * k5
    return cd3, cd4


@njit(cache=True, inline="always")
def dense_value(x, x_new, cd3, cd4, s):
    """Dense output at the fraction ``s`` in [0, 1] of the accepted step from x to x_new."""
    return x * (1.0 - s) + s * (x_new + (1.0 - s) * (cd3 + s * cd4))


@njit(cache=True, inline="always")
def dense_slope(x, x_new, cd3, cd4, s, h):
    """Time derivative of :func:`dense_value` (step length ``h``)."""
    return (x_new - x + (1.0 - 2.0 * s) * cd3 + s * (2.0 - 3.0 * s) * cd4) / h
