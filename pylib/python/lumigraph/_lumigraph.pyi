# Type stubs of the native module (pylib/src); checked against it by mypy.stubtest.
from collections.abc import Callable, Iterable, Mapping, Sequence
from os import PathLike
from typing import Any, Literal, TypedDict, Unpack, final

import numpy as np
import numpy.typing as npt

__version__: str
__all__ = [
    "AssetError", "BakeError", "Frame", "LightField", "LumigraphError", "Mesh", "MeshError",
    "RenderError", "View", "bake", "bake_two_plane", "bake_volume", "compare", "depth_error", "device_info", "import_lightfield", "import_zstack", "mae", "masked_psnr",
    "orbit_views", "psnr", "reference_render", "reference_volume", "ssim", "__version__",
]

_ViewLike = View | Mapping[str, Any]

class _Quality(TypedDict, total=False):
    """The quality request (core ``Quality``): the keys of the HTTP render body and the CLI flags."""

    lod: int | None
    step: float | None
    tolerance: float | None
    method: str | None
    guide: int | None
    target_psnr: float | None
    budget_ms: float | None
    auto_lod: float | None
    lod_min_psnr: float | None
    lod_max_psnr_drop: float | None
    lod_blend: float | None
    refine: int | None
    layers: Mapping[str, float] | str | None
    light: Sequence[float] | None
    state: str | None
    time: float | None
    frame: int | None
    # Two-plane light fields (``lf.kind == "two_plane"``) take these instead (tolerance in
    # world units there): docs/two_plane.md.
    uv_filter: str | None
    focus: float | None
    aperture: float | None
    steps: int | None
    dither_amplitude: float | None
    sample_budget: int | None
    frame_index: int | None

_Image = Frame | npt.ArrayLike

class LumigraphError(Exception): ...
class AssetError(LumigraphError): ...
class BakeError(LumigraphError): ...
class RenderError(LumigraphError): ...
class MeshError(ValueError): ...

@final
class View:
    def __new__(
        cls,
        *,
        eye: Sequence[float],
        target: Sequence[float],
        up: Sequence[float] = ...,
        yfov_deg: float,
        width: int,
        height: int,
    ) -> View: ...
    @staticmethod
    def from_dict(d: Mapping[str, Any]) -> View: ...
    @staticmethod
    def from_json(text: str) -> View: ...
    def to_dict(self) -> dict[str, Any]: ...
    def to_json(self) -> str: ...
    def ray_directions(self) -> npt.NDArray[np.float64]: ...
    @property
    def forward(self) -> tuple[float, float, float]: ...
    @property
    def eye(self) -> tuple[float, float, float]: ...
    @property
    def target(self) -> tuple[float, float, float]: ...
    @property
    def up(self) -> tuple[float, float, float]: ...
    @property
    def yfov_deg(self) -> float: ...
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    def __eq__(self, value: object, /) -> bool: ...
    def __ne__(self, value: object, /) -> bool: ...
    __hash__: None  # type: ignore[assignment]

@final
class Mesh:
    def __new__(
        cls,
        vertices: npt.ArrayLike,
        faces: npt.ArrayLike,
        colors: npt.ArrayLike | None = None,
        *,
        normals: npt.ArrayLike | None = None,
        uvs: npt.ArrayLike | None = None,
        texture: npt.ArrayLike | None = None,
        base_color: Sequence[float] | None = None,
        name: str = ...,
    ) -> Mesh: ...
    @staticmethod
    def load(path: str | PathLike[str]) -> Mesh: ...
    @staticmethod
    def demo() -> Mesh: ...
    @property
    def vertices(self) -> npt.NDArray[np.float32]: ...
    @property
    def faces(self) -> npt.NDArray[np.uint32]: ...
    @property
    def vertex_count(self) -> int: ...
    @property
    def triangle_count(self) -> int: ...
    @property
    def bounding_sphere(self) -> tuple[tuple[float, float, float], float]: ...
    @property
    def name(self) -> str: ...

@final
class Frame:
    @property
    def color(self) -> npt.NDArray[np.uint8]: ...
    @property
    def depth(self) -> npt.NDArray[np.float32]: ...
    @property
    def coverage(self) -> npt.NDArray[np.bool_]: ...
    @property
    def stats(self) -> dict[str, Any]: ...
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def covered_px(self) -> int: ...

