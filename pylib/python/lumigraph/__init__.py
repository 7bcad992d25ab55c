"""lumigraph: bake meshes into spherical light fields and render them on the GPU.

Quick start::

    import lumigraph as lg
    lf = lg.bake_mesh("bunny.ply", cameras=162, resolution=256)   # or a trimesh.Trimesh
    view = {"eye": [0, 0, 3], "target": [0, 0, 0], "up": [0, 1, 0],
            "yfov_deg": 40, "width": 256, "height": 256}
    frame = lf.render(view)            # frame.color (H, W, 4) uint8, frame.depth (H, W) float32
    ref = lg.reference_render("bunny.ply", view, **lf.shading)
    print(lg.metrics.masked_psnr(frame, ref))

Everything runs on the same core as the ``lumigraph`` CLI and service (one device per process,
Mesa lavapipe on CPU-only machines). Bake and render release the GIL; every object may be used
from several threads. Options are keyword-only. Conventions (DESIGN §3): right-handed world,
views in the mesh's own world coordinates, depth is z-depth along the view direction in world
units (+inf where nothing is hit).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Mapping, Sequence
from typing import Any, TypeAlias

import numpy as np

from . import metrics
from ._lumigraph import (
    AssetError,
    BakeError,
    Frame,
    LightField,
    LumigraphError,
    Mesh,
    MeshError,
    RenderError,
    View,
    __version__,
    device_info,
    orbit_views,
)
from ._lumigraph import bake as _bake
from ._lumigraph import bake_two_plane as _bake_two_plane
from ._lumigraph import bake_volume as _bake_volume
from ._lumigraph import import_lightfield as _import_lightfield
from ._lumigraph import import_zstack as _import_zstack
from ._lumigraph import reference_render as _reference_render
from ._lumigraph import reference_volume as _reference_volume

__all__ = [
    "AssetError",
    "BakeError",
    "DEFAULT_AMBIENT",
    "DEFAULT_LIGHT",
    "Frame",
    "LightField",
    "LumigraphError",
    "Mesh",
    "MeshError",
    "MeshLike",
    "RenderError",
    "View",
    "ViewLike",
    "__version__",
    "as_mesh",
    "bake_animation",
    "bake_mesh",
    "bake_two_plane",
    "bake_volume",
    "device_info",
    "import_lightfield",
    "import_zstack",
    "metrics",
    "orbit_views",
    "reference_render",
    "reference_volume",
]

#: Default light direction (normalized when used), DESIGN §3.
DEFAULT_LIGHT: tuple[float, float, float] = (0.3, 1.0, 0.5)
#: Default ambient term, DESIGN §3.
DEFAULT_AMBIENT: float = 0.25

#: What the functions accept as a mesh: a :class:`Mesh`, a ``trimesh.Trimesh``, a path, or
#: ``(vertices, faces)`` / ``(vertices, faces, colors)`` arrays.
MeshLike: TypeAlias = "Mesh | str | os.PathLike[str] | Sequence[Any] | Any"
#: A :class:`View` or a dict with keys eye, target, up, yfov_deg, width, height.
ViewLike: TypeAlias = "View | Mapping[str, Any]"


def as_mesh(mesh: MeshLike, *, name: str | None = None) -> Mesh:
    """Converts any accepted mesh input into a validated :class:`Mesh`.

    Args:
        mesh: one of
            - a :class:`Mesh` (returned as is);
            - a path (``str`` or ``os.PathLike``) to glTF/GLB, OBJ (+MTL), PLY, STL or OFF,
              loaded by lumigraph's own loaders (the CLI's);
            - a ``trimesh.Trimesh``: vertex colours, face colours (vertices are split per face)
              and texture visuals (``SimpleMaterial.image`` × ``diffuse`` or
              ``PBRMaterial.baseColorTexture`` × ``baseColorFactor``; trimesh's v-up UVs are
              flipped to lumigraph's glTF convention) are honoured; normals are recomputed
              (area-weighted), as for every source without explicit normals;
            - ``(vertices, faces)`` or ``(vertices, faces, colors)``: (N, 3) real, (M, 3)
              integer, and (N, 3|4) uint8 0..255 or float 0..1 arrays.
        name: source name recorded in a baked asset's provenance (default: the file name,
            ``"trimesh"`` or ``"arrays"``).

    Raises:
        TypeError: an unsupported type, or arrays of the wrong dtype kind.
        ValueError: arrays of the wrong shape; MeshError (a ValueError): invalid mesh data.
        FileNotFoundError: a path that does not exist.
    """
    if isinstance(mesh, Mesh):
        return mesh
    if isinstance(mesh, (str, os.PathLike)):
        return Mesh.load(os.fspath(mesh))
    module = type(mesh).__module__ or ""
    if module.startswith("trimesh"):
        if type(mesh).__name__ == "Scene":
            raise TypeError(
                "a trimesh.Scene holds several meshes: load with trimesh.load(path, force='mesh') "
                "or concatenate with scene.to_geometry()"
            )
        return _from_trimesh(mesh, name)
    if isinstance(mesh, (tuple, list)) and len(mesh) in (2, 3):
        colors = mesh[2] if len(mesh) == 3 else None
        return Mesh(mesh[0], mesh[1], colors, name=name or "arrays")
    raise TypeError(
        "mesh must be a lumigraph.Mesh, a trimesh.Trimesh, a file path, or a "
        f"(vertices, faces[, colors]) tuple of arrays; got {type(mesh).__name__}"
    )


def _from_trimesh(tm: Any, name: str | None) -> Mesh:
    vertices = np.asarray(tm.vertices)
    faces = np.asarray(tm.faces)
    if name is None:
        name = str(getattr(tm, "metadata", {}).get("file_name") or "trimesh")
    visual: Any = getattr(tm, "visual", None)
    kind = getattr(visual, "kind", None)
    if kind == "vertex":
        return Mesh(vertices, faces, np.asarray(visual.vertex_colors), name=name)
    if kind == "face":
        # Per-face colours have no per-vertex form: give every face its own three vertices.
        face_colors = np.asarray(visual.face_colors)
        split = vertices[faces].reshape(-1, 3)
        return Mesh(
            split,
            np.arange(len(split), dtype=np.int64).reshape(-1, 3),
            np.repeat(face_colors, 3, axis=0),
            name=name,
        )
    if kind == "texture" and getattr(visual, "uv", None) is not None:
        material = visual.material
        image = getattr(material, "baseColorTexture", None)
        factor = getattr(material, "baseColorFactor", None)
        if image is None and factor is None:
            image = getattr(material, "image", None)
            factor = getattr(material, "diffuse", None)
        base_color = None
        if factor is not None:
            f = np.asarray(factor, dtype=np.float64).reshape(-1)
            if np.asarray(factor).dtype == np.uint8 or f.max(initial=0.0) > 1.0:
                f = f / 255.0
            base_color = tuple(float(c) for c in np.clip(np.resize(f, 4), 0.0, 1.0))
            if f.size == 3:
                base_color = (*base_color[:3], 1.0)
        uv = np.asarray(visual.uv, dtype=np.float64)
        uv_gltf = np.column_stack([uv[:, 0], 1.0 - uv[:, 1]])
        texture = None if image is None else np.asarray(image.convert("RGBA"))
        return Mesh(
            vertices,
            faces,
            uvs=uv_gltf if texture is not None else None,
            texture=texture,
            base_color=base_color,
            name=name,
        )
    return Mesh(vertices, faces, name=name)


def _progress_printer() -> Callable[[int, int], None]:
    def report(done: int, total: int) -> None:
        end = "\n" if done >= total else ""
        print(f"\rbaking cameras {done}/{total}", end=end, file=sys.stderr, flush=True)

    return report


def _progress_callback(
    progress: bool | Callable[[int, int], object] | None,
) -> Callable[[int, int], object] | None:
    """A bake's `progress` argument as the native callback: True prints, False/None is silent."""
    if progress is True:
        return _progress_printer()
    if progress is False or progress is None:
        return None
    return progress


