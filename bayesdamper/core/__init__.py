"""Core: the error types and the physical constants and parameter containers every layer shares.

Owns :mod:`~bayesdamper.core.errors` (the one-line user errors), :mod:`~bayesdamper.core.params` (damper
constants, flow coefficients, dynamic parameters) and :mod:`~bayesdamper.core.frozen` (read-only arrays that stay
read-only in worker processes). Imports nothing else from bayesdamper; every other
subpackage may import it.
"""
