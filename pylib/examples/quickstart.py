import lumigraph as lg
import trimesh

mesh = trimesh.creation.icosphere(subdivisions=3)  # or a path, or (vertices, faces[, colors]) arrays
lf = lg.bake_mesh(mesh, cameras=42, resolution=128)  # GPU bake (Mesa lavapipe on CPU-only machines)
lf.save("sphere.lfa")
view = {"eye": [0, 1, 3], "target": [0, 0, 0], "up": [0, 1, 0], "yfov_deg": 40, "width": 256, "height": 256}
frame = lg.LightField.open("sphere.lfa").render(view)  # .color (H, W, 4) uint8, .depth (H, W) float32
reference = lg.reference_render(mesh, view, **lf.shading)  # rasterized mesh: the ground truth
print(f"masked PSNR {lg.metrics.masked_psnr(frame, reference):.1f} dB in {frame.stats['render_ms']:.1f} ms")