def bake_mesh(
    mesh: MeshLike,
    *,
    cameras: int | None = None,
    resolution: int | None = None,
    light: Sequence[float] = DEFAULT_LIGHT,
    ambient: float = DEFAULT_AMBIENT,
    specular: tuple[float, float] | None = None,
    unlit: bool = False,
    depth_bits: int | None = None,
    progress: bool | Callable[[int, int], object] = True,
    calibrate: bool = False,
    auto: bool = False,
    target_psnr: float | None = None,
    max_bytes: int | None = None,
    shadows: bool = False,
    lights: int | None = None,
    states: Mapping[str, MeshLike] | None = None,
    color_codec: str = "raw",
    depth_codec: str | None = None,
) -> LightField:
    """Bakes a mesh into a spherical light field on the GPU (GIL released).

    Every camera of an icosphere camera set records a parabolic colour + depth map of the
    hemisphere opposite to it; depth is exact per texel (ray traced). Shading (DESIGN §3, §9):
    ``color = albedo * (ambient + (1 - ambient) * V * max(0, n·light)) + ks * V * max(0, n·h)**shininess``
    with ``V = 1`` unless ``shadows``.

    Args:
        mesh: a :class:`Mesh`, ``trimesh.Trimesh``, path, or ``(vertices, faces[, colors])``
            (see :func:`as_mesh`).
        cameras: 12, 42, 162 (default) or 642 (icosphere levels 0-3; coarser sets are
            prefixes, so the asset also renders at every lower ``lod``).
        resolution: side of each camera's parabolic map in pixels, 8..4096, default 256
            (silhouette accuracy grows with it; size and bake time with its square).
        light: world-space light direction (x, y, z), non-zero; normalized.
        ambient: ambient term in [0, 1].
        specular: ``(ks, shininess)`` with 0 <= ks <= 1 and 0 < shininess <= 10000, or None for
            view-independent (Lambertian) shading.
        unlit: if True, ``color = albedo``.
        shadows: if True, every texel casts a shadow ray towards the light through the mesh
            (DESIGN §9): ``V`` is 0 where it meets a triangle. Recorded in the asset, so
            ``**lf.shading`` and ``lumigraph eval`` shade the reference alike.
        lights: light states (DESIGN §9): also bake the colour for each of 12, 42 or 162 light
            directions (a nested icosphere) plus the ambient part and the shading normals,
            sharing one depth per camera, so that ``lf.render(view, light=(x, y, z))`` relights the asset at any
            direction (with ``shadows``, the shadows move). Costs ``(lights + 2) x cameras x
            resolution**2 x 4`` bytes more in memory. Not with ``auto`` or ``unlit``.
        states: deformation states ``{"name": mesh}`` (any :func:`as_mesh` input, any topology,
            inside ``mesh``'s bounding sphere): each is baked in ``mesh``'s frame and stores
            only the pages whose colour or depth differ from the base (exactly: the bake is
            deterministic); ``lf.render(view, state="name")`` renders it and
            ``lf.deformations`` says what each stores. Not with ``auto`` or ``lights``.
        depth_bits: depth precision, 16 (default) or 8. With ``auto=True``, ``cameras``,
            ``resolution`` and ``depth_bits`` are chosen and must not be given.
        color_codec: colour pages as RGBA8 texels (``"raw"``, default) or GPU blocks:
            ``"bc1"`` (4 bits per texel) or ``"bc7"`` (8); both drop the edge texels that place
            silhouettes between texels (``docs/format.md`` §7.1; BENCHMARKS "Block
            compression" measures the loss). Not with ``auto``.
        depth_codec: ``"r16"``, ``"r8"`` (as ``depth_bits``) or ``"bc4"`` (8-bit codes in
            4-bit blocks; blurs depth across silhouettes). Not with ``depth_bits`` or ``auto``.
        progress: True prints "baking cameras k/n" to stderr; a callable gets
            ``(cameras_done, cameras_total)`` (its first exception is raised after the bake);
            False is silent.
        calibrate: if True, also measure this scene's error against cost (the default
            marcher at every camera count × step 1/8..1/64 on 4 views of 256², against the
            mesh; ~4 s at 162 cameras on a 2-core CPU) into the asset's quality report, for
            :meth:`LightField.render` / :meth:`LightField.choose` with ``target_psnr`` or
            ``budget_ms``. ``lumigraph bake`` on the command line calibrates by default.
        auto: if True, choose cameras, map resolution and depth bits for this scene
            (``lumigraph bake --auto``, docs/auto-bake.md): three low-resolution calibration
            bakes measured against the mesh fit a model of masked PSNR and bytes; the setting it
            picks is baked and, for a target PSNR, measured on tuning views and corrected (at
            most three bakes); the kept bake is measured on held-out views. The report is in
            ``info["quality"]["auto_bake"]`` (choice with predictions, ``correction_db`` and
            ``reach``, ``bakes`` with each one's tuning PSNR, ``measured_psnr``,
            ``target_met``, ``message`` for a target out of reach). Tens of seconds on a 2-core
            CPU; ``progress`` reports the bakes of the chosen settings only.
        target_psnr: with ``auto``: the masked PSNR (dB, in (0, 100]) to reach with the fewest
            bytes; default 27 when ``max_bytes`` is not given either.
        max_bytes: with ``auto``: the asset size within which to reach the best masked PSNR.

    Returns:
        The baked :class:`LightField` (in memory; :meth:`LightField.save` writes it).

    Raises:
        ValueError: an option out of range (the message names it), a NaN/infinite/out-of-range
            target, both targets, or a target or chosen knob with(out) ``auto``; a state mesh
            outside the base's bounding sphere, a state named ``base`` or twice; MeshError:
            invalid mesh.
        TypeError: an argument of the wrong type.
        BakeError: the GPU device failed or is missing (the message names the driver package).
    """
    if auto:
        given = [
            name
            for name, value in (
                ("cameras", cameras),
                ("resolution", resolution),
                ("depth_bits", depth_bits),
            )
            if value is not None
        ]
        if given:
            raise ValueError(f"auto=True chooses {', '.join(given)}: do not pass them")
        if depth_codec is not None or color_codec != "raw":
            raise ValueError("auto=True bakes raw pages: do not pass color_codec or depth_codec")
    bits, depth_block = _depth_storage(depth_codec, depth_bits)
    native = as_mesh(mesh)
    callback = _progress_callback(progress)
    return _bake(
        native,
        cameras=162 if cameras is None else cameras,
        resolution=256 if resolution is None else resolution,
        light=tuple(light),
        ambient=ambient,
        specular=specular,
        unlit=unlit,
        depth_bits=bits,
        progress=callback,
        calibrate=calibrate,
        auto=auto,
        target_psnr=target_psnr,
        max_bytes=max_bytes,
        shadows=shadows,
        lights=lights,
        states=None if states is None else [(name, as_mesh(m)) for name, m in states.items()],
        color_codec=color_codec,
        depth_codec=depth_block,
    )


