"""`import lumigraph`, a bake and a render print nothing on stderr, also without a login session
(no XDG_RUNTIME_DIR), where Mesa would otherwise print an error line per adapter listing."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

SCRIPT = """
import lumigraph as lg
mesh = lg.Mesh.demo()
lf = lg.bake_mesh(mesh, cameras=12, resolution=32, progress=False, calibrate=False)
center, radius = mesh.bounding_sphere
view = lg.orbit_views(center, 2.5 * radius, 1, seed=0, yfov_deg=40.0, size=32)[0]
frame = lf.render(view)
assert frame.color.shape == (32, 32, 4)
print("rendered")
"""


def test_bake_and_render_without_a_runtime_dir_print_nothing_on_stderr(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("XDG_RUNTIME_DIR", "RUST_LOG")}
    env["TMPDIR"] = str(tmp_path)
    result = subprocess.run(
        [sys.executable, "-c", SCRIPT], capture_output=True, text=True, env=env, check=False
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "rendered"
    assert result.stderr.strip() == "", result.stderr
    made = [p for p in tmp_path.iterdir() if p.name.startswith("lumigraph-xdg-")]
    assert len(made) == 1 and (made[0].stat().st_mode & 0o777) == 0o700
