"""Plot ms/frame against masked PSNR over camera counts (lod) and march step sizes.

One bake at the largest camera count serves every lower count (nested camera sets). Each point
is the mean over orbit views of the render time (GPU work plus readback) and of the masked PSNR
against the reference renderer. Usage: python quality_vs_speed.py --out plot.png [--mesh PATH]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from _common import fixture_meshes

import lumigraph as lg


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--mesh", type=Path, help="mesh file (default: the bunny fixture or the demo)")
    parser.add_argument("--cameras", type=int, default=162)
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--views", type=int, default=3)
    parser.add_argument("--size", type=int, default=128)
    args = parser.parse_args()
    bunny = [p for p in fixture_meshes() if p.name.startswith("bunny")]
    source = args.mesh or (bunny[0] if bunny else None)
    mesh = lg.Mesh.load(source) if source else lg.Mesh.demo()
    lf = lg.bake_mesh(mesh, cameras=args.cameras, resolution=args.resolution, progress=False)
    center, radius = lf.bounding_sphere
    views = lg.orbit_views(center, 2.5 * radius, args.views, seed=0, size=args.size)
    references = [lg.reference_render(mesh, v, **lf.shading) for v in views]
    lf.render(views[0])  # upload and warm the pipeline outside the timings

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for lod in [n for n in (12, 42, 162, 642) if n <= lf.cameras]:
        xs, ys = [], []
        for step in (1 / 8, 1 / 16, 1 / 32, 1 / 64):
            frames = lf.render_many(views, lod=lod, step=step)
            xs.append(float(np.mean([f.stats["render_ms"] for f in frames])))
            ys.append(float(np.mean([lg.metrics.masked_psnr(f, r) for f, r in zip(frames, references)])))
            ax.annotate(f"1/{round(1 / step)}", (xs[-1], ys[-1]), fontsize=7)
        ax.plot(xs, ys, marker="o", label=f"{lod} cameras")
        print(f"lod {lod}: ms/frame {np.round(xs, 1)}, masked PSNR {np.round(ys, 2)} dB")
    ax.set_xlabel(f"ms / frame ({args.size}x{args.size} px, GPU work plus readback)")
    ax.set_ylabel("masked PSNR vs reference (dB)")
    ax.set_title(f"{mesh.name}: quality vs speed (point labels: march step, diameters)", fontsize=10)
    fig.text(0.01, 0.01, lg.device_info()[:110], fontsize=6, color="grey")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.out, dpi=120)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
