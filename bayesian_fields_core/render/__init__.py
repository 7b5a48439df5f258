"""Gaussian-splat rendering: colour, expected and median depth, alpha (torch; gsplat on GPU)."""

from bayesian_fields_core.render.output import RasterSettings, RenderOutput
from bayesian_fields_core.render.renderer import GaussianRenderer, render

__all__ = ["GaussianRenderer", "RasterSettings", "RenderOutput", "render"]
