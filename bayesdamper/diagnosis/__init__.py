"""Diagnosis: the structured residual of a calibrated model, its features, the candidate effects
and the selection loop that adds an effect, refits and reports the error before and after.

May import core, physics, io and inference; it computes and returns results, the run layer writes them.
"""
