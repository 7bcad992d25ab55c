"""Batch-bake a folder of meshes and write a quality report (Markdown and CSV).

For every mesh: bake a light field, save it, render orbit views (the CLI eval's: eye at 2.5x the
bounding radius, 40 degrees) and score them against the reference renderer with the core's
metrics. Usage:

    python batch_bake_report.py [--meshes DIR] --out DIR [--cameras 42] [--resolution 128]
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np
from _common import fixture_meshes, write_stand_in_meshes

import lumigraph as lg

COLUMNS = [
    "mesh", "triangles", "cameras", "resolution", "bake_s", "asset_mib",
    "masked_psnr_db", "psnr_db", "ssim", "mask_mismatch_px", "depth_err_median", "ms_per_frame",
]  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--meshes", type=Path, help="folder of meshes (default: the dev fixtures)")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--cameras", type=int, default=42)
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--views", type=int, default=4)
    parser.add_argument("--size", type=int, default=128, help="view width and height, px")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.meshes:
        paths = sorted(p for p in args.meshes.iterdir() if p.is_file())
    else:
        paths = fixture_meshes() or write_stand_in_meshes(args.out / "meshes")

    rows = []
    for path in paths:
        mesh = lg.Mesh.load(path)
        start = time.perf_counter()
        lf = lg.bake_mesh(mesh, cameras=args.cameras, resolution=args.resolution, progress=False)
        bake_s = time.perf_counter() - start
        asset = args.out / f"{path.stem}.lfa"
        lf.save(asset)
        center, radius = lf.bounding_sphere
        views = lg.orbit_views(center, 2.5 * radius, args.views, seed=0, size=args.size)
        frames = lf.render_many(views)
        scores = [lg.metrics.compare(f, lg.reference_render(mesh, v, **lf.shading)) for v, f in zip(views, frames)]
        rows.append({
            "mesh": path.name,
            "triangles": mesh.triangle_count,
            "cameras": lf.cameras,
            "resolution": lf.resolution,
            "bake_s": round(bake_s, 2),
            "asset_mib": round(asset.stat().st_size / 2**20, 2),
            "masked_psnr_db": round(float(np.mean([s["masked_psnr"] for s in scores])), 2),
            "psnr_db": round(float(np.mean([s["psnr"] for s in scores])), 2),
            "ssim": round(float(np.mean([s["ssim"] for s in scores])), 4),
            "mask_mismatch_px": round(float(np.mean([s["mask_mismatch_px"] for s in scores])), 1),
            "depth_err_median": float(np.mean([s["depth"]["median"] for s in scores])),
            "ms_per_frame": round(float(np.mean([f.stats["render_ms"] for f in frames])), 2),
        })  # fmt: skip
        print(f"{path.name}: masked PSNR {rows[-1]['masked_psnr_db']} dB")

    with open(args.out / "report.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    lines = [
        f"# Light-field quality report ({args.views} views of {args.size} px, {lg.device_info()})",
        "",
        "| " + " | ".join(COLUMNS) + " |",
        "|" + "---|" * len(COLUMNS),
    ]
    lines += ["| " + " | ".join(f"{row[c]:.3g}" if isinstance(row[c], float) else str(row[c]) for c in COLUMNS) + " |" for row in rows]
    (args.out / "report.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out / 'report.md'} and {args.out / 'report.csv'}")


if __name__ == "__main__":
    main()
