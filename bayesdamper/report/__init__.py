"""Report: matplotlib figures (the paper's figures, the diagnostic plots) and the HTML report.

Reads results; never fits. May import every layer below it (core, physics, io, inference, diagnosis).
"""
