"""The signal vector through which the composed kernel hands the model's signals to effect hooks.

The composed kernel (:mod:`bayesdamper.physics.compose`) evaluates the model at a time t in a fixed
order and writes every intermediate signal into one float64 array ``sig``; an effect's hooks read the
signals they need by these indices (SI units):

========  ===========================================================================
``T``     time t [s] (absolute record time)
``YA``    measured (actuator) displacement y_A [m], ``VA`` its velocity [m/s] and ``AA`` its acceleration
          [m/s^2] (0 between the knots of a piecewise-linear input, and in the steady state before t0)
``YP``    drive displacement [m]: y_A after the displacement-path effects, then the piston position
          y_P once the series compliance is applied; ``VP`` its velocity [m/s] (v_P after compliance)
``DP``    Δp [Pa]; ``DDP`` dΔp/dt [Pa/s]
``QO``    orifice flow Q_O(Δp) of eq. (8) [m^3/s]; ``Q`` the flow of the path after flow-path effects
``P1``    absolute chamber pressures p_1, ``P2`` p_2 [Pa] (NaN unless an effect supplies them);
          ``DP1``, ``DP2`` their time derivatives [Pa/s]
``V1``    chamber volumes V_1, ``V2`` V_2 [m^3]
``PR``    the window's reference pressure p_R [Pa], ``AV`` its liquid-gas ratio α_V [-], ``BL`` the liquid bulk
          modulus B_0 [Pa] (constants of the solve)
========  ===========================================================================

Hook protocol (every hook is optional; ``z`` is the effect's slice of the state vector, ``p`` its
parameters in the order of its :class:`~bayesdamper.physics.effects.base.Effect`, ``dz`` the slice of
the state derivative it must fill; hooks return scalars or tuples of scalars, never an array: the kernel's
callers of the hooks count no references, :data:`~bayesdamper.physics.composed_template.NO_REFCOUNT`):

* ``displacement(sig, z, p, dz) -> (y, v)``: the displacement path (from sig[YP], sig[VP]);
* ``compliance(p) -> c``: a series compliance [m/N] (the kernel adds them);
* ``flow(sig, z, p, dz) -> q``: the flow path, from sig[Q];
* ``pressures(sig, z, p) -> (p1, p2)``: absolute chamber pressures (replaces the rule of eq. (6));
* ``moduli(sig, z, p) -> (b1, b2)``: the chambers' bulk moduli [Pa] (replaces eq. (3) at the pressures; at most one
  effect);
* ``chamber_flows(sig, z, p) -> (q1, q2)``: extra inflows into chambers 1 and 2 [m^3/s];
* ``derivatives(sig, z, p, dz)``: state derivatives not written by the hooks above;
* ``force(sig, z, p) -> f``: a force added to the measured force [N];
* ``force_acts(p) -> bool``: whether ``force`` adds anything for these parameters (default: it does; an
  effect that acts elsewhere for some structure values says so, and the kernel then computes the force at
  the output times from Δp alone instead of evaluating every signal there);
* ``force_reads(p) -> level``: which signals ``force`` reads for these parameters (default: any,
  :data:`FORCE_READS_ANY`): :data:`FORCE_READS_STATE` t (``T``) and Δp (``DP``) besides its states,
  :data:`FORCE_READS_MOTION` also the motion (``YA``, ``VA``, ``AA``, ``YP``, ``VP``: the input and the
  displacement path). At the output times the
  kernel then sets only those from the dense-output states instead of evaluating the right-hand side there;
* ``initial(sig, p, z)``: the states at the start (sig holds t0, y_A, the velocity before t0 in VA and
  VP, Δp0 and Q_O(Δp0));
* ``state_atol(p, atol_pa, out)``: absolute tolerances of the states (else the module's ``STATE_ATOL``).
"""

from __future__ import annotations

__all__ = ["AA", "AV", "BL", "DDP", "DP", "DP1", "DP2", "FORCE_READS_ANY", "FORCE_READS_MOTION", "FORCE_READS_STATE",
           "N_SIGNALS", "P1", "P2", "PR", "PRESSURE_FLOOR_PA", "Q", "QO", "T", "V1", "V2", "VA", "VP", "YA", "YP"]

T, YA, VA, YP, VP, DP, DDP, QO, Q, P1, P2, DP1, DP2, V1, V2, AA, PR, AV, BL = range(19)
#: Length of the signal vector.
N_SIGNALS = 19
#: Levels of the ``force_reads`` hook: t, Δp and the effect's states; also the motion's signals; any signal.
FORCE_READS_STATE, FORCE_READS_MOTION, FORCE_READS_ANY = 1, 2, 3
#: Absolute pressure below which the bulk modulus is evaluated at this floor [Pa] (about vapour pressure).
PRESSURE_FLOOR_PA = 1.0e4
