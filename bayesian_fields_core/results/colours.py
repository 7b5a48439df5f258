"""The colours every view of a result shares: object palette, rank colours, dimming and tint.

Previews, the recoloured exports and the viewer colour objects alike, so a user who saw rank 1
in red in a preview finds it red in the viewer too.
"""

from __future__ import annotations

import colorsys

import numpy as np

from bayesian_fields_core.geometry.spherical_harmonics import SH_C0
from bayesian_fields_core.scene.types import Gaussians

BACKGROUND_GREY = 0.25
"""Colour (in [0, 1]) of Gaussians that belong to no object in the recoloured scene."""

_GOLDEN = 0.618033988749895


def object_palette(num_objects: int, *, saturation: float = 0.75, value: float = 0.95) -> np.ndarray:
    """(num_objects, 3) RGB in [0, 1]: hues stepped by the golden ratio so that neighbouring ids
    (often neighbouring objects) get far-apart colours. A loop over objects, not Gaussians."""
    hues = (np.arange(num_objects) * _GOLDEN) % 1.0
    return np.array([colorsys.hsv_to_rgb(h, saturation, value) for h in hues], dtype=np.float32).reshape(
        -1, 3
    )


RANK_COLOURS = np.array(
    [
        [1.00, 0.25, 0.20],  # rank 1: red
        [1.00, 0.75, 0.10],  # rank 2: amber
        [0.25, 0.85, 0.30],  # rank 3: green
        [0.25, 0.60, 1.00],  # rank 4: blue
        [0.85, 0.35, 1.00],  # rank 5: violet
    ],
    dtype=np.float32,
)
"""Colour of a task's k-th object (cycled past 5) in previews, task exports and the viewer."""

DIM = 0.35
"""Brightness factor of Gaussians outside the task's selection in a preview."""

TINT = 0.65
"""Weight of the rank colour when tinting a selected object's Gaussians (1 = flat colour)."""


def rank_colour(rank: int) -> np.ndarray:
    """(3,) RGB in [0, 1] of the object at 0-based `rank`."""
    return RANK_COLOURS[rank % len(RANK_COLOURS)]


def base_colours(g: Gaussians) -> np.ndarray:
    """(N, 3) view-independent colour of each Gaussian (its degree-0 SH term)."""
    return np.clip(0.5 + SH_C0 * np.asarray(g.sh[:, 0, :], dtype=np.float32), 0.0, 1.0)
