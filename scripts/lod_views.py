"""Views in which an asset's bounding sphere projects to given sizes (pixels across).

    python3 scripts/lod_views.py LUMIGRAPH ASSET FRAME_PX SIZE,SIZE,... > views.json

The eye sits at distance d = r·sqrt(1 + (2f/P)²) from the centre (f: focal length in pixels of a
40° frame of FRAME_PX), which makes the tangent cone 2·f·r/sqrt(d² − r²) = P pixels wide; the
direction turns from view to view so every size sees another side.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys


def main() -> None:
    lumigraph, asset, frame_px, sizes = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
    info = subprocess.run([lumigraph, "info", asset], check=True, capture_output=True, text=True).stdout
    header = json.loads(info[info.index("\n{") + 1 :])
    center, radius = header["frame"]["center"], header["frame"]["radius"]
    focal = frame_px / 2 / math.tan(math.radians(20.0))
    views = []
    for i, size in enumerate(float(s) for s in sizes.split(",")):
        d = radius * math.sqrt(1.0 + (2.0 * focal / size) ** 2)
        a = 0.7 + 1.3 * i
        direction = [0.8 * math.cos(a), 0.45, 0.8 * math.sin(a)]
        norm = math.sqrt(sum(x * x for x in direction))
        eye = [center[k] + d * direction[k] / norm for k in range(3)]
        views.append({"eye": eye, "target": center, "yfov_deg": 40.0, "width": frame_px, "height": frame_px})
    json.dump(views, sys.stdout)


if __name__ == "__main__":
    main()
