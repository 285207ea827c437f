"""Sections of the benchmark report (``benchmarks/report.py``), one module per family.

``dsp``: the estimator ladder and the chirp linearization (ILC); ``phase_noise``: laser phase-noise
compensation (detection probability, loss at any range); ``frame``: the end-to-end frame (scaling
laws, the reference frame against the limit kernel); ``system``: accuracy on the simulated bench,
simulator fidelity, daemon load, kernels, link budget, hidden tolerances. Each section is a
function ``(quick, img_dir, log) -> Section`` listed in ``benchmarks.report.SECTIONS``.
"""
