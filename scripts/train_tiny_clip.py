"""Train the project's tiny CLIP (``bayesian_fields_core/models/tiny-clip/``) on masked crops of the synthetic vocabulary.

Why: tests, the demo and CI need a real image/text encoder that knows the synthetic scenes' objects
and is small enough to commit (< 1 MB) and run on a CPU. This script renders the vocabulary's
objects (alone, and inside whole scenes with occlusions) and background segments, crops them with
the pipeline's own ``mask_crops``, and trains a transformers ``CLIPModel`` with a multi-positive
contrastive loss: a caption such as "move all the red things" is right for every red object, so
every (image, caption) pair whose meaning matches is a positive, not only the sampled pair.
Some cubes, cylinders and mugs carry a coloured label on one side (the capture suite's
view-dependent identity, paper Fig. 3a): "get the red cube with the blue label" is right for a
crop that shows the blue label and wrong for the same cube seen from behind, so each batch also
holds label captions naming the wrong label or an unseen one, as hard negatives. Some objects
and scenes are striped / checkered as the capture suite's are, so texture is not mistaken for
identity.
It then fits ``calibration.json`` (mu0 from unrelated tasks, mu1 and s from right tasks) on
held-out crops from other seeds, and writes a word-level tokenizer and ``preprocessor_config.json``
so ``perception.hf_clip.HFClipEncoder`` loads the folder with ``local_files_only``.

Usage: ``.venv/bin/python scripts/train_tiny_clip.py [--out bayesian_fields_core/models/tiny-clip] [--steps 3600]``.
Deterministic for a given seed; about 9 minutes on 2 CPU cores (half rendering the crops, half training).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from tokenizers import Tokenizer, models, normalizers, pre_tokenizers, processors
from transformers import CLIPConfig, CLIPModel, PreTrainedTokenizerFast

from bayesian_fields_core.calibration.model import fit_calibration, save_calibration
from bayesian_fields_core.eval.clip_quality import label_reading
from bayesian_fields_core.eval.synthetic.crops import LabelledCrop, object_crops, scene_crops
from bayesian_fields_core.eval.vocabulary import (
    BACKGROUND_KINDS,
    COLOURS,
    KINDS,
    LABELLED_KINDS,
    Caption,
    all_words,
    captions_for,
    label_colours,
)
from bayesian_fields_core.perception.clip_inputs import CLIP_MEAN, CLIP_STD, ClipImagePreprocessor
from bayesian_fields_core.perception.hf_clip import hf_clip_model_id

SPECIALS = ["[PAD]", "[UNK]", "<start>", "<end>"]  # <end> must not be id 2 (HF CLIP's legacy pooling)
IMAGE_SIZE = 48
CONTEXT = 16


def build_tokenizer() -> PreTrainedTokenizerFast:
    """Word-level tokenizer over the vocabulary's words; adds <start> ... <end> around every text."""
    vocab = {w: i for i, w in enumerate(SPECIALS + all_words())}
    tok = Tokenizer(models.WordLevel(vocab=vocab, unk_token="[UNK]"))
    tok.normalizer = normalizers.Lowercase()
    tok.pre_tokenizer = pre_tokenizers.Sequence([pre_tokenizers.Whitespace(), pre_tokenizers.Punctuation()])
    tok.post_processor = processors.TemplateProcessing(
        single="<start> $A <end>", special_tokens=[("<start>", vocab["<start>"]), ("<end>", vocab["<end>"])]
    )
    return PreTrainedTokenizerFast(
        tokenizer_object=tok,
        unk_token="[UNK]",
        pad_token="[PAD]",
        bos_token="<start>",
        eos_token="<end>",
        model_max_length=CONTEXT,
    )


