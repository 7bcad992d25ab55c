"""Hypothesis properties: view parsing (dict / JSON / View round trips, rejection of bad fields,
pixel rays = DESIGN §3) and asset round trips (save/open, bytes, corruption never crashes)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import lumigraph as lg

finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
vec3 = st.tuples(finite, finite, finite)


@st.composite
def view_dicts(draw: st.DrawFn) -> dict:
    eye = draw(vec3)
    target = draw(vec3)
    up = draw(vec3)
    delta = np.subtract(target, eye)
    assume(np.linalg.norm(delta) > 1e-3 * max(1.0, np.abs(eye).max(), np.abs(target).max()))
    fwd = delta / np.linalg.norm(delta)
    assume(np.linalg.norm(up) > 1e-6)
    assume(np.linalg.norm(np.cross(fwd, np.asarray(up) / np.linalg.norm(up))) > 1e-3)
    return {
        "eye": list(eye),
        "target": list(target),
        "up": list(up),
        "yfov_deg": draw(st.floats(0.5, 179.0)),
        "width": draw(st.integers(1, 8192)),
        "height": draw(st.integers(1, 8192)),
    }


@settings(max_examples=150, deadline=None)
@given(view_dicts())
def test_view_dict_json_and_object_round_trip(d: dict) -> None:
    view = lg.View.from_dict(d)
    assert lg.View(**d) == view
    assert lg.View.from_json(json.dumps(d)) == view
    assert lg.View.from_json(view.to_json()) == view
    assert lg.View.from_dict(view.to_dict()) == view
    back = view.to_dict()
    assert back["eye"] == tuple(d["eye"]) and back["width"] == d["width"]
    # `up` is optional and defaults to +y.
    no_up = {k: v for k, v in d.items() if k != "up"}
    try:
        assert lg.View.from_dict(no_up).up == (0.0, 1.0, 0.0)
    except ValueError as e:  # +y parallel to this view direction
        assert "up" in str(e)


@settings(max_examples=60, deadline=None)
@given(view_dicts(), st.sampled_from(["eye", "target", "up", "yfov_deg"]), st.sampled_from([math.nan, math.inf, -math.inf]))
def test_non_finite_view_fields_are_rejected(d: dict, key: str, bad: float) -> None:
    if key == "yfov_deg":
        d[key] = bad
    else:
        d[key] = [d[key][0], bad, d[key][2]]
    with pytest.raises(ValueError, match=key):
        lg.View.from_dict(d)


@settings(max_examples=60, deadline=None)
@given(view_dicts(), st.sampled_from(["eye", "target", "yfov_deg", "width", "height"]))
def test_missing_view_fields_are_rejected(d: dict, key: str) -> None:
    del d[key]
    with pytest.raises(ValueError, match=f"missing the field `{key}`"):
        lg.View.from_dict(d)


@settings(max_examples=60, deadline=None)
@given(view_dicts(), st.text(min_size=1, max_size=8).filter(
    lambda k: k not in {"eye", "target", "up", "yfov_deg", "width", "height"}))
def test_unknown_view_fields_are_rejected(d: dict, key: str) -> None:
    d[key] = 1
    with pytest.raises(ValueError, match="unknown view field"):
        lg.View.from_dict(d)
    with pytest.raises(ValueError, match="unknown view field"):
        lg.View.from_json(json.dumps(d))


@settings(max_examples=40, deadline=None)
@given(view_dicts().map(lambda d: {**d, "width": d["width"] % 24 + 1, "height": d["height"] % 24 + 1}))
def test_ray_directions_follow_design_section_3(d: dict) -> None:
    view = lg.View.from_dict(d)
    eye, target, up = (np.asarray(d[k], float) for k in ("eye", "target", "up"))
    fwd = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(fwd, up / np.linalg.norm(up))
    right /= np.linalg.norm(right)
    true_up = np.cross(right, fwd)
    h, w = d["height"], d["width"]
    f = (h / 2) / np.tan(np.radians(d["yfov_deg"]) / 2)
    j, i = np.meshgrid(np.arange(w), np.arange(h))
    dirs = ((j + 0.5 - w / 2) / f)[..., None] * right + (-(i + 0.5 - h / 2) / f)[..., None] * true_up + fwd
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    np.testing.assert_allclose(view.ray_directions(), dirs, atol=1e-9)
    np.testing.assert_allclose(view.forward, fwd, atol=1e-12)


@pytest.fixture(scope="module")
def tiny_lf() -> lg.LightField:
    return lg.bake_mesh(lg.Mesh.demo(), cameras=12, resolution=16, depth_bits=8, progress=False)


TINY_VIEW = {"eye": [0, 0.4, 3.5], "target": [0, 0, 0], "yfov_deg": 45, "width": 24, "height": 24}


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(name=st.text(st.characters(codec="utf-8", exclude_characters="/\\\0"), min_size=1, max_size=20).filter(
    lambda s: s not in {".", ".."} and not s.startswith(".")))
def test_save_open_round_trip_any_file_name(tiny_lf: lg.LightField, tmp_path: Path, name: str) -> None:
    path = tmp_path / name
    tiny_lf.save(path)
    opened = lg.LightField.open(path)
    assert opened.info == tiny_lf.info
    assert opened.to_bytes() == tiny_lf.to_bytes()
    a, b = tiny_lf.render(TINY_VIEW), opened.render(TINY_VIEW)
    np.testing.assert_array_equal(a.color, b.color)
    np.testing.assert_array_equal(a.depth, b.depth)


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_corrupted_assets_raise_asset_error_or_render_unchanged(tiny_lf: lg.LightField, data: st.DataObject) -> None:
    good = tiny_lf.to_bytes()
    blob = bytearray(good)
    offset = data.draw(st.integers(0, len(blob) - 1), label="offset")
    blob[offset] ^= data.draw(st.integers(1, 255), label="xor")
    cut = data.draw(st.one_of(st.none(), st.integers(0, len(blob))), label="truncate")
    if cut is not None:
        blob = blob[:cut]
    try:
        lf = lg.LightField.from_bytes(bytes(blob))
        lf.verify()
        frame = lf.render(TINY_VIEW)
    except lg.AssetError as e:
        assert str(e)
        return
    # Only bytes no checksum covers (e.g. padding) may change without an error, and then the
    # render is unchanged.
    np.testing.assert_array_equal(frame.color, tiny_lf.render(TINY_VIEW).color)


@settings(max_examples=20, deadline=None)
@given(st.binary(max_size=200))
def test_random_bytes_are_not_an_asset(tiny_lf: lg.LightField, blob: bytes) -> None:
    with pytest.raises(lg.AssetError):
        lg.LightField.from_bytes(blob)
