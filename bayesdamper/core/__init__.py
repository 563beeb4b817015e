"""Core: the error types and the physical constants and parameter containers every layer shares.

Owns :mod:`~bayesdamper.core.errors` (the one-line user errors) and :mod:`~bayesdamper.core.params` (damper
constants, flow coefficients, dynamic parameters). Imports nothing else from bayesdamper; every other
subpackage may import it.
"""
