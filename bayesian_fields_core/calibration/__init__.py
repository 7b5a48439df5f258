"""Calibration of the likelihoods (METHOD step 3), in one place.

- `model`: the fitted `Calibration` (mu0, mu1, s per CLIP model id), its fit and its JSON file;
- `ground_truth`: labelled scores from scenes with ground truth, through the pipeline's own stages;
- `entry`: `calibrate(CalibrationRequest)`, the typed entry point `bfields calibrate` calls.
"""
