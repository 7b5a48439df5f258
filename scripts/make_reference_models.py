"""Write the reference-architecture models (random weights, real configurations) and profiles.

No weights can be downloaded, so every perception path would otherwise meet only the tiny test
CLIP. These are the architectures users bring, built here with random weights, so loading,
shapes, preprocessing, batching, memory and speed are checked on the very code path a user's
official weights take:

  clip-vit-b16-hf/           OpenAI CLIP ViT-B/16 (its published config: 12+12 layers, 768/512
                             widths, patch 16, 224 px, quick-GELU, 512-d projection) as a
                             Hugging Face folder: config.json, model.safetensors, a real BPE
                             vocabulary (vocab.json + merges.txt built from open_clip's packaged
                             bpe_simple_vocab_16e6.txt.gz, tokenizer.json), preprocessor_config.json
  clip-vit-b16-open_clip.safetensors   the SAME weights as an open_clip "ViT-B-16-quickgelu"
                             state dict (the open_clip name of OpenAI's ViT-B/16), loaded strict
  clip-vit-b16-onnx/         image and text towers of the same weights exported to ONNX
  FastSAM-x.pt, FastSAM-s.pt FastSAM's architectures (YOLOv8x-seg / YOLOv8s-seg with one class),
                             built by ultralytics from its model YAML, saved as ultralytics saves
  profiles/reference-*.yaml  one profile per encoder, in the form of models/profiles/*.yaml

Run it in the second venv (scripts/make_reference_venv.sh): ultralytics and open_clip need
torchvision. Usage: python scripts/make_reference_models.py --out DIR [--seed 0]
[--fastsam x,s] [--device cpu]. HOME-writing tools are pointed into DIR/.home.
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import sys
import time
from pathlib import Path

OPENAI_MEAN = [0.48145466, 0.4578275, 0.40821073]
OPENAI_STD = [0.26862954, 0.26130258, 0.27577711]
HF_DIR, OPEN_CLIP_FILE, ONNX_DIR = (
    "clip-vit-b16-hf",
    "clip-vit-b16-open_clip.safetensors",
    "clip-vit-b16-onnx",
)
OPEN_CLIP_NAME = "ViT-B-16-quickgelu"
START, END = "<|startoftext|>", "<|endoftext|>"


def clip_config():
    """OpenAI CLIP ViT-B/16's published configuration as a transformers `CLIPConfig`."""
    from transformers import CLIPConfig

    text = dict(
        vocab_size=49408,
        hidden_size=512,
        intermediate_size=2048,
        num_hidden_layers=12,
        num_attention_heads=8,
        max_position_embeddings=77,
        hidden_act="quick_gelu",
        bos_token_id=49406,
        eos_token_id=49407,
        pad_token_id=49407,
        projection_dim=512,
    )
    vision = dict(
        hidden_size=768,
        intermediate_size=3072,
        num_hidden_layers=12,
        num_attention_heads=12,
        image_size=224,
        patch_size=16,
        hidden_act="quick_gelu",
        projection_dim=512,
    )
    return CLIPConfig(
        text_config=text, vision_config=vision, projection_dim=512, logit_scale_init_value=2.6592
    )


def bpe_vocabulary() -> tuple[dict[str, int], list[str]]:
    """CLIP's byte-level BPE vocabulary (49408 tokens) and merges from open_clip's packaged file.

    Layout (CLIP's): the 256 byte symbols (printable bytes first, in byte order, then the others
    in byte order), the same with the end-of-word marker, one token per
    merge (the first 48894 merges of the file), then the start and end tokens.
    """
    import open_clip

    path = Path(open_clip.__file__).parent / "bpe_simple_vocab_16e6.txt.gz"
    lines = gzip.open(path, "rt", encoding="utf-8").read().split("\n")
    merges = lines[1 : 49152 - 256 - 2 + 1]
    # GPT-2's reversible byte -> unicode map: printable bytes map to themselves, the rest above 255.
    printable = list(range(ord("!"), ord("~") + 1)) + list(range(ord("¡"), ord("¬") + 1))
    printable += list(range(ord("®"), ord("ÿ") + 1))
    codes, extra = list(printable), 0
    for b in range(256):
        if b not in printable:
            printable.append(b)
            codes.append(256 + extra)
            extra += 1
    symbols = [chr(c) for c in codes]  # CLIP's order: printable bytes first, then the rest
    tokens = symbols + [s + "</w>" for s in symbols] + ["".join(m.split()) for m in merges] + [START, END]
    if len(tokens) != 49408:
        raise SystemExit(f"{path}: expected 49408 tokens, built {len(tokens)}")
    return {t: i for i, t in enumerate(tokens)}, merges


