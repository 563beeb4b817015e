"""Run orchestration: the check, identify, diagnose and report jobs with resume, settings
fingerprints, atomic output folders, progress display, parallel workers and the Dask scheduler.

The top of the library: may import every other subpackage; only :mod:`bayesdamper.cli` imports it.
"""