@final
class LightField:
    @staticmethod
    def open(
        path: str | PathLike[str],
        *,
        cache_mib: float | None = None,
        prefetch: Literal["none", "lru", "predict"] | None = None,
        pages_per_frame: int | None = None,
    ) -> LightField: ...
    @property
    def page_stats(self) -> dict[str, Any] | None: ...
    @staticmethod
    def from_bytes(data: bytes) -> LightField: ...
    def to_bytes(self) -> bytes: ...
    def save(self, path: str | PathLike[str]) -> None: ...
    def verify(self) -> None: ...
    @property
    def info(self) -> dict[str, Any]: ...
    @property
    def deformations(self) -> list[dict[str, Any]]: ...
    @property
    def kind(self) -> str: ...
    @property
    def planes(self) -> dict[str, Any] | None: ...
    @property
    def cameras(self) -> int: ...
    @property
    def resolution(self) -> int: ...
    @property
    def bounding_sphere(self) -> tuple[tuple[float, float, float], float]: ...
    @property
    def shading(self) -> dict[str, Any]: ...
    def render(
        self,
        view: _ViewLike,
        *,
        background: Sequence[int] | None = None,
        **quality: Unpack[_Quality],
    ) -> Frame: ...
    def render_many(
        self,
        views: Iterable[_ViewLike],
        *,
        background: Sequence[int] | None = None,
        **quality: Unpack[_Quality],
    ) -> list[Frame]: ...
    def choose(
        self,
        view: _ViewLike,
        *,
        target_psnr: float | None = None,
        budget_ms: float | None = None,
    ) -> dict[str, Any]: ...
    def choose_lod(
        self,
        view: _ViewLike,
        *,
        auto_lod: float = 1.0,
        lod_min_psnr: float | None = None,
        lod_max_psnr_drop: float | None = None,
        lod_blend: float | None = None,
        lod: int | None = None,
        step: float | None = None,
        tolerance: float | None = None,
        guide: int | None = None,
    ) -> dict[str, Any]: ...

def orbit_views(
    center: Sequence[float],
    distance: float,
    n: int,
    *,
    seed: int = 0,
    yfov_deg: float = 40.0,
    size: int = 256,
) -> list[View]: ...
def bake(
    mesh: Mesh | None,
    *,
    cameras: int,
    resolution: int,
    light: Sequence[float],
    ambient: float,
    specular: tuple[float, float] | None,
    unlit: bool,
    depth_bits: int,
    progress: Callable[[int, int], object] | None,
    calibrate: bool = False,
    auto: bool = False,
    target_psnr: float | None = None,
    max_bytes: int | None = None,
    shadows: bool = False,
    lights: int | None = None,
    states: Sequence[tuple[str, Mesh]] | None = None,
    animation: tuple[str, str | None, float] | None = None,
    color_codec: str | None = None,
    depth_codec: str | None = None,
) -> LightField: ...
def bake_two_plane(
    mesh: Mesh,
    *,
    planes: str | None,
    axis: Sequence[float],
    grid: Sequence[int],
    st_res: Sequence[int],
    light: Sequence[float],
    ambient: float,
    specular: tuple[float, float] | None,
    unlit: bool,
    shadows: bool,
    progress: Callable[[int, int], object] | None,
) -> LightField: ...
def import_lightfield(
    path: str | PathLike[str],
    *,
    layout: str,
    planes: str | None,
    output: str | PathLike[str] | None,
) -> LightField: ...
def import_zstack(
    stack: npt.ArrayLike | str | PathLike[str],
    *,
    spacing: Sequence[float] | None,
    grid: Sequence[int],
    angle: float,
    composite: str,
    window: Sequence[float] | None,
    opacity: float,
    depth_threshold: float,
    output: str | PathLike[str] | None,
) -> LightField: ...
def reference_render(
    mesh: Mesh,
    view: _ViewLike,
    *,
    light: Sequence[float],
    ambient: float,
    specular: tuple[float, float] | None,
    unlit: bool,
    background: Sequence[int] | None,
    shadows: bool = False,
) -> Frame: ...
def reference_volume(
    volume: npt.ArrayLike | str | PathLike[str],
    view: _ViewLike,
    *,
    tf: str | Mapping[str, Any] | None,
    layers: Sequence[Mapping[str, Any]] | Mapping[str, Any] | str | None,
    opacities: Mapping[str, float] | None,
    spacing: tuple[float, float, float] | None,
    origin: tuple[float, float, float] | None,
    labels: bool,
    shade: bool,
    step: float | None,
    depth_threshold: float,
    light: Sequence[float],
    ambient: float,
) -> Frame: ...
def bake_volume(
    volume: npt.ArrayLike | str | PathLike[str],
    *,
    tf: str | Mapping[str, Any] | None,
    layers: Sequence[Mapping[str, Any]] | Mapping[str, Any] | str | None,
    spacing: tuple[float, float, float] | None,
    origin: tuple[float, float, float] | None,
    labels: bool,
    shade: bool,
    step: float | None,
    depth_threshold: float,
    light: Sequence[float],
    ambient: float,
    cameras: int,
    resolution: int,
    depth_bits: int,
    progress: Callable[[int, int], object] | None,
    color_codec: str | None = None,
    depth_codec: str | None = None,
) -> LightField: ...
def device_info() -> str: ...
def psnr(a: _Image, b: _Image, *, mask: npt.ArrayLike | None = None) -> float: ...
def masked_psnr(
    test: _Image,
    reference: _Image,
    *,
    test_coverage: npt.ArrayLike | None = None,
    reference_coverage: npt.ArrayLike | None = None,
) -> float: ...
def ssim(a: _Image, b: _Image) -> float: ...
def mae(a: _Image, b: _Image) -> float: ...
def depth_error(test: Frame | npt.ArrayLike, reference: Frame | npt.ArrayLike) -> dict[str, float]: ...
def compare(test: Frame, reference: Frame) -> dict[str, Any]: ...
