"""Fusion: turn per-frame cosine scores into per-Gaussian task probabilities.

`likelihood` (measurement model), `visibility` (which Gaussians a mask sees), `bayes` (recursive
log-odds update with OR-phi), `averaging` (the ablation baseline), `calibration` (per-model fits).
"""
