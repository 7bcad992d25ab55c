"""Formats the raw `lumigraph eval --json` reports of scripts/bench.sh as markdown tables."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def load(path: Path) -> dict:
    return json.loads(path.read_text())


def quality_table(out: Path) -> list[str]:
    rows = [
        "| scene | cameras | method | asset MiB | bake s | MAE | masked PSNR | PSNR ∩ masks | PSNR | SSIM | mask mismatch px | depth err median (× r) | ms/frame |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for scene in ["bunny", "cow", "spot", "demo"]:
        for cams in [42, 162]:
            bake_time = (out / f"{scene}-{cams}.bake-time").read_text().split(",")[0]
            for method in ["default", "fixed"]:
                path = out / f"{scene}-{cams}-{method}.json"
                if not path.exists():
                    continue
                r = load(path)
                m = r["mean"]
                radius = r.get("radius") or 1.0
                rows.append(
                    f"| {scene} | {cams} | {method} | {r['asset_bytes'] / 2**20:.2f} | {bake_time} | {m['mae']:.2f} | "
                    f"{m['masked_psnr']:.2f} | {m['intersection_psnr']:.2f} | {m['psnr']:.2f} | {m['ssim']:.4f} | "
                    f"{m['mask_mismatch_px']:.0f} | {m['depth']['median'] / radius:.2e} | {r['mean_ms']:.1f} |"
                )
    return rows


def speed_table(out: Path) -> list[str]:
    rows = [
        "| cameras | method | step (diameters) | ms/frame 512² | fetches/pixel | masked PSNR |",
        "|---|---|---|---|---|---|",
    ]
    for cams in [12, 42, 162]:
        for method in ["default", "fixed"]:
            for step in ["0.0625", "0.03125", "0.015625"]:
                path = out / f"speed-{cams}-{method}-{step}.json"
                if not path.exists():
                    continue
                r = load(path)
                fetches = r.get("mean_fetches_per_pixel", float("nan"))
                rows.append(
                    f"| {cams} | {method} | {step} | {r['mean_ms']:.1f} | {fetches:.1f} | {r['mean']['masked_psnr']:.2f} |"
                )
    return rows


def main() -> None:
    out = Path(sys.argv[1])
    lines = ["### Quality (256-px maps, 12 random views at 256², 2.5 r orbit)", ""]
    lines += quality_table(out)
    lines += ["", "### Speed at 512×512 (bunny, 6 random views)", ""]
    lines += speed_table(out)
    cold = out / "cold-start"
    if cold.exists():
        lines += ["", f"Cold start (process start → first 512² frame written): {cold.read_text().strip()} s"]
    print("\n".join(lines))


if __name__ == "__main__":
    main()