def _depth_storage(depth_codec: str | None, depth_bits: int | None) -> tuple[int, str | None]:
    """Depth bits and block codec of ``depth_codec`` (``"r16"``, ``"r8"``, ``"bc4"``) or of
    ``depth_bits`` (default 16): the command line's ``--depth-codec`` and ``--depth-bits``."""
    if depth_codec is None:
        return (16 if depth_bits is None else depth_bits, None)
    if depth_bits is not None:
        raise ValueError("depth_codec sets the depth bits: do not pass depth_bits too")
    storage = {"r16": (16, None), "r8": (8, None), "bc4": (8, "bc4")}
    if depth_codec not in storage:
        raise ValueError(f"depth_codec {depth_codec!r}: use r16, r8 or bc4")
    return storage[depth_codec]


def _planes_json(planes: object, other: str) -> str:
    """DESIGN §9's plane JSON text of a dict or of a JSON file's path (``other`` names the
    caller's third accepted value in the TypeError)."""
    import json

    if isinstance(planes, Mapping):
        return json.dumps(dict(planes))
    if isinstance(planes, (str, os.PathLike)):
        with open(planes, encoding="utf-8") as f:
            return f.read()
    raise TypeError(f"planes must be {other}, a dict or a path to a JSON file")


def bake_two_plane(
    mesh: MeshLike,
    *,
    planes: Mapping[str, Any] | str | os.PathLike[str] = "auto",
    axis: Sequence[float] = (0.0, 0.0, 1.0),
    grid: tuple[int, int] = (8, 8),
    st_res: tuple[int, int] = (256, 256),
    light: Sequence[float] = DEFAULT_LIGHT,
    ambient: float = DEFAULT_AMBIENT,
    specular: tuple[float, float] | None = None,
    unlit: bool = False,
    shadows: bool = False,
    progress: bool | Callable[[int, int], object] = True,
) -> LightField:
    """Captures a mesh into a two-plane light field L(u, v, s, t) on the GPU (GIL released).

    One off-axis camera per uv grid cell images the st rectangle (DESIGN §9): colour and the
    stored depth ``|hit - C| / |S - C|`` of the first surface beyond the camera, geometry
    between the planes included. Render with ``lf.render(view, uv_filter=..., focus=...,
    aperture=...)`` (docs/two_plane.md).

    Args:
        mesh: any :func:`as_mesh` input.
        planes: ``"auto"`` to fit the planes to the mesh's bounding sphere along ``axis`` (st
            through its centre, uv three radii from it; ``lf.planes`` says what was chosen),
            DESIGN §9's plane JSON as a dict, or a path to such a JSON file.
        axis: with ``"auto"``: the direction from the object towards the cameras.
        grid: with ``"auto"``: cameras ``(nu, nv)``, at most 2048 in all.
        st_res: with ``"auto"``: each camera's image ``(ns, nt)`` in texels.
        light, ambient, specular, unlit, shadows: shading, as :func:`bake_mesh`.
        progress: True prints progress to stderr; a callable gets ``(done, total)``.

    Returns:
        The :class:`LightField` (``kind == "two_plane"``, in memory; :meth:`LightField.save`
        writes it).

    Raises:
        ValueError: invalid planes (the message names the rule), a bad axis, grid or
            resolution. MeshError: invalid mesh. BakeError: the device failed.
    """
    text = None if isinstance(planes, str) and planes == "auto" else _planes_json(planes, "'auto'")
    native = as_mesh(mesh)
    return _bake_two_plane(
        native,
        planes=text,
        axis=tuple(float(x) for x in axis),
        grid=(int(grid[0]), int(grid[1])),
        st_res=(int(st_res[0]), int(st_res[1])),
        light=tuple(light),
        ambient=ambient,
        specular=specular,
        unlit=unlit,
        shadows=shadows,
        progress=_progress_callback(progress),
    )


