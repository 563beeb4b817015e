"""Physics: the damper models and their compiled solvers, driven by any displacement history.

Owns the orifice law (eq. (8)), the pressure-difference bulk modulus (eq. (6)), the displacement input as
polynomial pieces (piecewise linear for a triangular test, a smoothing spline for a measured record), the RODAS4
kernel of the single-state model (eq. (7)), the kernel generator that composes eq. (7) with any set of effects
(:mod:`~bayesdamper.physics.compose`; eq. (7) is the set with no effects, and the hand-written eq. (7) kernel is
its fast path), the effect library and the scipy references (eq. (7), the two-state eq. (1)). May import only
:mod:`bayesdamper.core`.
"""
