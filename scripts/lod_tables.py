"""Formats scripts/bench_lod.sh's eval reports as the Markdown tables of BENCHMARKS.md.

    python3 scripts/lod_tables.py OUT_DIR SCENE [SCENE ...]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def level(d: dict) -> str:
    text = f"{d['level']['cameras']} × 1/{round(1 / d['level']['step'])}"
    if d.get("blend"):
        nxt, w = d["blend"]
        text += f" → {nxt['cameras']} × 1/{round(1 / nxt['step'])} ({w:.0%})"
    return text


def main() -> None:
    out, scenes = Path(sys.argv[1]), sys.argv[2:]
    for scene in scenes:
        auto = json.loads((out / f"{scene}.auto.json").read_text())
        base = json.loads((out / f"{scene}.default.json").read_text())
        print(f"\n**{scene}** (162 cameras, 256-px maps; 512² frames; default = 162 × 1/32)\n")
        print("| object px | auto level | silhouette error px, predicted / measured | ms auto / default | masked PSNR auto / default |")
        print("|---|---|---|---|---|")
        for a, b in zip(auto["views"], base["views"]):
            d = a["lod"]
            print(
                f"| {d['projected_px']:.0f} | {level(d)} | {d['error_px']:.2f} / {a['silhouette_error_px']:.2f}"
                f"{'' if d['met'] else ' (bound unmet)'} | {a['ms']:.0f} / {b['ms']:.0f} | "
                f"{a['masked_psnr']:.2f} / {b['masked_psnr']:.2f} |"
            )
        print(
            f"| mean | | | {auto['mean_ms']:.0f} / {base['mean_ms']:.0f} | "
            f"{auto['mean']['masked_psnr']:.2f} / {base['mean']['masked_psnr']:.2f} |"
        )


if __name__ == "__main__":
    main()
