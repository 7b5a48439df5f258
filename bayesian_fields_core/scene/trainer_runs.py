"""Trainers' run folders as they are: a gsplat `result_dir` (cfg.yml) and a nerfstudio run
(config.yml), resolved to a `SceneLayout` without the user writing any transform file.

gsplat `simple_trainer` writes `cfg.yml` (`yaml.dump(vars(cfg))`: `data_dir`, `data_factor`,
`normalize_world_space`, ... plus python-object tags for its strategy), `ckpts/ckpt_<step>_rank0.pt`
and, with `--save_ply`, `ply/point_cloud_<step>.ply`. The data folder holds the COLMAP model
(`sparse/0` or `sparse`) and `images` (`images_<factor>` when data_factor > 1). We recompute the
world normalisation (`scene.gsplat_normalise`) when `normalize_world_space` is true.

nerfstudio writes `outputs/<exp>/<method>/<timestamp>/config.yml` (a YAML dump of its config
dataclasses, the data folder as a `pathlib` object tag) and `dataparser_transforms.json` beside
it; `ns-export gaussian-splat` writes `splat.ply` where the user says, usually `exports/...` in
or beside the run. We look for the splat in the run folder (and its `exports/`), and for the
cameras in the data folder: transforms.json, else the COLMAP model, `colmap/sparse/0` included.

The YAML is read with a safe loader that turns every python tag into plain data (a mapping, a
list or None); nothing is constructed. A data folder outside the run folder is followed only
with `allow_outside` (the CLI); the service never leaves the uploaded folder.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.camera_formats import camera_format_named
from bayesian_fields_core.scene.colmap import read_colmap, read_colmap_points
from bayesian_fields_core.scene.gsplat_normalise import gsplat_world_to_splat

GSPLAT_CFG = "cfg.yml"
NERFSTUDIO_CFG = "config.yml"
MAX_CONFIG_BYTES = 1 << 20


class _PlainLoader(yaml.SafeLoader):
    """SafeLoader that reads python object tags as plain data instead of refusing them."""


def _plain(loader: yaml.Loader, suffix: str, node: yaml.Node) -> Any:
    if isinstance(node, yaml.MappingNode):
        return loader.construct_mapping(node, deep=True)
    if isinstance(node, yaml.SequenceNode):
        return loader.construct_sequence(node, deep=True)
    assert isinstance(node, yaml.ScalarNode)  # the only other kind of YAML node
    return loader.construct_scalar(node)


_PlainLoader.add_multi_constructor("tag:yaml.org,2002:python/", _plain)
_PlainLoader.add_multi_constructor("!", _plain)


def read_run_config(path: Path) -> dict[str, Any]:
    """A trainer's YAML config as plain data (InputError naming the file when unreadable)."""
    try:
        if path.stat().st_size > MAX_CONFIG_BYTES:
            raise InputError("config is larger than 1 MiB", source=str(path))
        doc = yaml.load(path.read_text(encoding="utf-8"), Loader=_PlainLoader)  # noqa: S506 - safe subclass
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise InputError(f"cannot read the trainer config ({type(exc).__name__})", source=str(path)) from None
    if not isinstance(doc, dict):
        raise InputError("trainer config is not a mapping", source=str(path))
    return doc


def data_folder(run: Path, named: str, *, source: Path, allow_outside: bool) -> Path:
    """The data folder a config names: as given when absolute, else tried against the run folder
    and its ancestors (trainers record it relative to where they ran); must stay in `run` unless
    `allow_outside`."""
    given = Path(named)
    candidates = [given] if given.is_absolute() else [p / given for p in (run, *run.parents)]
    found = next((c.resolve() for c in candidates if c.is_dir()), None)
    if found is None:
        raise InputError(
            f"the data folder {named!r} it names is not found (looked beside the run and above it); "
            "copy the data into the run folder or write a scene.yaml",
            source=str(source),
        )
    if not allow_outside and not found.is_relative_to(run.resolve()):
        raise InputError(
            f"the data folder {named!r} lies outside the uploaded folder; include it in the upload",
            source=str(source),
        )
    return found


def _colmap_dir(data: Path, source: Path) -> Path:
    """The COLMAP model of a data folder, at the camera table's COLMAP locations in order."""
    colmap = camera_format_named("colmap")
    for rel in colmap.locations:
        if colmap.present(data / rel):
            return data / rel
    first, *rest = colmap.locations
    raise InputError(
        f"no {colmap.model_name} in {data.name}/{', '.join([first, *rest[:-1]])} or {rest[-1]}",
        source=str(source),
    )


def gsplat_run(run: Path, *, allow_outside: bool) -> dict[str, Any]:
    """(cameras, images folder, splat -> world similarity or None) of a gsplat result_dir."""
    cfg_path = run / GSPLAT_CFG
    cfg = read_run_config(cfg_path)
    named = cfg.get("data_dir")
    if not isinstance(named, str) or not named:
        raise InputError("cfg.yml has no data_dir", source=str(cfg_path))
    data = data_folder(run, named, source=cfg_path, allow_outside=allow_outside)
    factor = cfg.get("data_factor", 1)
    if isinstance(factor, bool) or not isinstance(factor, int) or factor < 1:
        raise InputError(f"data_factor must be a positive integer, got {factor!r}", source=str(cfg_path))
    images = data / ("images" if factor == 1 else f"images_{factor}")
    if not images.is_dir():
        raise InputError(
            f"{images.name}/ (data_factor {factor}) is missing in {data.name}", source=str(cfg_path)
        )
    sparse = _colmap_dir(data, cfg_path)
    splat_to_world = None
    if cfg.get("normalize_world_space", True) is not False:
        frames = read_colmap(sparse, images)
        poses = np.stack([f.camera_to_world for f in frames])
        splat_to_world = gsplat_world_to_splat(poses, read_colmap_points(sparse)).inverse()
    return {"sparse": sparse, "images": images, "splat_to_world": splat_to_world, "rescale": factor > 1}


def _section(cfg: dict[str, Any], name: str) -> dict[str, Any]:
    """`cfg[name]` when it is a mapping, else an empty one (configs of other versions omit it)."""
    value = cfg.get(name)
    return value if isinstance(value, dict) else {}


def _nerfstudio_data(cfg: dict[str, Any]) -> str | None:
    """The data path from a nerfstudio config: `data`, else pipeline.datamanager(.dataparser).data;
    a pathlib tag reads as the list of its parts."""
    pipeline = _section(cfg, "pipeline")
    manager = _section(pipeline, "datamanager")
    parser = _section(manager, "dataparser")
    for value in (cfg.get("data"), manager.get("data"), parser.get("data")):
        if isinstance(value, list) and value and all(isinstance(v, str) for v in value):
            return str(Path(*value))
        if isinstance(value, str) and value:
            return value
    return None


def nerfstudio_run(run: Path, *, allow_outside: bool) -> dict[str, Any]:
    """(data folder, camera kind and path) of a nerfstudio run folder (config.yml)."""
    cfg_path = run / NERFSTUDIO_CFG
    named = _nerfstudio_data(read_run_config(cfg_path))
    if named is None:
        raise InputError("config.yml names no data folder", source=str(cfg_path))
    data = data_folder(run, named, source=cfg_path, allow_outside=allow_outside)
    transforms = camera_format_named("transforms")
    for location in transforms.locations:
        if transforms.present(data / location):
            return {"data": data, "camera_kind": transforms.name, "camera_path": data / location}
    return {"data": data, "camera_kind": "colmap", "camera_path": _colmap_dir(data, cfg_path)}
