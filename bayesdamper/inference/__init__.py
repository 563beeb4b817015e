"""Inference: stage 1 (static coefficients from plateaus), the point fit, priors, the eq. (9)
likelihood, emcee sampling with its convergence rules, the NetCDF posterior store and drift with speed.

May import :mod:`bayesdamper.core`, :mod:`bayesdamper.physics` and :mod:`bayesdamper.io`; all arviz calls
live in :mod:`~bayesdamper.inference.posterior`.
"""
