"""Physics: the damper models and their compiled solvers, driven by any displacement history.

Owns the orifice law (eq. (8)), the pressure-difference bulk modulus (eq. (6)), the piecewise-linear
excitation, the RODAS4 kernels of the single-state model (eq. (7)), the two-state reference (eq. (1)) and the
effect library with its augmented kernel. May import only :mod:`bayesdamper.core`.
"""
