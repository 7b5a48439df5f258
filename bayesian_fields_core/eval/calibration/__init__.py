"""`bfields calibrate` as library calls: fit a CLIP model's likelihoods from labelled scores or
from scenes with ground truth (`fit`), the latter scored through the pipeline's own stages
(`ground_truth`)."""
