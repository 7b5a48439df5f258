"""The real architectures (random weights) through the project's perception code.

ViT-B/16 through transformers, open_clip and ONNX must give the same embeddings of the same
weights; FastSAM-x/-s must load from ultralytics checkpoints and give exclusive masks; each
reference profile must run the sample scene end to end through the CLI.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from PIL import Image

from bayesian_fields_core.perception.profiles import build_encoder, load_profile

from .conftest import MISSING

if MISSING:
    pytest.skip(
        "reference-model tests need the second venv (scripts/make_reference_venv.sh); missing "
        + ", ".join(MISSING),
        allow_module_level=True,
    )

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "samples" / "tabletop"
TEXTS = ["get the orange cone", "a red lamp", "move all the cyan things!", "x"]


def _frame(i: int = 0) -> np.ndarray:
    return np.asarray(Image.open(SAMPLE / "images" / f"frame_{i:05d}.png").convert("RGB"))


def _crops(n: int, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    img = _frame()
    out = []
    for _ in range(n):
        h, w = rng.integers(20, 120, 2)
        y, x = rng.integers(0, img.shape[0] - h), rng.integers(0, img.shape[1] - w)
        out.append(np.ascontiguousarray(img[y : y + h, x : x + w]))
    return out


def _profile(reference_dir: Path, name: str):
    return load_profile(reference_dir / "profiles" / f"{name}.yaml")


@pytest.fixture(scope="module")
def encoders(reference_dir: Path) -> dict:
    torch.set_num_threads(2)
    return {
        "hf": build_encoder(_profile(reference_dir, "reference-fastsam-hf-clip")),
        "open_clip": build_encoder(_profile(reference_dir, "reference-fastsam-open-clip")),
        "onnx": build_encoder(_profile(reference_dir, "reference-fastsam-onnx-clip")),
    }


def test_hf_folder_has_the_real_architecture(reference_dir: Path, encoders: dict) -> None:
    cfg = json.loads((reference_dir / "clip-vit-b16-hf" / "config.json").read_text())
    v, t = cfg["vision_config"], cfg["text_config"]
    assert (v["hidden_size"], v["num_hidden_layers"], v["patch_size"], v["image_size"]) == (768, 12, 16, 224)
    assert (t["hidden_size"], t["num_hidden_layers"], t["vocab_size"]) == (512, 12, 49408)
    n_params = sum(p.numel() for p in encoders["hf"].model.parameters())
    assert 149e6 < n_params < 151e6  # OpenAI ViT-B/16 has 149.6M parameters
    assert all(e.dim == 512 for e in encoders.values())


def test_tokenizers_agree_with_open_clip(encoders: dict) -> None:
    import open_clip

    hf_ids = encoders["hf"].tokenizer(TEXTS)["input_ids"]
    oc_ids = open_clip.get_tokenizer("ViT-B-16-quickgelu")(TEXTS).numpy()
    for row_hf, row_oc in zip(hf_ids, oc_ids, strict=True):
        end = int(np.argmax(row_oc == 49407)) + 1
        assert row_hf[:end].tolist() == row_oc[:end].tolist()  # same BPE ids, start to end token
    assert len(set(map(tuple, hf_ids.tolist()))) == len(TEXTS)


def test_towers_agree_on_identical_inputs(encoders: dict) -> None:
    """The three runtimes on the same pixel tensor: differences are float rounding only."""
    hf, oc, onnx = encoders["hf"], encoders["open_clip"], encoders["onnx"]
    pixels = hf.preprocess(_crops(6))
    with torch.inference_mode():
        a = hf.model.get_image_features(pixel_values=torch.from_numpy(pixels))
        a = getattr(a, "pooler_output", a) if not isinstance(a, torch.Tensor) else a
        b = oc.model.encode_image(torch.from_numpy(pixels))
    (c,) = onnx._image.run(None, {onnx._image_input: pixels})
    a, b, c = (np.asarray(x, dtype=np.float32) for x in (a, b, c))
    assert a.shape == b.shape == c.shape == (6, 512)
    np.testing.assert_allclose(b, a, atol=2e-4, rtol=1e-3)
    np.testing.assert_allclose(c, a, atol=2e-4, rtol=1e-3)


def test_encoders_give_the_same_embeddings(encoders: dict) -> None:
    crops = _crops(9)
    emb = {k: e.encode_images(crops) for k, e in encoders.items()}
    txt = {k: e.encode_texts(TEXTS) for k, e in encoders.items()}
    for k in emb:
        assert emb[k].shape == (9, 512) and emb[k].dtype == np.float32
        assert txt[k].shape == (len(TEXTS), 512) and txt[k].dtype == np.float32
        np.testing.assert_allclose(np.linalg.norm(emb[k], axis=1), 1.0, atol=1e-5)
    # HF and ONNX share the preprocessing: equal up to rounding.
    np.testing.assert_allclose(emb["onnx"], emb["hf"], atol=1e-4)
    np.testing.assert_allclose(txt["onnx"], txt["hf"], atol=1e-4)
    np.testing.assert_allclose(txt["open_clip"], txt["hf"], atol=1e-4)
    # open_clip resizes with its own (torchvision) transform: same direction, not the same bits.
    cos = (emb["open_clip"] * emb["hf"]).sum(axis=1)
    assert cos.min() > 0.99, cos
    # Different images give different embeddings (random weights still separate inputs).
    assert (emb["hf"] @ emb["hf"].T)[~np.eye(9, dtype=bool)].min() < 0.9


@pytest.mark.parametrize("kind", ["hf", "onnx"])
def test_batch_size_does_not_change_embeddings(kind: str, encoders: dict) -> None:
    enc = encoders[kind]
    crops = _crops(8, seed=1)
    whole = enc.encode_images(crops)
    parts = np.concatenate(
        [enc.encode_images(crops[:1]), enc.encode_images(crops[1:5]), enc.encode_images(crops[5:])]
    )
    np.testing.assert_allclose(parts, whole, atol=1e-4)
    assert enc.encode_images([]).shape == (0, 512)


def _fastsam(reference_dir: Path, profile: str, **overrides: object):
    from bayesian_fields_core.perception.fastsam import FastSAMSegmenter

    params = _profile(reference_dir, profile).segmenter.params.kwargs()
    # conf 0: random heads score near 0, so every candidate the head proposes is kept; they
    # overlap heavily, which is what exercises the exclusive assignment.
    params.update(conf=0.0, min_area=20, **overrides)
    return FastSAMSegmenter(**params)


@pytest.mark.parametrize(("profile", "scale", "n_params"), [
    ("reference-fastsam-hf-clip", "x", (68e6, 73e6)),  # FastSAM-x: YOLOv8x-seg, one class (68M)
    ("reference-fastsam-open-clip", "s", (11e6, 12.5e6)),  # FastSAM-s: YOLOv8s-seg (11.8M)
])  # fmt: skip
def test_fastsam_architecture_and_label_map(
    profile: str, scale: str, n_params: tuple, reference_dir: Path
) -> None:
    seg = _fastsam(reference_dir, profile)
    assert seg.weights.stem == f"FastSAM-{scale}"
    count = sum(p.numel() for p in seg.model.model.parameters())
    assert n_params[0] < count < n_params[1]
    image = _frame(2)
    labels = seg.segment(image)  # random FastSAM-x proposes no mask on this frame: ids may be all -1
    assert labels.shape == image.shape[:2] and labels.dtype == np.int32 and labels.min() >= -1


def test_fastsam_gives_exclusive_masks(reference_dir: Path) -> None:
    seg = _fastsam(reference_dir, "reference-fastsam-open-clip")  # FastSAM-s
    image = _frame(2)
    raw = seg.model(np.ascontiguousarray(image[..., ::-1]), device="cpu", retina_masks=True,
                    imgsz=seg.imgsz, conf=seg.conf, iou=seg.iou, verbose=False)[0].masks.data.numpy()  # fmt: skip
    assert raw.shape[0] > 10 and raw.shape[1:] == image.shape[:2]
    assert (raw.sum(axis=0) > 1).any()  # the model's own masks overlap...
    labels = seg.segment(image)
    m = int(labels.max()) + 1
    assert m >= 2  # ...the labels are one id per pixel: exclusive by construction
    areas = np.bincount(labels[labels >= 0].ravel(), minlength=m)
    assert (areas >= seg.min_area).all()  # ids 0..M-1 all present, none below min_area


def test_fastsam_half_uses_the_installed_ultralytics_keyword(
    reference_dir: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """fp16 (`half: true` in a profile) runs without ultralytics' deprecation warning for `half`
    (8.4 renamed it `quantize`); on the CPU ultralytics computes in fp32, so the labels equal fp32's."""
    from ultralytics.utils import LOGGER

    fp32 = _fastsam(reference_dir, "reference-fastsam-open-clip")
    fp16 = _fastsam(reference_dir, "reference-fastsam-open-clip", half=True)
    LOGGER.addHandler(caplog.handler)
    try:
        labels = fp16.segment(_frame(2))
    finally:
        LOGGER.removeHandler(caplog.handler)
    assert not [r for r in caplog.records if "deprecated" in r.getMessage()]
    np.testing.assert_array_equal(labels, fp32.segment(_frame(2)))


@pytest.mark.parametrize(
    "profile", ["reference-fastsam-hf-clip", "reference-fastsam-open-clip", "reference-fastsam-onnx-clip"]
)
def test_bfields_run_completes_with_each_reference_profile(
    profile: str, reference_dir: Path, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    cmd = [
        sys.executable, "-m", "bayesian_fields_core.cli.main", "run", str(SAMPLE),
        "--profile", str(reference_dir / "profiles" / f"{profile}.yaml"),
        "--out", str(out), "--cache-dir", str(tmp_path / "cache"),
        "--param", "max_frames=2", "--param", "crop_batch_size=16", "-q", "--json",
    ]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=900, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads(proc.stdout[proc.stdout.index("{") :])
    assert set(summary["run"]["stage_seconds"]) == {"perceive", "fuse", "cluster"}
    assert summary["counts"]["gaussians"] > 0
    tasks = yaml.safe_load((SAMPLE / "tasks.yaml").read_text())["tasks"]
    assert len(summary["tasks"]) == len(tasks)
