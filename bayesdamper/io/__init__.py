"""Input and output: data sets on disk, their validation, segmentation into transients, synthetic data
sets and atomic writing of results.

Owns what a record is and how it is cut into plateaus and transients. May import :mod:`bayesdamper.core` and
:mod:`bayesdamper.physics` (the synthetic generator simulates); never inference, diagnosis, report or run.
"""
