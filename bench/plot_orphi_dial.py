"""The outlier dial's plot (issue 46 item 4): full minus w/o OR-phi, Strict and IoU, against the
share S of outlier views, with the scene-level paired bootstrap 95 % intervals as error bars, in
the geometric scoring and the Clio-code scoring, from bench/orphi_dial.py's JSON.

Usage: python bench/plot_orphi_dial.py [--json bench/results/ablation-20261207/orphi-dial.json]
    [--out docs/research/orphi-dial.png]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

SCORINGS = {"geometric": "geometric scoring", "clio_code": "Clio-code scoring"}
METRICS = {"strict_osr": "Strict-OsR", "iou": "IoU"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", type=Path, default=Path("bench/results/ablation-20261207/orphi-dial.json"))
    parser.add_argument("--out", type=Path, default=Path("docs/research/orphi-dial.png"))
    parser.add_argument(
        "--more",
        type=Path,
        default=Path("bench/results/ablation-20261207/ten-scenes/orphi-dial.json"),
        help="a second run of the sweep on more scenes (drawn as its own series when present)",
    )
    args = parser.parse_args()
    results = json.loads(args.json.read_text())
    more = json.loads(args.more.read_text()) if args.more.is_file() else {}
    shares = sorted(results, key=float)
    x = [float(s) for s in shares]
    fig, axes = plt.subplots(1, len(METRICS), figsize=(9, 3.6), sharex=True)
    for ax, (metric, label) in zip(axes, METRICS.items(), strict=True):
        for k, (scoring, name) in enumerate(SCORINGS.items()):
            d = [results[s][scoring][metric] for s in shares]
            mean = [v["diff"] for v in d]
            err = [[v["diff"] - v["low"] for v in d], [v["high"] - v["diff"] for v in d]]
            offset = (k - 0.5) * 0.012
            ax.errorbar([v + offset for v in x], mean, yerr=err, fmt="o-", capsize=4, label=name)
        if more:
            m_shares = sorted(more, key=float)
            d = [more[s]["geometric"][metric] for s in m_shares]
            err = [[v["diff"] - v["low"] for v in d], [v["high"] - v["diff"] for v in d]]
            n_more = len(more[m_shares[0]]["scenes"])
            ax.errorbar(
                [float(s) + 0.02 for s in m_shares], [v["diff"] for v in d], yerr=err, fmt="s",
                capsize=4, color="black", label=f"geometric, {n_more} scenes",
            )  # fmt: skip
        ax.axhline(0.0, color="grey", linewidth=0.8)
        ax.set_xlabel("share S of outlier views")
        ax.set_ylabel(f"full minus w/o OR-phi, {label}")
        ax.set_xticks(x)
        ax.set_title(label)
    axes[0].legend(fontsize=8)
    n = len(results[shares[0]]["scenes"])
    fig.suptitle(
        f"OR-phi as the outlier views rise: {n} public capture scenes (circles), realistic regime, "
        "95 % scene-level paired bootstrap",
        fontsize=9,
    )
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=120)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
