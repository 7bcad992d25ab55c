"""Helpers of scripts/bench_auto.sh.

    python3 scripts/bench_auto_tables.py views ASSET   # the held-out views of `bake --auto`, JSON
    python3 scripts/bench_auto_tables.py tables OUT    # the BENCHMARKS.md tables, Markdown

The held-out views are the odd points of a Fibonacci spiral of 2 × 24 points at 2.5 bounding
radii, yfov 40°, 256² (core/src/auto_bake.rs `auto_views`); each run's `eval` on them is printed
beside the report's own measurement as a check.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

VIEWS = 24


def frame_of(asset: str) -> tuple[list[float], float]:
    text = subprocess.run(
        ["target/release/lumigraph", "info", asset], check=True, capture_output=True, text=True
    ).stdout
    header = json.loads(text[text.index("\n{") + 1 :])
    return header["frame"]["center"], header["frame"]["radius"]


def held_out_views(center: list[float], radius: float) -> list[dict[str, Any]]:
    total = 2 * VIEWS
    golden = math.pi * (3.0 - math.sqrt(5.0))
    views = []
    for i in range(1, total, 2):
        y = 1.0 - (2.0 * i + 1.0) / total
        s = math.sqrt(max(0.0, 1.0 - y * y))
        phi = golden * i
        d = 2.5 * radius
        eye = [center[0] + d * s * math.cos(phi), center[1] + d * y, center[2] + d * s * math.sin(phi)]
        up = [0.0, 0.0, 1.0] if abs(y) > 0.99 else [0.0, 1.0, 0.0]
        views.append(
            {"eye": eye, "target": center, "up": up, "yfov_deg": 40.0, "width": 256, "height": 256}
        )
    return views


def load(path: Path) -> Any:
    return json.loads(path.read_text())


def mib(n: float) -> str:
    return f"{n / 2**20:.2f}"


def tables(out: Path) -> str:
    rows = []
    equal_q = []
    equal_b = []
    for dir in sorted(p for p in out.iterdir() if p.is_dir()):
        scene = dir.name
        default_psnr = load(dir / "default-eval.json")["mean"]["masked_psnr"]
        default_bytes = (dir / "default.lfa").stat().st_size
        for run in ["psnr-24", "psnr-27", "psnr-30", "equal-quality", "equal-bytes"]:
            if not (dir / f"{run}.json").exists():
                continue
            r = load(dir / f"{run}.json")
            check = load(dir / f"{run}-eval.json")["mean"]["masked_psnr"]
            s = r["choice"]["setting"]
            target = r["target"]
            wall = float((dir / f"{run}.time").read_text().split()[-1])
            row = {
                "scene": scene,
                "run": run,
                "target": f"{target['target_psnr']:.2f} dB"
                if "target_psnr" in target
                else f"≤ {target['max_bytes']} B",
                "setting": f"{s['cameras']} × {s['resolution']} px × {s['depth_bits']}-bit",
                "predicted": s["predicted_psnr"],
                "corrected": s["predicted_psnr"] + r["choice"]["correction_db"],
                "bakes": ", ".join(
                    f"{b['choice']['setting']['cameras']}×{b['choice']['setting']['resolution']}"
                    + (f": {b['tuning_psnr']:.2f}" if b["tuning_psnr"] is not None else "")
                    for b in r["bakes"]
                ),
                "measured": r["measured_psnr"],
                "check": check,
                "bytes": r["asset_bytes"],
                "predicted_bytes": s["predicted_bytes"],
                "reach": r["choice"]["reach"],
                "met": r["target_met"],
                "calibrate_s": r["calibrate_ms"] / 1e3,
                "wall_s": wall,
                "default_psnr": default_psnr,
                "default_bytes": default_bytes,
            }
            rows.append(row)
            if run == "equal-quality":
                equal_q.append(row)
            if run == "equal-bytes":
                equal_b.append(row)
    lines = [
        "| scene | target | bakes (cameras×map: tuning dB) | kept (cameras × map × depth) | predicted dB (corrected) | measured dB (held-out) | eval check dB | measured − target | asset MiB (predicted) | default MiB | default dB | reach | met | calibration s | wall s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if r["run"] == "equal-bytes":
            delta = "—"
        else:
            t = float(r["target"].split()[0])
            delta = f"{r['measured'] - t:+.2f}"
        lines.append(
            f"| {r['scene']} | {r['target']} | {r['bakes']} | {r['setting']} | {r['predicted']:.2f} ({r['corrected']:.2f}) | {r['measured']:.2f} | "
            f"{r['check']:.2f} | {delta} | {mib(r['bytes'])} ({mib(r['predicted_bytes'])}) | {mib(r['default_bytes'])} | "
            f"{r['default_psnr']:.2f} | {r['reach']} | {'yes' if r['met'] else 'no'} | {r['calibrate_s']:.1f} | {r['wall_s']:.1f} |"
        )
    lines += [
        "",
        "Equal quality (target = the default bake's held-out masked PSNR):",
        "",
        "| scene | default dB | default MiB | auto measured dB | auto MiB | bytes saved |",
        "|---|---|---|---|---|---|",
    ]
    for r in equal_q:
        saved = 1.0 - r["bytes"] / r["default_bytes"]
        lines.append(
            f"| {r['scene']} | {r['default_psnr']:.2f} | {mib(r['default_bytes'])} | {r['measured']:.2f} | {mib(r['bytes'])} | {saved:.0%} |"
        )
    lines += [
        "",
        "Equal bytes (--max-bytes = the default bake's size):",
        "",
        "| scene | default MiB | default dB | auto MiB | auto measured dB | quality gained |",
        "|---|---|---|---|---|---|",
    ]
    for r in equal_b:
        lines.append(
            f"| {r['scene']} | {mib(r['default_bytes'])} | {r['default_psnr']:.2f} | {mib(r['bytes'])} | {r['measured']:.2f} | {r['measured'] - r['default_psnr']:+.2f} dB |"
        )
    return "\n".join(lines)


def main() -> None:
    if len(sys.argv) != 3 or sys.argv[1] not in ("views", "tables"):
        sys.exit(__doc__)
    if sys.argv[1] == "views":
        center, radius = frame_of(sys.argv[2])
        print(json.dumps(held_out_views(center, radius)))
    else:
        print(tables(Path(sys.argv[2])))


if __name__ == "__main__":
    main()
