"""The Clio-style baseline's p(y|x), built by Clio's rules (`eval/clio_rows.py`), on hand-made cosines."""

from __future__ import annotations

import numpy as np
import pytest

from bayesian_fields_core.eval.clio_rows import DROPPED, clio_conditionals, clio_null_score


def test_clio_threshold_carried_to_a_calibration() -> None:
    assert clio_null_score(0.20, 0.27) == pytest.approx(0.23)  # Clio's own sims_thres
    assert clio_null_score(-0.228, 0.639) == pytest.approx(-0.228 + 3 / 7 * 0.867)


def test_top_two_cumulative_weights_and_the_rest_dropped() -> None:
    cos = np.array([[0.30, 0.25, 0.10]])  # null 0.23 is third: dropped like the third task
    rows = clio_conditionals(cos, 0.23)
    raw = np.array([2 * 0.30, 0.25, 0.0, 0.0]) + DROPPED
    np.testing.assert_allclose(rows[0], raw / raw.sum())
    assert rows.shape == (1, 4) and rows.sum() == pytest.approx(1.0)


def test_a_primitive_whose_best_score_is_the_null_task_is_certain_of_it() -> None:
    rows = clio_conditionals(np.array([[0.21, 0.15, 0.22]]), 0.23)
    assert rows[0, -1] == pytest.approx(1.0) and rows[0, :-1].max() < 1e-10


def test_the_null_task_in_second_place_keeps_its_score() -> None:
    rows = clio_conditionals(np.array([[0.26, 0.10]]), 0.23)
    raw = np.array([2 * 0.26, DROPPED, 0.23]) + np.array([DROPPED, 0, DROPPED])
    np.testing.assert_allclose(rows[0], raw / raw.sum())


def test_negative_cosines_are_clipped_and_not_cumulative_weighs_equally() -> None:
    rows = clio_conditionals(np.array([[-0.5, 0.4]]), 0.1, cumulative=False)
    raw = np.array([DROPPED, 0.4 + DROPPED, 0.1 + DROPPED])
    np.testing.assert_allclose(rows[0], raw / raw.sum())


def test_sparse_rows_carry_information_that_normalised_cosines_do_not() -> None:
    """Why the baseline changed: with a real CLIP's narrow range, normalising (cos + 1) / 2 makes
    every row almost uniform, while Clio's rows separate primitives of different tasks."""
    rng = np.random.default_rng(0)
    cos = 0.2 + 0.035 * rng.standard_normal((200, 8))
    cos[:100, 0] += 0.07  # half the primitives are relevant to task 0
    old = np.concatenate([(cos + 1) / 2, np.full((200, 1), 0.6)], axis=1)
    old /= old.sum(axis=1, keepdims=True)
    new = clio_conditionals(cos, 0.23)
    assert old.max() < 0.15  # 9 columns: uniform would be 0.111
    assert np.median(new[:100, 0]) > 0.6 and np.median(new.max(axis=1)) > 0.6
