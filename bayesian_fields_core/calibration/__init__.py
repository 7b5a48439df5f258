"""Calibration of the likelihoods (METHOD step 3): the fitted `Calibration` (mu0, mu1, s per CLIP
model id), its fit and its JSON file (`model`). Perception reads it to pick a model's file.

Fitting from labelled scores or from scenes with ground truth (`bfields calibrate`) runs the
pipeline, so it lives higher up, in `eval.calibration`.
"""
