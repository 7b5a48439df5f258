"""The primitive rule traced by hand over a short sequence of frames, and p(y|x) per primitive."""

import numpy as np
import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.objects.primitives import PrimitiveBuilder
from bayesian_fields_core.objects.probabilities import primitive_probabilities


def _frame(builder: PrimitiveBuilder, masks: list[list[int]], accepted: list[bool]) -> None:
    gids = np.array([g for ids in masks for g in ids], dtype=np.int64)
    mids = np.array([m for m, ids in enumerate(masks) for _ in ids], dtype=np.int32)
    builder.add_frame(gids, mids, np.array(accepted))


def test_primitive_rule_hand_traced() -> None:
    b = PrimitiveBuilder(6)
    # Frame 1: fresh Gaussians -> P0 = {0,1,2,3}, P1 = {4}; Gaussian 5 unseen.
    _frame(b, [[0, 1, 2, 3], [4]], [True, True])
    assert b.raw_ids.tolist() == [0, 0, 0, 0, 1, -1]
    # Frame 2: mask 0 = {0,1} (|G|=2): |P0| = 4 is not < 2 -> move to P2.
    # Mask 1 = {2,3,4,5} (|G|=4): 2,3 in P0 with |P0| = 4 at frame start, not < 4 -> move to P3;
    # 4 in P1, |P1| = 1 < 4 -> stays; 5 unassigned -> P3. (Sizes from the frame start: applied
    # sequentially, mask 0 would have shrunk P0 to 2 and 2,3 would have stayed.)
    _frame(b, [[0, 1], [2, 3, 4, 5]], [True, True])
    assert b.raw_ids.tolist() == [2, 2, 3, 3, 1, 3]
    # Frame 3: the only mask is rejected by OR-phi -> nothing changes.
    _frame(b, [[0, 1, 2, 3, 4, 5], []], [False, True])
    assert b.raw_ids.tolist() == [2, 2, 3, 3, 1, 3]
    # Frame 4: one big mask; every primitive (sizes 2, 3, 1) is smaller than 6 -> all stay and no
    # (empty) new primitive is allocated.
    _frame(b, [[0, 1, 2, 3, 4, 5]], [True])
    assert b.raw_ids.tolist() == [2, 2, 3, 3, 1, 3]
    assert b.num_raw_primitives == 4
    # P0 became empty: compact ids renumber 1, 2, 3 -> 0, 1, 2 in creation order.
    assert b.primitive_ids.tolist() == [1, 1, 2, 2, 0, 2]
    assert b.primitive_ids.dtype == np.int32


def test_builder_grows_past_initial_capacity() -> None:
    n = 5000
    b = PrimitiveBuilder(n)
    ids = np.arange(n)
    # 2,500 two-Gaussian masks in one frame, then each Gaussian alone (size 1 < 2 is false ->
    # every Gaussian moves to its own new primitive).
    b.add_frame(ids, ids // 2, np.ones(n // 2, dtype=bool))
    b.add_frame(ids, ids, np.ones(n, dtype=bool))
    assert b.num_raw_primitives == n // 2 + n
    assert np.array_equal(b.primitive_ids, ids)


def test_builder_rejects_bad_mask_ids() -> None:
    with pytest.raises(InputError, match="mask_ids"):
        PrimitiveBuilder(3).add_frame(np.array([0]), np.array([2]), np.array([True]))


def test_primitive_probabilities_hand_values() -> None:
    ids = np.array([0, 0, 1, -1])
    probs = np.array([[0.2, 0.4], [0.4, 0.6], [0.5, 0.0], [0.9, 0.9]], dtype=np.float32)
    pyx = primitive_probabilities(ids, probs)
    # P0: mean (0.3, 0.5), null 0.7 * 0.5 = 0.35, total 1.15. P1: (0.5, 0), null 0.5, total 1.
    np.testing.assert_allclose(pyx, [[0.3 / 1.15, 0.5 / 1.15, 0.35 / 1.15], [0.5, 0.0, 0.5]], rtol=1e-6)
    # 1 - max: P0 null 0.5, total 1.3.
    alt = primitive_probabilities(ids, probs, null_mode="one_minus_max")
    np.testing.assert_allclose(alt[0], [0.3 / 1.3, 0.5 / 1.3, 0.5 / 1.3], rtol=1e-6)
    with pytest.raises(InputError, match="null"):
        primitive_probabilities(ids, probs, null_mode="bogus")