def import_lightfield(
    path: str | os.PathLike[str],
    *,
    layout: str = "grid",
    planes: Mapping[str, Any] | str | os.PathLike[str] | None = None,
    output: str | os.PathLike[str] | None = None,
) -> LightField:
    """Imports real light-field data as a two-plane light field (docs/two_plane.md).

    Args:
        path: ``layout="grid"``: a folder of PNGs, one per camera, whose names end in their row
            and column (``003_012.png``); ``"stanford"``: the Stanford archive's
            ``out_ROW_COL_*.png``. Both read an optional ``planes.json`` and a depth ``.npy``
            beside each image. ``"lenslet"``: a raw plenoptic image, or its folder, with a
            calibration beside it (``lenslet.json``, or napari-LF's ``metadata.txt``) naming the
            radiometry and dark frames and the optics; the lenslet grid is found, the image
            devignetted and resampled to N x N integer views.
        layout: ``"grid"``, ``"stanford"`` or ``"lenslet"``.
        planes: grid layouts only: DESIGN §9's plane JSON as a dict or a path, instead of the
            folder's ``planes.json`` or the default placement.
        output: write the asset here (atomically) and open it from there; ``None`` keeps it in
            memory (:meth:`LightField.save` writes it).

    Returns:
        The :class:`LightField` (``kind == "two_plane"``).

    Raises:
        FileNotFoundError: ``path`` does not exist. ValueError: a bad layout or planes, a
            malformed grid, images of mixed sizes, a lenslet image without calibration or with
            no lenslet grid (the message names the file and the rule).
    """
    text = None if planes is None else _planes_json(planes, "None")
    if not isinstance(layout, str):
        raise TypeError("layout must be 'grid', 'stanford' or 'lenslet'")
    return _import_lightfield(
        os.fspath(path),
        layout=layout,
        planes=text,
        output=None if output is None else os.fspath(output),
    )


