"""Over-segmentation of the Gaussians into 3D primitives over time (paper Sec. 4.3).

For each accepted mask `L_i` with visible Gaussians `G_i`: Gaussians without a primitive join a
new primitive `P_new`; a Gaussian already in primitive `P` stays if `|P| < |G_i|`, otherwise it
moves to `P_new`. A smaller mask therefore carves its Gaussians out of a larger primitive, while a
larger mask leaves finer primitives intact: the scene ends up split at the finest granularity any
view segmented it at.

Order within a frame: the masks of one frame are applied simultaneously, every `|P|` being the size
at the start of the frame. Masks of a frame are disjoint in Gaussians, so they interact only when
two of them take Gaussians from the same primitive; a sequential order would then make the result
depend on the arbitrary mask numbering, which the simultaneous rule avoids, and it vectorises.
Masks rejected by OR-phi are skipped (paper: "we do not run the primitive assignment").
"""

from __future__ import annotations

import numpy as np

from bayesian_fields_core.errors import InputError


class PrimitiveBuilder:
    """Incremental primitive assignment of `num_gaussians` Gaussians, frame by frame."""

    def __init__(self, num_gaussians: int) -> None:
        self._assignment = np.full(num_gaussians, -1, dtype=np.int64)
        self._sizes = np.zeros(1024, dtype=np.int64)  # grows by doubling; index = raw primitive id
        self._next_id = 0

    @property
    def num_raw_primitives(self) -> int:
        """Primitive ids allocated so far, including ones that have since become empty."""
        return self._next_id

    def _reserve(self, count: int) -> None:
        needed = self._next_id + count
        if needed > self._sizes.size:
            grown = np.zeros(max(needed, 2 * self._sizes.size), dtype=np.int64)
            grown[: self._sizes.size] = self._sizes
            self._sizes = grown

    def add_frame(self, gaussian_ids: np.ndarray, mask_ids: np.ndarray, accepted: np.ndarray) -> None:
        """Apply one frame's associations (as from `mask_associations`) and OR-phi flags (M,)."""
        gaussian_ids = np.asarray(gaussian_ids, dtype=np.int64)
        mask_ids = np.asarray(mask_ids, dtype=np.int64)
        accepted = np.asarray(accepted, dtype=bool)
        if gaussian_ids.shape != mask_ids.shape or gaussian_ids.ndim != 1:
            raise InputError("gaussian_ids and mask_ids must be 1-D of equal length", source="primitives")
        if mask_ids.size and (mask_ids.min() < 0 or mask_ids.max() >= accepted.size):
            raise InputError(f"mask id outside [0, {accepted.size})", source="primitives.mask_ids")
        keep = accepted[mask_ids]
        g, m = gaussian_ids[keep], mask_ids[keep]
        if g.size == 0:
            return
        num_masks = accepted.size
        mask_size = np.bincount(m, minlength=num_masks)

        current = self._assignment[g]
        has = current >= 0
        current_size = np.where(has, self._sizes[np.where(has, current, 0)], 0)
        stays = has & (current_size < mask_size[m])
        moves = ~stays

        # One new primitive per mask that actually receives Gaussians (no empty primitives).
        moved_per_mask = np.bincount(m[moves], minlength=num_masks)
        receiving = moved_per_mask > 0
        new_ids = np.full(num_masks, -1, dtype=np.int64)
        new_ids[receiving] = self._next_id + np.arange(int(receiving.sum()))
        self._reserve(int(receiving.sum()))
        self._next_id += int(receiving.sum())

        leaving = current[moves & has]
        self._sizes[: self._next_id] -= np.bincount(leaving, minlength=self._next_id)[: self._next_id]
        self._sizes[new_ids[receiving]] = moved_per_mask[receiving]
        self._assignment[g[moves]] = new_ids[m[moves]]

    @property
    def raw_ids(self) -> np.ndarray:
        """(N,) int64 raw primitive ids (-1 = none), not renumbered; a view, do not modify."""
        return self._assignment

    @property
    def primitive_ids(self) -> np.ndarray:
        """(N,) int32 compact primitive ids `0..P-1` in creation order, -1 for no primitive.

        Primitives emptied by later frames are dropped by the renumbering.
        """
        assigned = self._assignment >= 0
        present = np.zeros(self._next_id + 1, dtype=bool)
        present[self._assignment[assigned]] = True
        compact = np.cumsum(present) - 1
        out = np.full(self._assignment.shape, -1, dtype=np.int32)
        out[assigned] = compact[self._assignment[assigned]]
        return out