def write_hf_clip(out: Path, seed: int) -> Path:
    """The random-weight CLIPModel folder with tokenizer and image preprocessor."""
    import torch
    from transformers import CLIPImageProcessor, CLIPModel, CLIPTokenizer, CLIPTokenizerFast

    folder = out / HF_DIR
    folder.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(seed)
    model = CLIPModel(clip_config()).eval()
    model.save_pretrained(folder, safe_serialization=True)
    vocab, merges = bpe_vocabulary()
    (folder / "vocab.json").write_text(json.dumps(vocab, ensure_ascii=False), encoding="utf-8")
    (folder / "merges.txt").write_text("#version: 0.2\n" + "\n".join(merges) + "\n", encoding="utf-8")
    special = dict(bos_token=START, eos_token=END, unk_token=END, pad_token=END, model_max_length=77)
    slow = CLIPTokenizer(str(folder / "vocab.json"), str(folder / "merges.txt"), **special)
    slow.save_pretrained(folder)
    CLIPTokenizerFast.from_pretrained(str(folder), **special).save_pretrained(folder)
    CLIPImageProcessor(
        do_resize=True,
        size={"shortest_edge": 224},
        resample=3,
        do_center_crop=True,
        crop_size={"height": 224, "width": 224},
        do_normalize=True,
        image_mean=OPENAI_MEAN,
        image_std=OPENAI_STD,
        do_convert_rgb=True,
    ).save_pretrained(folder)
    return folder


def hf_to_open_clip(sd: dict) -> dict:
    """Rename a transformers CLIPModel state dict to open_clip's OpenAI-style layout.

    open_clip keeps q/k/v as one `in_proj` matrix, stores the two projections transposed and
    names the MLP `c_fc`/`c_proj`; everything else is a rename.
    """
    import torch

    out: dict[str, torch.Tensor] = {}

    def blocks(src: str, dst: str, layers: int) -> None:
        for i in range(layers):
            s, d = f"{src}.encoder.layers.{i}", f"{dst}.resblocks.{i}"
            for part in ("weight", "bias"):
                out[f"{d}.attn.in_proj_{part}"] = torch.cat(
                    [sd[f"{s}.self_attn.{p}_proj.{part}"] for p in ("q", "k", "v")], dim=0
                )
                out[f"{d}.attn.out_proj.{part}"] = sd[f"{s}.self_attn.out_proj.{part}"]
                out[f"{d}.ln_1.{part}"] = sd[f"{s}.layer_norm1.{part}"]
                out[f"{d}.ln_2.{part}"] = sd[f"{s}.layer_norm2.{part}"]
                out[f"{d}.mlp.c_fc.{part}"] = sd[f"{s}.mlp.fc1.{part}"]
                out[f"{d}.mlp.c_proj.{part}"] = sd[f"{s}.mlp.fc2.{part}"]

    blocks("vision_model", "visual.transformer", 12)
    blocks("text_model", "transformer", 12)
    v = "vision_model"
    out["visual.conv1.weight"] = sd[f"{v}.embeddings.patch_embedding.weight"]
    out["visual.class_embedding"] = sd[f"{v}.embeddings.class_embedding"]
    out["visual.positional_embedding"] = sd[f"{v}.embeddings.position_embedding.weight"]
    for part in ("weight", "bias"):
        out[f"visual.ln_pre.{part}"] = sd[f"{v}.pre_layrnorm.{part}"]
        out[f"visual.ln_post.{part}"] = sd[f"{v}.post_layernorm.{part}"]
        out[f"ln_final.{part}"] = sd[f"text_model.final_layer_norm.{part}"]
    out["visual.proj"] = sd["visual_projection.weight"].T.contiguous()
    out["token_embedding.weight"] = sd["text_model.embeddings.token_embedding.weight"]
    out["positional_embedding"] = sd["text_model.embeddings.position_embedding.weight"]
    out["text_projection"] = sd["text_projection.weight"].T.contiguous()
    out["logit_scale"] = sd["logit_scale"]
    return {k: t.contiguous() for k, t in out.items()}


def write_open_clip(out: Path, hf_folder: Path) -> Path:
    """The HF weights as an open_clip checkpoint (safetensors), verified by a strict load."""
    import open_clip
    from safetensors.torch import save_file
    from transformers import CLIPModel

    sd = hf_to_open_clip(CLIPModel.from_pretrained(str(hf_folder), local_files_only=True).state_dict())
    model = open_clip.create_model(OPEN_CLIP_NAME, pretrained=None)
    try:
        model.load_state_dict(sd, strict=True)  # every tensor named and shaped as open_clip's
    except RuntimeError as exc:
        raise SystemExit(f"open_clip layout mismatch: {exc}") from exc
    path = out / OPEN_CLIP_FILE
    save_file(sd, str(path))
    return path


def write_fastsam(out: Path, scale: str, seed: int) -> Path:
    """FastSAM-{scale}: ultralytics' YOLOv8{scale}-seg built from its YAML with FastSAM's one class."""
    import torch
    import yaml
    from ultralytics import YOLO
    from ultralytics.nn.tasks import yaml_model_load

    cfg = yaml_model_load(f"yolov8{scale}-seg.yaml")
    cfg["nc"] = 1
    # ultralytics reads the scale (n/s/m/l/x) from the file name, so the YAML keeps that name.
    tmp = out / ".build" / scale
    tmp.mkdir(parents=True, exist_ok=True)
    cfg_path = tmp / f"yolov8{scale}-seg.yaml"
    cfg_path.write_text(yaml.safe_dump(cfg), encoding="utf-8")
    torch.manual_seed(seed)
    model = YOLO(str(cfg_path), task="segment")
    model.model.names = {0: "object"}
    path = out / f"FastSAM-{scale}.pt"
    model.save(str(path))
    return path