def import_zstack(
    stack: Any,
    *,
    spacing: Sequence[float] | None = None,
    grid: tuple[int, int] = (9, 9),
    angle: float = 15.0,
    composite: str = "mip",
    window: tuple[float, float] | None = None,
    opacity: float = 0.1,
    depth_threshold: float = 0.25,
    output: str | os.PathLike[str] | None = None,
) -> LightField:
    """Synthesises a two-plane light field from a microscope z-stack (docs/zstack.md).

    Cameras on a cone above the stack's middle slice; each camera pixel's ray is composited
    through the slices (``"mip"``: maximum intensity; ``"over"``: emission-absorption) and the
    hit's depth stored, so every two-plane renderer, refocus on a slice (``focus=z``) and the
    paged cache (:meth:`LightField.open` with ``cache_mib``) work on it.

    Args:
        stack: a multi-page TIFF or a folder of 8/16-bit grey slices (a path), or a
            ``uint8``/``uint16`` array of shape ``(nz, ny, nx)`` (slice 0 at the bottom, row 0
            on top), e.g. from ``tifffile`` or ``skimage.io``.
        spacing: voxel spacing ``(sx, sy, sz)`` (the light field's world unit; default: a TIFF's
            ImageJ metadata, else 1, 1, 1).
        grid: cameras per row and rows.
        angle: half-angle of the cameras' cone, degrees (0 < angle <= 60).
        composite: ``"mip"`` or ``"over"``.
        window: grey values mapped to black and white (default: the 0.1 and 99.9 percentiles).
        opacity: ``"over"``: opacity per slice at full intensity, in (0, 1].
        depth_threshold: ``"mip"``: fraction of the window a ray's maximum must reach for its
            depth to be stored (else the middle slice's plane), in [0, 1].
        output: write the asset here (atomically) and open it from there; ``None`` keeps it in
            memory.

    Returns:
        The :class:`LightField` (``kind == "two_plane"``).

    Raises:
        FileNotFoundError: a path that does not exist. TypeError: an array that is not uint8 or
            uint16. ValueError: a bad option, a stack of the wrong shape or size, slices of
            mixed sizes or an unreadable file (the message names it).
    """
    source: Any = stack
    if isinstance(stack, (str, os.PathLike)):
        source = os.fspath(stack)
    return _import_zstack(
        source,
        spacing=None if spacing is None else [float(v) for v in spacing],
        grid=[int(grid[0]), int(grid[1])],
        angle=float(angle),
        composite=composite,
        window=None if window is None else [float(window[0]), float(window[1])],
        opacity=float(opacity),
        depth_threshold=float(depth_threshold),
        output=None if output is None else os.fspath(output),
    )