def build_model(tokenizer: PreTrainedTokenizerFast, seed: int) -> CLIPModel:
    """About 0.2M parameters: 64-wide towers, 48 px images in 8 px patches."""
    torch.manual_seed(seed)
    config = CLIPConfig(
        text_config={
            "vocab_size": len(tokenizer),
            "hidden_size": 64,
            "intermediate_size": 128,
            "num_hidden_layers": 2,
            "num_attention_heads": 4,
            "max_position_embeddings": CONTEXT,
            "pad_token_id": tokenizer.pad_token_id,
            "bos_token_id": tokenizer.bos_token_id,
            "eos_token_id": tokenizer.eos_token_id,
        },
        vision_config={
            "image_size": IMAGE_SIZE,
            "patch_size": 8,
            "hidden_size": 64,
            "intermediate_size": 128,
            "num_hidden_layers": 3,
            "num_attention_heads": 4,
        },
        projection_dim=64,
    )
    return CLIPModel(config)


def preprocessor() -> ClipImagePreprocessor:
    return ClipImagePreprocessor(IMAGE_SIZE, (IMAGE_SIZE, IMAGE_SIZE), CLIP_MEAN, CLIP_STD)


def preprocessor_config() -> dict:
    return {
        "image_processor_type": "CLIPImageProcessor",
        "do_resize": True,
        "size": {"shortest_edge": IMAGE_SIZE},
        "do_center_crop": True,
        "crop_size": {"height": IMAGE_SIZE, "width": IMAGE_SIZE},
        "do_rescale": True,
        "rescale_factor": 1 / 255,
        "do_normalize": True,
        "image_mean": list(CLIP_MEAN),
        "image_std": list(CLIP_STD),
        "resample": 3,
        "do_convert_rgb": True,
    }


Class = tuple[str | None, str, str | None]  # (colour, kind, colour of the label in sight)


def make_crops(seed: int, n_objects: int, n_scenes: int, args: argparse.Namespace) -> list[LabelledCrop]:
    rng = np.random.default_rng(seed)
    objects = object_crops(
        rng, n_objects, views_per_object=4, label_share=args.label_share, stripe_share=args.stripe_share
    )
    return objects + scene_crops(rng, n_scenes, args.views, textured_share=args.textured_scenes)


def caption_table() -> tuple[list[Caption], np.ndarray, list[Class]]:
    """All captions, the (classes, captions) match matrix, and the classes."""
    classes: list[Class] = [(c, k, None) for k in KINDS for c in COLOURS]
    classes += [(None, b, None) for b in BACKGROUND_KINDS]
    classes += [(c, k, lab) for k in LABELLED_KINDS for c in COLOURS for lab in label_colours(c)]
    captions = list({cap.text: cap for cls in classes for cap in captions_for(*cls)}.values())
    match = np.array([[cap.matches(c, k, lab) for cap in captions] for c, k, lab in classes])
    return captions, match, classes


def label_caption_index(captions: list[Caption]) -> dict[tuple[str, str, str], list[int]]:
    """(colour, kind, label) -> the indices of the captions that name that label."""
    out: dict[tuple[str, str, str], list[int]] = {}
    for i, cap in enumerate(captions):
        if cap.label is not None:
            assert cap.colour is not None and cap.kind is not None
            out.setdefault((cap.colour, cap.kind, cap.label), []).append(i)
    return out


def encode(
    model: CLIPModel, pixels: torch.Tensor | None, ids: torch.Tensor | None, mask: torch.Tensor | None
):
    """Unit image and/or text embeddings through the projection heads (what get_*_features do)."""
    img = txt = None
    if pixels is not None:
        img = model.visual_projection(model.vision_model(pixel_values=pixels).pooler_output)
        img = img / img.norm(dim=-1, keepdim=True)
    if ids is not None:
        txt = model.text_projection(model.text_model(input_ids=ids, attention_mask=mask).pooler_output)
        txt = txt / txt.norm(dim=-1, keepdim=True)
    return img, txt


def multi_positive_loss(logits: torch.Tensor, positive: torch.Tensor) -> torch.Tensor:
    """Symmetric InfoNCE where every matching pair counts: -log of the softmax mass on positives."""
    neg_inf = torch.finfo(logits.dtype).min

    def one_side(lg: torch.Tensor, pos: torch.Tensor) -> torch.Tensor:
        # Rows without a positive (a hard-negative caption no crop of the batch matches) only
        # count on the other side, as negatives.
        has = pos.any(dim=1)
        lg, pos = lg[has], pos[has]
        return -(torch.logsumexp(lg.masked_fill(~pos, neg_inf), dim=1) - torch.logsumexp(lg, dim=1)).mean()

    return 0.5 * (one_side(logits, positive) + one_side(logits.T, positive.T))