def profile_text(name: str, comment: str, segmenter: dict, encoder: dict) -> str:
    """A profile YAML in the form of models/profiles/fastsam-clip-vitb16.yaml (paths relative)."""
    import yaml

    body = {
        "name": name,
        "segmenter": segmenter,
        "encoder": encoder,
        # Random weights have no meaningful calibration: the paper's values, inline.
        "calibration": {"mu0": 0.20, "mu1": 0.27, "s": 0.035},
    }
    head = "".join(f"# {line}\n" for line in comment.splitlines())
    return head + yaml.safe_dump(body, sort_keys=False)


def write_profiles(out: Path, scales: list[str], device: str, *, minimal: bool = False) -> list[Path]:
    """One profile per encoder (HF, open_clip, ONNX), each with a reference FastSAM."""
    folder = out / "profiles"
    folder.mkdir(parents=True, exist_ok=True)

    def fastsam(scale: str) -> dict:
        # conf: random heads score near 0, so a low threshold keeps masks flowing (official
        # weights use 0.4); imgsz 640 keeps CPU runs short (the paper's FastSAM-x uses 1024).
        return {
            "kind": "fastsam",
            "params": {
                "weights": f"../FastSAM-{scale}.pt",
                "conf": 0.01,
                "iou": 0.9,
                "imgsz": 640,
                "retina_masks": True,
                "device": device,
                "min_area": 100,
            },
        }

    big, small = scales[0], scales[-1]
    specs = [
        (
            "reference-fastsam-hf-clip",
            f"FastSAM-{big} + CLIP ViT-B/16 (transformers), random weights of the real architectures.",
            fastsam(big),
            {
                "kind": "hf_clip",
                "path": f"../{HF_DIR}",
                "device": device,
                "params": {"resize_mode": "shortest_crop"},
            },
        ),
        (
            "reference-fastsam-open-clip",
            f"FastSAM-{small} + the same CLIP ViT-B/16 weights through open_clip.",
            fastsam(small),
            {
                "kind": "open_clip",
                "path": f"../{OPEN_CLIP_FILE}",
                "device": device,
                "params": {"model_name": OPEN_CLIP_NAME},
            },
        ),
        (
            "reference-fastsam-onnx-clip",
            f"FastSAM-{small} + the same CLIP ViT-B/16 weights as ONNX towers (onnxruntime).",
            fastsam(small),
            {"kind": "onnx", "path": f"../{ONNX_DIR}", "params": {"resize_mode": "shortest_crop"}},
        ),
    ]
    paths = []
    for name, comment, seg, enc in specs[:1] if minimal else specs:
        path = folder / f"{name}.yaml"
        path.write_text(profile_text(name, comment, seg, enc), encoding="utf-8")
        paths.append(path)
    return paths


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--fastsam", default="x,s", help="FastSAM scales, biggest first (x,s)")
    parser.add_argument("--device", default="cpu", help="device written into the profiles")
    parser.add_argument(
        "--minimal",
        action="store_true",
        help="only the HF CLIP, FastSAM and their profile (bench/gpu_check.sh)",
    )
    args = parser.parse_args(argv)
    out: Path = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    for var, sub in (
        ("HOME", "home"),
        ("YOLO_CONFIG_DIR", "yolo"),
        ("HF_HOME", "hf"),
        ("XDG_CACHE_HOME", "cache"),
    ):
        os.environ[var] = str(out / ".home" / sub)
    os.environ["HF_HUB_OFFLINE"] = "1"
    scales = [s.strip() for s in args.fastsam.split(",") if s.strip()]
    if not scales or any(s not in "nslmx" or len(s) != 1 for s in scales):
        parser.error(f"--fastsam: scales from n, s, m, l, x; got {args.fastsam!r}")
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from bayesian_fields_core.perception.onnx_export import export_clip_onnx

    steps: list[tuple[str, float]] = []

    def step(name: str, fn, *a):
        t = time.perf_counter()
        result = fn(*a)
        steps.append((name, time.perf_counter() - t))
        print(f"  {name:<22} {steps[-1][1]:6.1f} s  {result}", flush=True)
        return result

    print(f"reference models -> {out}")
    hf = step("hf clip ViT-B/16", write_hf_clip, out, args.seed)
    if not args.minimal:
        step("open_clip checkpoint", write_open_clip, out, hf)
        step("onnx towers", export_clip_onnx, hf, out / ONNX_DIR)
    for scale in scales:
        step(f"FastSAM-{scale}", write_fastsam, out, scale, args.seed)
    for path in write_profiles(out, scales, args.device, minimal=args.minimal):
        print(f"  profile {path}")
    print(f"done in {sum(s for _, s in steps):.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
