"""Fixtures for the in-process pipeline tests: one tiny rendered scene and one tiny random CLIP per
session, a model profile around them, and helpers that build a job on local stores (through
`job.factories.local_job`, as the CLI does).

The scene is a real synthetic tabletop (~7k Gaussians) rendered by the project's renderer from 5
orbit cameras at 128x96, so every stage runs on real images, real masks and real CLIP features.
The CLIP is random-initialised, so its cosine scores sit near 0: the profile's calibration
(mu0=-0.05, mu1=0.05, s=0.1) centres the likelihoods there, which makes some masks accepted and
some rejected, as with a real model and its own calibration.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any, Unpack

import numpy as np
import pytest
from PIL import Image

from bayesian_fields_core.job.factories import Job, LocalJobOptions, local_job
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.perception.models import Models, load_models

TASKS = ["red chair", "blue cup", "green plant"]
OTHER_TASKS = ["the mug", "a table", "photo of a red cup"]
N_FRAMES = 5
SEGMENTER_PARAMS = {"method": "felzenszwalb", "scale": 100, "sigma": 0.5, "min_size": 20, "min_area": 16}


@pytest.fixture(scope="session")
def pipeline_clip_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tests.core.perception.conftest import make_tiny_clip

    return make_tiny_clip(tmp_path_factory.mktemp("pipeline-models") / "tiny-clip")


@pytest.fixture(scope="session")
def profile(pipeline_clip_dir: Path) -> dict[str, Any]:
    return {
        "name": "pipeline-test",
        "segmenter": {"kind": "classical", "params": dict(SEGMENTER_PARAMS)},
        "encoder": {"kind": "hf_clip", "path": str(pipeline_clip_dir)},
        "calibration": {"mu0": -0.05, "mu1": 0.05, "s": 0.1},
    }


@pytest.fixture(scope="session")
def profile_yaml(profile: dict[str, Any], tmp_path_factory: pytest.TempPathFactory) -> Path:
    import yaml

    path = tmp_path_factory.mktemp("pipeline-profile") / "profile.yaml"
    path.write_text(yaml.safe_dump(profile), encoding="utf-8")
    return path


@pytest.fixture(scope="session")
def scene_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A scene folder as a user would hand it over: point_cloud.ply, transforms.json, images/."""
    from bayesian_fields_core.eval.synthetic.builder import build_scene
    from bayesian_fields_core.eval.synthetic.cameras import orbit_frames
    from bayesian_fields_core.eval.synthetic.spec import SceneSpec
    from bayesian_fields_core.render import GaussianRenderer
    from bayesian_fields_core.scene.nerfstudio import write_transforms
    from bayesian_fields_core.scene.ply import write_ply

    out = tmp_path_factory.mktemp("pipeline-scene")
    (out / "images").mkdir()
    spec = SceneSpec(
        seed=3,
        n_frames=N_FRAMES,
        n_objects=4,
        n_duplicates=0,
        n_groups=2,
        object_density=5000,
        table_density=800,
        room_density=60,
        width=128,
        height=96,
    )
    scene = build_scene(spec)
    frames = orbit_frames(spec, scene.table_top_center, np.random.default_rng(0))
    renderer = GaussianRenderer(scene.gaussians)
    for frame in frames:
        rgb = renderer.render(frame.K, frame.world_to_camera, frame.width, frame.height).rgb
        path = out / "images" / f"{frame.name}.png"
        Image.fromarray((np.clip(rgb, 0.0, 1.0) * 255).astype(np.uint8)).save(path)
        frame.image_path = path
    write_ply(out / "point_cloud.ply", scene.gaussians)
    write_transforms(out / "transforms.json", frames)
    return out


class CountingEncoder:
    """Delegates to the real encoder and counts calls (a proxy, not a stand-in)."""

    def __init__(self, inner: Any, counts: Counter) -> None:
        self._inner = inner
        self._counts = counts
        self.model_id = inner.model_id
        self.dim = inner.dim

    def encode_images(self, images: list[np.ndarray]) -> np.ndarray:
        self._counts["encode_images"] += 1
        return self._inner.encode_images(images)

    def encode_texts(self, texts: list[str]) -> np.ndarray:
        self._counts["encode_texts"] += 1
        return self._inner.encode_texts(texts)


class CountingSegmenter:
    """Delegates to the real segmenter and counts `segment` calls."""

    def __init__(self, inner: Any, counts: Counter) -> None:
        self._inner = inner
        self._counts = counts
        self.name = inner.name
        self.params = inner.params

    def segment(self, image: np.ndarray) -> np.ndarray:
        self._counts["segment"] += 1
        return self._inner.segment(image)


class CountingModels(Models):
    """The profile's real models behind counting proxies; also records which ones were built."""

    def __init__(self, profile: Any) -> None:
        super().__init__(profile)
        self.counts: Counter = Counter()
        self._counting_encoder: CountingEncoder | None = None
        self._counting_segmenter: CountingSegmenter | None = None

    @property
    def encoder(self) -> Any:
        if self._counting_encoder is None:
            self.counts["encoder_built"] += 1
            self._counting_encoder = CountingEncoder(super().encoder, self.counts)
        return self._counting_encoder

    @property
    def segmenter(self) -> Any:
        if self._counting_segmenter is None:
            self.counts["segmenter_built"] += 1
            self._counting_segmenter = CountingSegmenter(super().segmenter, self.counts)
        return self._counting_segmenter


def counting_models(profile: dict[str, Any]) -> CountingModels:
    return CountingModels(load_models(profile).profile)


def make_job(
    scene_dir: Path,
    job_root: Path,
    cache_root: Path,
    models: Models,
    *,
    tasks: list[str] | None = None,
    params: PipelineParams | None = None,
    **options: Unpack[LocalJobOptions],
) -> Job:
    """A job on local folders: `job_root` holds the job's artifacts (below ``job/``), `cache_root`
    the scene caches (below ``scenes/tiny/cache/``)."""
    options.setdefault("job_prefix", "job/")
    options.setdefault("cache_prefix", "scenes/tiny/cache/")
    return local_job(
        scene_dir, job_root, cache_root, list(tasks or TASKS), params or PipelineParams(), models, **options
    )


@pytest.fixture(scope="session", autouse=True)
def single_torch_thread() -> Any:
    """Run torch single-threaded for these tests.

    The CPU renderer issues hundreds of small torch ops per frame; with OpenMP threads on a busy
    shared 2-core machine each op waits on spinning threads and a 128x96 frame took ~2 s instead
    of ~0.2 s. One thread keeps the suite fast and its timings stable.
    """
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