def bake_animation(
    path: str | os.PathLike[str],
    *,
    animation: str | None = None,
    fps: float = 24.0,
    cameras: int = 162,
    resolution: int = 256,
    light: Sequence[float] = DEFAULT_LIGHT,
    ambient: float = DEFAULT_AMBIENT,
    specular: tuple[float, float] | None = None,
    unlit: bool = False,
    shadows: bool = False,
    depth_bits: int = 16,
    progress: bool | Callable[[int, int], object] = True,
    calibrate: bool = False,
) -> LightField:
    """Bakes a glTF animation into a light field of frames (``lumigraph bake --animation``).

    The animation (``animation`` by name, else the file's first) is sampled every ``1 / fps``
    seconds up to its last key: node translation, rotation and scale (step, linear with slerp,
    cubic-spline keys), morph-target weights and skins pose the scene. Frame 0 is the base state;
    every other frame is a state storing only the pages that differ from it; all share the
    bounding sphere around every frame. ``lf.render(view, time=seconds)`` or ``frame=n`` renders
    a frame. At most 256 frames; on the device each frame that stores pages costs a copy of the
    base state's maps. Other options as :func:`bake_mesh`.

    Raises:
        MeshError: not glTF, no animation or an unknown name, bad keys, a bad fps or too many
            frames. ValueError: an option out of range. BakeError: the device failed.
    """
    callback = _progress_callback(progress)
    return _bake(
        None,
        cameras=cameras,
        resolution=resolution,
        light=tuple(light),
        ambient=ambient,
        specular=specular,
        unlit=unlit,
        depth_bits=depth_bits,
        progress=callback,
        calibrate=calibrate,
        shadows=shadows,
        animation=(os.fspath(path), animation, float(fps)),
    )


