"""Fusion: turn per-frame cosine scores into per-Gaussian task probabilities.

`likelihood` (measurement model), `visibility` (which Gaussians a mask sees), `bayes` (recursive
log-odds update with OR-phi, correlated-views discount), `peak` (best single view per task),
`averaging` (the ablation baseline), `state` (one run's state, frame by frame), `tensors` (host /
device moves). The per-Gaussian ops are written once, in torch, and run on the CPU and on a GPU
alike; calibration files live in `bayesian_fields_core.calibration`.
"""
