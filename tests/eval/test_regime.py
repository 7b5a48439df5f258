"""The realistic perception regime: its cosine algebra on the tiny CLIP, and its calibration on the
sample scene against the paper's likelihoods."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bayesian_fields_core.calibration.model import fit_calibration
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.eval.calibration.ground_truth import collect_scores
from bayesian_fields_core.eval.regime import (
    PAPER_LIKELIHOODS,
    REALISTIC_TOLERANCE,
    Likelihoods,
    RegimeModels,
    ScoreMap,
    WeakEvidenceEncoder,
    regime_models,
)
from bayesian_fields_core.job.pipeline import load_models

SAMPLE = Path(__file__).resolve().parents[2] / "samples" / "tabletop"


def test_the_score_map_hits_the_target_moments() -> None:
    tiny = Likelihoods(mu0=-0.228, mu1=0.639, s=0.171)
    m = ScoreMap.between(tiny, PAPER_LIKELIHOODS)
    assert m.scale * tiny.mu0 + m.offset == pytest.approx(0.20)
    assert m.scale * tiny.mu1 + m.offset == pytest.approx(0.27)
    assert np.hypot(m.scale * tiny.s, m.noise_sd) == pytest.approx(0.035)
    with pytest.raises(InputError, match="must exceed"):
        ScoreMap.between(PAPER_LIKELIHOODS, tiny)  # the regime only ever weakens evidence


def test_cosines_follow_the_map_exactly_and_repeat() -> None:
    models = RegimeModels(load_models())
    encoder = models.encoder
    assert isinstance(encoder, WeakEvidenceEncoder)
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 256, size=(32, 24, 3), dtype=np.uint8) for _ in range(40)]
    texts = ["red mug", "blue box", "green ball"]
    v, t = encoder.encode_images(images), encoder.encode_texts(texts)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(t, axis=1), 1.0, atol=1e-5)
    base_v, base_t = encoder.base.encode_images(images), encoder.base.encode_texts(texts)
    m = encoder.score_map
    expected = m.scale * (base_v @ base_t.T) + m.offset + m.noise_sd * encoder.noise(base_v)[:, None]
    np.testing.assert_allclose(v @ t.T, expected, atol=1e-5)
    np.testing.assert_array_equal(encoder.encode_images(images), v)  # seeded by content
    assert models.calibration is not None and models.calibration.mu1 == 0.27
    assert models.fingerprint != load_models().fingerprint  # its own perception cache
    assert regime_models(load_models(), "strong").encoder.model_id == encoder.base.model_id


def test_calibration_in_the_realistic_regime_matches_the_paper() -> None:
    labels, model_id = collect_scores([SAMPLE], None, max_frames=8, regime="realistic")
    cal = fit_calibration(labels.positive, labels.negative, model_id)
    fitted = Likelihoods(cal.mu0, cal.mu1, cal.s)
    assert "weak-evidence" in model_id
    assert REALISTIC_TOLERANCE.check(fitted, PAPER_LIKELIHOODS) == [], fitted