def reference_render(
    mesh: MeshLike,
    view: ViewLike,
    *,
    light: Sequence[float] = DEFAULT_LIGHT,
    ambient: float = DEFAULT_AMBIENT,
    specular: tuple[float, float] | None = None,
    unlit: bool = False,
    background: Sequence[int] | None = None,
    shadows: bool = False,
) -> Frame:
    """Rasterizes the mesh itself with the bake's shading: the ground truth for quality numbers.

    Same view convention, shading function and texture sampling as the baker (GIL released).
    Pass ``**lf.shading`` to shade exactly as a light field was baked. For repeated renders of
    one mesh, convert it once with :func:`as_mesh`: a :class:`Mesh` keeps its GPU upload.

    Args:
        mesh: a :class:`Mesh`, ``trimesh.Trimesh``, path, or ``(vertices, faces[, colors])``.
        view: a :class:`View` or a dict with keys eye, target, up, yfov_deg, width, height.
        light, ambient, specular, unlit, shadows: shading, as in :func:`bake_mesh` (with
            ``shadows`` every pixel casts its shadow ray through the mesh).
        background: RGB or RGBA integers 0..255 outside coverage (default transparent black).

    Returns:
        A :class:`Frame` (``stats`` has ``render_ms``; ``steps``/``fetches`` are 0).

    Raises:
        ValueError: a bad view or shading option. RenderError: the device failed.
    """
    return _reference_render(
        as_mesh(mesh),
        view,
        light=tuple(light),
        ambient=ambient,
        specular=specular,
        unlit=unlit,
        background=background,
        shadows=shadows,
    )


def bake_volume(
    volume: np.ndarray[Any, Any] | str | os.PathLike[str],
    *,
    tf: str | Mapping[str, Any] | None = None,
    layers: Sequence[Mapping[str, Any]] | Mapping[str, Any] | str | None = None,
    spacing: Sequence[float] | None = None,
    origin: Sequence[float] | None = None,
    labels: bool = False,
    shade: bool = False,
    step: float | None = None,
    depth_threshold: float = 0.5,
    light: Sequence[float] = DEFAULT_LIGHT,
    ambient: float = DEFAULT_AMBIENT,
    cameras: int = 162,
    resolution: int = 256,
    depth_bits: int | None = None,
    progress: bool | Callable[[int, int], object] = True,
    color_codec: str = "raw",
    depth_codec: str | None = None,
) -> LightField:
    """Bakes a volume into a semi-transparent spherical light field on the GPU (GIL released).

    Every texel of every camera's parabolic map is ray-cast through the volume with the
    sampling, transfer function, compositing and shading of :func:`reference_volume`; the maps
    hold premultiplied RGBA and the depth where the accumulated opacity reached
    ``depth_threshold`` (``docs/volumes.md``, "Volume light fields"). The result renders like
    any :class:`LightField`; its frames carry alpha (``Frame.color[..., 3]``) and depth only
    where the opacity reaches ``depth_threshold``.

    Args:
        volume, tf, spacing, origin, labels, shade, step, depth_threshold, light, ambient: as in
            :func:`reference_volume`.
        layers: instead of ``tf``, a multi light field: a list of
            ``{"name": str, "tf": preset | dict, "opacity": float}`` (opacity, default 1, is the
            layer's default runtime opacity), baked on one camera set; or depth layers, a dict
            ``{"tf": ..., "split": {"opacity": [0.3, 0.7]} | {"value": [...]} | {"labels": n},
            "layers": [{"name": ...}, ...]}`` with one more layer than boundaries: the segments
            of every ray, cut where its accumulated opacity (or scalar value) reaches each
            boundary, or at its first ``n`` transitions between labels.
            Render it with ``LightField.render(view, layers={"skin": 0.3})``: the layers
            composite per pixel in depth order, depth layers in their order along the ray
            (``docs/volumes.md``, "Layers").
        cameras: 12, 42, 162 (default) or 642.
        resolution: side of each camera's parabolic map in pixels, 8..4096, default 256.
        depth_bits: depth precision, 16 (default) or 8.
        progress: True prints "baking cameras k/n" to stderr; a callable gets
            ``(cameras_done, cameras_total)`` (its first exception is raised after the bake);
            False is silent.
        color_codec: ``"raw"`` (default) or ``"bc7"`` (8 bits per texel, alpha kept); the
            colour is premultiplied and semi-transparent, so ``"bc1"`` (1-bit alpha) is refused.
        depth_codec: as in :func:`bake_mesh` (``"r16"``, ``"r8"``, ``"bc4"``).

    Returns:
        The baked :class:`LightField` (in memory; :meth:`LightField.save` writes it).

    Raises:
        FileNotFoundError: no such file. ValueError: a bad array, file, tf, option or codec.
        TypeError: an argument of the wrong type. BakeError: the GPU device failed.
    """
    bits, depth_block = _depth_storage(depth_codec, depth_bits)
    callback = _progress_callback(progress)
    return _bake_volume(
        volume,
        tf=tf,
        layers=layers,
        spacing=None if spacing is None else _triple(spacing, "spacing"),
        origin=None if origin is None else _triple(origin, "origin"),
        labels=labels,
        shade=shade,
        step=step,
        depth_threshold=depth_threshold,
        light=tuple(light),
        ambient=ambient,
        cameras=cameras,
        resolution=resolution,
        depth_bits=bits,
        progress=callback,
        color_codec=color_codec,
        depth_codec=depth_block,
    )


