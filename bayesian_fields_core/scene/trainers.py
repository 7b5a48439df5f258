"""The trainer layout table: every layout a scene folder may have, written once.

`scene.layout.resolve_layout` tries the rows that recognise a folder (`markers`) in table order
and resolves the folder with the first that matches; `SceneLayout.trainer` (the result's
`frames.layout`, the upload report's `layout`) is always a row's name; the CLI's "a run folder
may be named by its config file" and the docs' layout table (`markdown_table`, written into
docs/guide/your-scene.md at build time, whose sections a test checks against `heading`) read it
too. Adding a trainer is adding a row here and its resolver, as adding a camera format is a row
of `scene/camera_formats.py`.

A row names its resolver by import path (``module:function``), imported on first use, so this
table imports nothing of the layout code that reads it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bayesian_fields_core.scene.formats.registry import load_function
from bayesian_fields_core.scene.scene_yaml import SCENE_YAML
from bayesian_fields_core.scene.trainer_runs import GSPLAT_CFG, NERFSTUDIO_CFG
from bayesian_fields_core.scene.trainer_transforms import DATAPARSER_TRANSFORMS

LAYOUT_MODULE = "bayesian_fields_core.scene.layout"


@dataclass(frozen=True)
class TrainerLayout:
    """One layout: how a folder is recognised as it, how it is resolved, what a user reads.

    name: `SceneLayout.trainer`, the result's `frames.layout` ('gsplat', 'inria', ...).
    title: what people call it, for the docs' table.
    markers: files that must all be present at the top of a folder for it to be this layout
        (the first is its config when `run_config`); empty: the folder is not recognised by
        files: the row is reached as the fallback (`resolve` with no markers) or names what
        another rule found (`assigned_by`).
    resolve: ``module:function`` of `(folder, *, allow_source_path) -> SceneLayout`; None: the
        layout is never resolved by itself, only named (`assigned_by`).
    run_config: the folder may be given by its config file (`bfields run .../config.yml`).
    assigned_by: how a folder gets this name when no marker decides (a camera format's
        `trainer`, the splat rule, a transform file's kind), in words for the docs.
    heading: the docs section (docs/guide/your-scene.md `## ...`) that describes it; "" none.
    """

    name: str
    title: str
    markers: tuple[str, ...] = ()
    resolve: str | None = None
    run_config: bool = False
    assigned_by: str = ""
    heading: str = ""

    def matches(self, folder: Path) -> bool:
        """The folder is this layout by its files (a row without markers never matches)."""
        return bool(self.markers) and all((folder / name).is_file() for name in self.markers)

    def resolver(self) -> Callable[..., Any]:
        """This row's resolver, `(folder, *, allow_source_path) -> SceneLayout` (typed loosely
        here: the table sits below the layout code it names and imports none of it)."""
        if self.resolve is None:
            raise ValueError(f"trainer layout {self.name!r} is named, not resolved")
        return load_function(self.resolve)


TRAINER_LAYOUTS: tuple[TrainerLayout, ...] = (
    TrainerLayout(
        "scene.yaml",
        "`scene.yaml`: the folder names its parts",
        markers=(SCENE_YAML,),
        resolve=f"{LAYOUT_MODULE}:scene_yaml_layout",
        heading="`scene.yaml` for anything else",
    ),
    TrainerLayout(
        "gsplat",
        "gsplat `simple_trainer` result folder",
        markers=(GSPLAT_CFG,),
        resolve=f"{LAYOUT_MODULE}:gsplat_layout",
        run_config=True,
        assigned_by="also: a `splat_transform.json` holding `camera_to_splat` (gsplat's normalisation)",
        heading="gsplat `simple_trainer`",
    ),
    TrainerLayout(
        "nerfstudio",
        "nerfstudio run folder (splatfacto)",
        markers=(NERFSTUDIO_CFG, DATAPARSER_TRANSFORMS),
        resolve=f"{LAYOUT_MODULE}:nerfstudio_layout",
        run_config=True,
        assigned_by="also: a `dataparser_transforms.json` beside the splat or at the top",
        heading="nerfstudio splatfacto",
    ),
    TrainerLayout(
        "inria",
        "INRIA 3DGS output folder",
        assigned_by="the cameras are a `cameras.json`, or the splat is "
        "`point_cloud/iteration_<N>/point_cloud.ply`",
        heading="INRIA 3DGS",
    ),
    TrainerLayout(
        "matrix",
        "any splat with a `splat_transform.json` holding `splat_to_camera`",
        assigned_by="a transform file holding `splat_to_camera` (or `--splat-transform`)",
    ),
    TrainerLayout(
        "plain",
        "a capture folder: cameras and a splat in their frame",
        resolve=f"{LAYOUT_MODULE}:capture_layout",
        assigned_by="any other folder: the splat and camera rules, then a transform file if one lies there",
        heading="Plain COLMAP + any splat",
    ),
)
"""Rows with markers are tried in table order; the first row that resolves without markers
(`plain`) takes every other folder."""


def trainer_layout_named(name: str) -> TrainerLayout:
    """The row called `name`; KeyError naming the known ones otherwise."""
    for row in TRAINER_LAYOUTS:
        if row.name == name:
            return row
    raise KeyError(f"unknown trainer layout {name!r}; known: {', '.join(r.name for r in TRAINER_LAYOUTS)}")


def run_config_names() -> tuple[str, ...]:
    """The config files a run folder may be given by (`bfields run .../cfg.yml`)."""
    return tuple(row.markers[0] for row in TRAINER_LAYOUTS if row.run_config)


def layout_row(folder: Path) -> TrainerLayout:
    """The row that resolves `folder`: the first whose markers it holds, else the fallback."""
    for row in TRAINER_LAYOUTS:
        if row.resolve is not None and (row.matches(folder) or not row.markers):
            return row
    raise AssertionError("TRAINER_LAYOUTS has no fallback row (a resolver without markers)")


def markdown_table() -> str:
    """The docs' layout table, one row per `frames.layout` value (`docs/_build/hooks.py`)."""
    lines = ["| `frames.layout` | what | recognised by |", "|---|---|---|"]
    for row in TRAINER_LAYOUTS:
        by = " + ".join(f"`{m}`" for m in row.markers)
        by = "; ".join(part for part in (by, row.assigned_by) if part)
        title = f"[{row.title}](#{_anchor(row.heading)})" if row.heading else row.title
        cells = (f"`{row.name}`", title, by)
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(lines) + "\n"


def _anchor(heading: str) -> str:
    """The anchor MkDocs (toc's default slugify) gives a heading: lower case, punctuation and
    backticks dropped, spaces to hyphens."""
    import re

    text = re.sub(r"[^\w\s-]", "", heading.replace("`", "")).strip().lower()
    return re.sub(r"[-\s]+", "-", text)
