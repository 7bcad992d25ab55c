"""Formats the `lumigraph bench tradeoff` CSVs of scripts/bench_tradeoff.sh as markdown tables.

For each scene: the seed's fixed-step baseline (162 cameras, step 1/64, tolerance step/2, 16-bit
depth) against the default marcher at its defaults, both at 512², then the Pareto front.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

SCENES = ["bunny", "cow", "spot", "demo"]


def load(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def pick(rows: list[dict[str, str]], **want: str) -> dict[str, str] | None:
    for r in rows:
        if all(abs(float(r[k]) - float(v)) < 1e-9 if k in ("step", "tolerance") else r[k] == v for k, v in want.items()):
            return r
    return None


def fmt(r: dict[str, str]) -> str:
    step = float(r["step"])
    return (
        f"{r['cameras']} | {r['method']} | 1/{1 / step:.0f} | {float(r['tolerance']) / step:.2g} | {r['depth_bits']} | "
        f"{r['size']}² | {float(r['ms_per_frame']):.1f} | {float(r['fetches_per_pixel']):.1f} | "
        f"{float(r['masked_psnr']):.2f} | {float(r['ssim']):.4f} | {float(r['depth_median_r']):.1e}"
    )


HEAD = (
    "| scene | setting | cameras | method | step | tol/step | depth bits | size | ms/frame | fetches/px | masked PSNR | SSIM | depth err median (× r) |\n"
    "|---|---|---|---|---|---|---|---|---|---|---|---|---|"
)


def main() -> None:
    out = Path(sys.argv[1] if len(sys.argv) > 1 else "out/tradeoff")
    print("### Default marcher against the seed's fixed-step baseline (512², 162 cameras, 16-bit depth)\n")
    print(HEAD)
    for scene in SCENES:
        path = out / scene / "tradeoff.csv"
        if not path.exists():
            continue
        rows = load(path)
        base = dict(cameras="162", depth_bits="16", size="512")
        fixed = pick(rows, method="fixed", step=1 / 64, tolerance=1 / 128, **base)
        default = pick(rows, method="default", step=1 / 32, tolerance=1 / 64, **base)
        for name, r in (("baseline: fixed 64 steps", fixed), ("default", default)):
            if r is not None:
                print(f"| {scene} | {name} | {fmt(r)} |")
        if fixed is not None:
            # The cheapest 512² setting at least 3 dB better than the baseline.
            better = [
                r
                for r in rows
                if r["size"] == "512" and float(r["masked_psnr"]) >= float(fixed["masked_psnr"]) + 3.0
            ]
            if better:
                r = min(better, key=lambda r: float(r["ms_per_frame"]))
                ratio = float(r["ms_per_frame"]) / float(fixed["ms_per_frame"])
                print(f"| {scene} | cheapest ≥ baseline + 3 dB ({ratio:.2f}× baseline time) | {fmt(r)} |")
    print("\n### Pareto fronts (ms/frame against masked PSNR, all sizes)\n")
    print(HEAD)
    for scene in SCENES:
        path = out / scene / "tradeoff.csv"
        if not path.exists():
            continue
        front = sorted((r for r in load(path) if r["pareto"] == "true"), key=lambda r: float(r["ms_per_frame"]))
        for r in front:
            print(f"| {scene} | front | {fmt(r)} |")


if __name__ == "__main__":
    main()