def reference_volume(
    volume: np.ndarray[Any, Any] | str | os.PathLike[str],
    view: ViewLike,
    *,
    tf: str | Mapping[str, Any] | None = None,
    layers: Sequence[Mapping[str, Any]] | Mapping[str, Any] | str | None = None,
    opacities: Mapping[str, float] | None = None,
    spacing: Sequence[float] | None = None,
    origin: Sequence[float] | None = None,
    labels: bool = False,
    shade: bool = False,
    step: float | None = None,
    depth_threshold: float = 0.5,
    light: Sequence[float] = DEFAULT_LIGHT,
    ambient: float = DEFAULT_AMBIENT,
) -> Frame:
    """Ray-casts a volume directly (DESIGN §9): the ground truth for volume light fields.

    Runs on the CPU cores with the GIL released; conventions in ``docs/volumes.md``.

    Args:
        volume: a 3-D array of shape ``(nz, ny, nx)`` (indexed ``[k, j, i]``), or the path of a
            volume file (.nii, .nii.gz, .npy, .mha, .mhd, .nrrd, .nhdr, .inr, .inr.gz, .vti).
        view: a :class:`View` or a dict with keys eye, target, up, yfov_deg, width, height.
        tf: a preset (``"ct-bone"``, ``"ct-skin"``, ``"mri-brain"``), or a transfer function as a
            dict or JSON string: ``{"points": [[value, r, g, b, a], ...], "ref_step": L}`` or
            ``{"labels": {"LABEL": [r, g, b, a]}}``.
        spacing: voxel spacing (x, y, z) of an array or a .npy file (default 1, 1, 1).
        origin: world position of voxel (0, 0, 0) of an array (default 0, 0, 0).
        labels: integer labels (nearest-voxel sampling, a label ``tf``).
        shade: gradient shading with ``light`` and ``ambient`` (scalar volumes only).
        step: sample spacing along rays, world units (default half the tf's reference step).
        depth_threshold: accumulated opacity that places the depth, in (0, 1].
        layers: instead of ``tf``, layers as :func:`bake_volume` takes them: each is ray-cast
            with its tf (depth layers: its segment) and the layers composite per pixel in depth
            order (depth layers: in ray order), as a baked multi light field renders.
        opacities: with ``layers``, runtime opacities by layer name (others keep theirs).

    Returns:
        A :class:`Frame`: straight colour with alpha ``round(255·A)``; ``depth`` is ``inf``
        where the opacity never reached ``depth_threshold``, so coverage (alpha ≥ 1) is read
        from the alpha channel, not from depth.

    Raises:
        FileNotFoundError: no such file. ValueError: a bad array, file, tf or option (NaN
        voxels, negative labels, a singular transform, a label tf on a scalar volume, ...).
    """
    return _reference_volume(
        volume,
        view,
        tf=tf,
        layers=layers,
        opacities=None if opacities is None else {str(k): float(v) for k, v in opacities.items()},
        spacing=None if spacing is None else _triple(spacing, "spacing"),
        origin=None if origin is None else _triple(origin, "origin"),
        labels=labels,
        shade=shade,
        step=step,
        depth_threshold=depth_threshold,
        light=tuple(light),
        ambient=ambient,
    )


def _triple(values: Sequence[float], name: str) -> tuple[float, float, float]:
    items = [float(v) for v in values]
    if len(items) != 3:
        raise ValueError(f"{name} needs 3 numbers (x, y, z), got {len(items)}")
    return (items[0], items[1], items[2])