def augment(x: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
    """Horizontal flips and mild brightness changes (colour itself is a label, so no hue jitter)."""
    flip = torch.rand(x.shape[0], generator=gen) < 0.5
    x = torch.where(flip[:, None, None, None], x.flip(-1), x)
    b = 1.0 + 0.2 * (torch.rand(x.shape[0], 1, 1, 1, generator=gen) - 0.5)
    mean = torch.tensor(CLIP_MEAN).view(1, 3, 1, 1)
    std = torch.tensor(CLIP_STD).view(1, 3, 1, 1)
    return b * x + (b - 1.0) * mean / std


def sample_caption(
    cls: int, cap_choices: list[torch.Tensor], label_choices: list[torch.Tensor], gen: torch.Generator
) -> torch.Tensor:
    """One matching caption for a crop of class `cls`; one naming its label half of the time."""
    pool = cap_choices[cls]
    if len(label_choices[cls]) and torch.rand(1, generator=gen).item() < 0.5:
        pool = label_choices[cls]
    return pool[torch.randint(len(pool), (1,), generator=gen)][0]


def hard_negatives(
    batch: list[int],
    classes: list[Class],
    label_caps: dict[tuple[str, str, str], list[int]],
    gen: torch.Generator,
) -> torch.Tensor:
    """For each crop of a labellable kind, one caption naming a label it does not show: another
    colour when it shows one, any colour when it shows none (its look-alike's task)."""
    out = []
    for cls in batch:
        colour, kind, label = classes[cls]
        if colour is None or kind not in LABELLED_KINDS:
            continue
        wrong = [lab for lab in label_colours(colour) if lab != label]
        pick = wrong[int(torch.randint(len(wrong), (1,), generator=gen))]
        caps = label_caps[(colour, kind, pick)]
        out.append(caps[int(torch.randint(len(caps), (1,), generator=gen))])
    return torch.tensor(out, dtype=torch.long)


def train(args: argparse.Namespace) -> None:
    torch.set_num_threads(args.threads)
    t0 = time.perf_counter()
    tokenizer = build_tokenizer()
    model = build_model(tokenizer, args.seed)
    print(f"model: {sum(p.numel() for p in model.parameters()):,} parameters")

    captions, match, classes = caption_table()
    class_index = {cls: i for i, cls in enumerate(classes)}
    crops = make_crops(args.seed, args.objects, args.scenes, args)
    held = make_crops(args.seed + 1000, args.objects // 6, max(args.scenes // 4, 1), args)
    print(
        f"data: {len(crops)} training crops, {len(held)} held-out crops in {time.perf_counter() - t0:.0f} s"
    )

    prep = preprocessor()
    pixels = torch.from_numpy(prep([c.image for c in crops]))
    labels = torch.tensor([class_index[(c.colour, c.kind, c.label)] for c in crops])
    enc = tokenizer([c.text for c in captions], padding=True, return_tensors="pt")
    cap_ids, cap_mask = enc["input_ids"], enc["attention_mask"]
    match_t = torch.from_numpy(match)
    # Per class, the captions it may be paired with (sampled uniformly per step); a crop that shows
    # a label is paired with a caption naming it half of the time (they are a few of its many).
    label_caps = label_caption_index(captions)
    cap_choices = [torch.from_numpy(np.flatnonzero(row)) for row in match]
    label_choices = [torch.tensor(label_caps.get(cls, []), dtype=torch.long) for cls in classes]  # type: ignore[arg-type]

    gen = torch.Generator().manual_seed(args.seed)
    opt = torch.optim.AdamW(model.parameters(), lr=args.lr, weight_decay=0.05)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=args.lr, total_steps=args.steps, pct_start=0.1)
    model.train()
    for step in range(args.steps):
        idx = torch.randint(len(crops), (args.batch,), generator=gen)
        y = labels[idx]
        pick = torch.stack([sample_caption(c, cap_choices, label_choices, gen) for c in y.tolist()])
        pick = torch.cat([pick, hard_negatives(y.tolist(), classes, label_caps, gen)])
        img, txt = encode(model, augment(pixels[idx], gen), cap_ids[pick], cap_mask[pick])
        logits = model.logit_scale.exp().clamp(max=100.0) * img @ txt.T
        loss = multi_positive_loss(logits, match_t[y][:, pick])
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if step % 200 == 0 or step == args.steps - 1:
            print(f"step {step:5d} loss {loss.item():.3f} ({time.perf_counter() - t0:.0f} s)")
    model.eval()
    save(model, tokenizer, Path(args.out), held, captions, match, class_index)
    print(f"done in {time.perf_counter() - t0:.0f} s")


def save(
    model: CLIPModel,
    tokenizer: PreTrainedTokenizerFast,
    out: Path,
    held: list[LabelledCrop],
    captions: list[Caption],
    match: np.ndarray,
    class_index: dict,
) -> None:
    """Write the model folder, then measure and calibrate it on the held-out crops."""
    out.mkdir(parents=True, exist_ok=True)
    model.save_pretrained(str(out))
    tokenizer.save_pretrained(str(out))
    (out / "preprocessor_config.json").write_text(json.dumps(preprocessor_config(), indent=2) + "\n")

    from bayesian_fields_core.perception.hf_clip import HFClipEncoder

    encoder = HFClipEncoder(out)  # measure through the production loader, as the pipeline will
    img = encoder.encode_images([c.image for c in held])
    txt = encoder.encode_texts([c.text for c in captions])
    scores = img @ txt.T
    y = np.array([class_index[(c.colour, c.kind, c.label)] for c in held])
    canon = [
        i
        for i, c in enumerate(captions)
        if c.colour is not None and c.kind is not None and c.text.count(" ") == 1
    ]
    canon += [i for i, c in enumerate(captions) if c.colour is None and c.text in BACKGROUND_KINDS]
    canon_match = match[:, canon]
    top1 = float(np.mean(canon_match[y, np.argmax(scores[:, canon], axis=1)]))
    # Task-like phrasings: positives are right tasks, negatives unrelated tasks (no shared colour or kind).
    tasks = [
        i for i, c in enumerate(captions) if c.text.split()[0] in ("get", "pick", "move", "grab", "find")
    ]
    pos = scores[:, tasks][match[y][:, tasks]]
    related = np.array(
        [[captions[j].colour == c.colour or captions[j].kind == c.kind for j in tasks] for c in held]
    )
    neg = scores[:, tasks][~match[y][:, tasks] & ~related]
    cal = fit_calibration(pos, neg, hf_clip_model_id(out))
    save_calibration(out / "calibration.json", cal)
    report = {
        "held_out_crops": len(held),
        "top1_canonical": round(top1, 4),
        **label_reading(encoder, held).as_dict(),
        "mu0": cal.mu0,
        "mu1": cal.mu1,
        "s": cal.s,
    }
    print(json.dumps(report))


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", default="bayesian_fields_core/models/tiny-clip")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--steps", type=int, default=3600)
    p.add_argument("--batch", type=int, default=128)
    p.add_argument("--lr", type=float, default=3e-3)
    p.add_argument("--objects", type=int, default=800, help="single objects rendered (4 views each)")
    p.add_argument("--scenes", type=int, default=12, help="whole scenes for context and background crops")
    p.add_argument("--views", type=int, default=10, help="random views per scene")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument(
        "--label-share", type=float, default=0.5, help="share of cubes, cylinders and mugs with a label"
    )
    p.add_argument("--stripe-share", type=float, default=0.3, help="share of single objects striped")
    p.add_argument("--textured-scenes", type=float, default=0.5, help="share of scenes striped / checkered")
    train(p.parse_args(argv))


if __name__ == "__main__":
    main()
