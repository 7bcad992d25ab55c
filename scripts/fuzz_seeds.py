"""Writes the seed corpora of the fuzz targets (fuzz/fuzz_targets/) into one folder per target.

Seeds are small valid inputs of every kind each parser takes, so that libFuzzer starts from the
formats' real structure: meshes generated here in every format and variant the loaders read
(OBJ, ASCII/binary PLY, ASCII/binary STL, OFF/COFF, glTF with a data URI and GLB), the real
fixture meshes (`scripts/fixtures.sh`; libFuzzer truncates them to its `-max_len`), `.lfa`
assets baked by `lumigraph bake` (raw and zstd pages, 8- and 16-bit depth, with and without a
calibration), and the JSON documents of docs/ (views and view lists, scenes, render bodies,
stream messages).

Usage: python3 scripts/fuzz_seeds.py OUT_DIR [--bin LUMIGRAPH] [--fixtures DIR]
"""

from __future__ import annotations

import argparse
import base64
import gzip
import json
import struct
import subprocess
import tempfile
from pathlib import Path

# An octahedron: the smallest closed mesh with distinct normals per face.
VERTICES: list[tuple[float, float, float]] = [
    (1.0, 0.0, 0.0),
    (-1.0, 0.0, 0.0),
    (0.0, 1.0, 0.0),
    (0.0, -1.0, 0.0),
    (0.0, 0.0, 1.0),
    (0.0, 0.0, -1.0),
]
FACES: list[tuple[int, int, int]] = [
    (0, 2, 4),
    (2, 1, 4),
    (1, 3, 4),
    (3, 0, 4),
    (2, 0, 5),
    (1, 2, 5),
    (3, 1, 5),
    (0, 3, 5),
]


def obj() -> bytes:
    lines = ["# octahedron", "o octa"]
    lines += [f"v {x} {y} {z}" for x, y, z in VERTICES]
    lines += ["vn 0 0 1", "vt 0.5 0.5"]
    lines += [f"f {a + 1}/1/1 {b + 1}/1/1 {c + 1}/1/1" for a, b, c in FACES]
    lines += ["f 1 2 3 4"]
    return ("\n".join(lines) + "\n").encode()


def ply_ascii() -> bytes:
    head = [
        "ply",
        "format ascii 1.0",
        f"element vertex {len(VERTICES)}",
        "property float x",
        "property float y",
        "property float z",
        "property uchar red",
        "property uchar green",
        "property uchar blue",
        f"element face {len(FACES)}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    body = [f"{x} {y} {z} 200 100 50" for x, y, z in VERTICES]
    body += [f"3 {a} {b} {c}" for a, b, c in FACES]
    return ("\n".join(head + body) + "\n").encode()


def ply_binary() -> bytes:
    head = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(VERTICES)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        f"element face {len(FACES)}\n"
        "property list uchar uint vertex_indices\nend_header\n"
    ).encode()
    body = b"".join(struct.pack("<3f", *v) for v in VERTICES)
    body += b"".join(struct.pack("<B3I", 3, *f) for f in FACES)
    return head + body


def stl_ascii() -> bytes:
    out = ["solid octa"]
    for face in FACES:
        out.append("facet normal 0 0 0")
        out.append("outer loop")
        out += [f"vertex {' '.join(str(c) for c in VERTICES[i])}" for i in face]
        out.append("endloop")
        out.append("endfacet")
    out.append("endsolid octa")
    return ("\n".join(out) + "\n").encode()


def stl_binary() -> bytes:
    out = b"octa".ljust(80, b" ") + struct.pack("<I", len(FACES))
    for face in FACES:
        out += struct.pack("<3f", 0.0, 0.0, 0.0)
        for i in face:
            out += struct.pack("<3f", *VERTICES[i])
        out += struct.pack("<H", 0)
    return out


def off(coloured: bool) -> bytes:
    lines = ["COFF" if coloured else "OFF", f"{len(VERTICES)} {len(FACES)} 0"]
    colour = " 255 128 0 255" if coloured else ""
    lines += [f"{x} {y} {z}{colour}" for x, y, z in VERTICES]
    lines += [f"3 {a} {b} {c}" for a, b, c in FACES]
    return ("\n".join(lines) + "\n").encode()


def gltf_parts() -> tuple[dict[str, object], bytes]:
    positions = b"".join(struct.pack("<3f", *v) for v in VERTICES)
    indices = b"".join(struct.pack("<3H", *f) for f in FACES)
    buffer = positions + indices
    doc: dict[str, object] = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "translation": [0.0, 0.0, 0.0]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.3, 0.2, 1.0]}}],
        "accessors": [
            {
                "bufferView": 0,
                "componentType": 5126,
                "count": len(VERTICES),
                "type": "VEC3",
                "min": [-1.0, -1.0, -1.0],
                "max": [1.0, 1.0, 1.0],
            },
            {"bufferView": 1, "componentType": 5123, "count": 3 * len(FACES), "type": "SCALAR"},
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": len(positions)},
            {"buffer": 0, "byteOffset": len(positions), "byteLength": len(indices)},
        ],
        "buffers": [{"byteLength": len(buffer)}],
    }
    return doc, buffer


def gltf() -> bytes:
    doc, buffer = gltf_parts()
    buffers = doc["buffers"]
    assert isinstance(buffers, list)
    buffers[0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(buffer).decode()
    return json.dumps(doc).encode()


def glb() -> bytes:
    doc, buffer = gltf_parts()
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    buffer += b"\0" * (-len(buffer) % 4)
    chunks = struct.pack("<I4s", len(text), b"JSON") + text
    chunks += struct.pack("<I4s", len(buffer), b"BIN\0") + buffer
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


VIEW = {"eye": [0.0, 0.0, 3.0], "target": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0], "yfov_deg": 40.0, "width": 64, "height": 48}


def volumes() -> dict[str, bytes]:
    """One small volume per reader, prefixed with the target's format byte (fuzz_targets/volume.rs)."""
    ramp = bytes(range(12))
    nii = bytearray(352)
    struct.pack_into("<i", nii, 0, 348)
    struct.pack_into("<8h", nii, 40, 3, 3, 2, 2, 1, 1, 1, 1)
    struct.pack_into("<hh", nii, 70, 2, 8)
    struct.pack_into("<8f", nii, 76, 1, 1, 1, 1, 1, 0, 0, 0)
    struct.pack_into("<f", nii, 108, 352.0)
    nii[344:348] = b"n+1\0"
    nii_file = bytes(nii) + ramp
    npy_header = b"{'descr': '|u1', 'fortran_order': False, 'shape': (2, 2, 3), }"
    npy_header += b" " * (63 - (10 + len(npy_header)) % 64) + b"\n"
    npy_file = b"\x93NUMPY\x01\x00" + struct.pack("<H", len(npy_header)) + npy_header + ramp
    mha = b"NDims = 3\nDimSize = 3 2 2\nElementType = MET_UCHAR\nElementSpacing = 1 1 1\nElementDataFile = LOCAL\n"
    nrrd = b"NRRD0004\ntype: uchar\ndimension: 3\nsizes: 3 2 2\nencoding: raw\nspacings: 1 1 1\n\n"
    inr = b"#INRIMAGE-4#{\nXDIM=3\nYDIM=2\nZDIM=2\nVDIM=1\nTYPE=unsigned fixed\nPIXSIZE=8 bits\nCPU=decm\n"
    inr += b"\n" * (252 - len(inr)) + b"##}\n"
    vti = (
        b'<VTKFile type="ImageData" byte_order="LittleEndian"><ImageData WholeExtent="0 2 0 1 0 1" '
        b'Spacing="1 1 1"><Piece Extent="0 2 0 1 0 1"><PointData Scalars="v"><DataArray type="UInt8" '
        b'Name="v" format="appended" offset="0"/></PointData></Piece></ImageData>'
        b'<AppendedData encoding="raw">_' + struct.pack("<I", 12) + ramp + b"</AppendedData></VTKFile>"
    )
    return {
        "nifti.nii": b"\x00" + nii_file,
        "nifti.nii.gz": b"\x01" + gzip.compress(nii_file),
        "plain.npy": b"\x02" + npy_file,
        "local.mha": b"\x03" + mha + ramp,
        "raw.nrrd": b"\x04" + nrrd + ramp,
        "plain.inr": b"\x05" + inr + ramp,
        "plain.inr.gz": b"\x06" + gzip.compress(inr + ramp),
        "labels.npy": b"\x82" + npy_file,  # 130 % 8 = 2: .npy, as labels
        "appended.vti": b"\x07" + vti,
    }


def json_seeds() -> dict[str, list[object]]:
    grazing = dict(VIEW, eye=[1.0, 0.0, 0.0], up=[0.0, 0.0, 1.0])
    return {
        "view_json": [VIEW, [VIEW, grazing], [VIEW] * 3],
        "scene_json": [
            {"objects": [{"type": "lightfield", "asset": "a.lfa"}]},
            {
                "objects": [
                    {"type": "lightfield", "asset": "a.lfa"},
                    {
                        "type": "lightfield",
                        "asset": "a.lfa",
                        "transform": {"translation": [0.3, 0, 0], "rotation": {"axis": [0, 1, 0], "degrees": 90}, "scale": 0.5},
                        "options": {"lod": 42, "step": 0.0625, "method": "default"},
                        "auto_lod": {"max_error_px": 1.0},
                    },
                    {"type": "mesh", "mesh": "floor.obj", "shading": {"unlit": True}},
                ]
            },
        ],
        "render_request": [
            {"view": VIEW},
            {"view": VIEW, "format": "jpeg", "quality": 80, "depth": "png16", "lod": 42, "step": 0.0625},
            {"view": VIEW, "format": "none", "depth": "npy", "background": [0, 0, 0, 255], "target_psnr": 30},
            {"view": VIEW, "auto_lod": 1.0, "lod_min_psnr": 30, "lod_blend": 0.2, "method": "fixed", "refine": 4},
            {"view": VIEW, "budget_ms": 20, "tolerance": 0.01, "guide": 8},
        ],
        "stream_message": [
            {"type": "view", "id": 1, "view": VIEW},
            {"type": "view", "id": 2, "view": VIEW, "still": True},
            {"type": "ack", "frame": 3},
            {"type": "ack", "frame": 4, "received_ms": 1234.5},
            {"type": "settings", "still_codec": "png", "interactive": True, "interactive_scale": 0.5, "target_fps": 30},
            {"type": "settings", "interactive_codec": "webp", "interactive_quality": 60, "lod": 42, "rest_ms": 100},
            {"type": "settings", "layers": {"base": 0.5}, "background": [1, 2, 3, 4], "max_in_flight": 2},
        ],
    }


def bake_assets(binary: Path, out: Path, fixtures: Path | None) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        mesh = Path(tmp) / "octa.obj"
        mesh.write_bytes(obj())
        runs = [
            ["--demo", "--cameras", "12", "--resolution", "64", "--no-calibrate"],
            [str(mesh), "--cameras", "12", "--resolution", "64", "--depth-bits", "8", "--no-calibrate"],
            [str(mesh), "--cameras", "12", "--resolution", "64"],
        ]
        for i, args in enumerate(runs):
            target = out / f"baked-{i}.lfa"
            subprocess.run([str(binary), "bake", *args, "-o", str(target)], check=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path)
    parser.add_argument("--bin", type=Path, help="lumigraph binary for the .lfa seeds")
    parser.add_argument("--fixtures", type=Path, help="fixture folder (scripts/fixtures.sh)")
    args = parser.parse_args()
    seeds: dict[str, dict[str, bytes]] = {
        "mesh_obj": {"octa.obj": obj()},
        "mesh_ply": {"ascii.ply": ply_ascii(), "binary.ply": ply_binary()},
        "mesh_stl": {"ascii.stl": stl_ascii(), "binary.stl": stl_binary()},
        "mesh_off": {"plain.off": off(False), "colour.off": off(True)},
        "mesh_gltf": {"embedded.gltf": gltf(), "binary.glb": glb()},
        "volume": volumes(),
    }
    for target, docs in json_seeds().items():
        seeds[target] = {f"{i}.json": json.dumps(doc).encode() for i, doc in enumerate(docs)}
    if args.fixtures is not None and (args.fixtures / "mesh").is_dir():
        for path in sorted((args.fixtures / "mesh").iterdir()):
            target = {".off": "mesh_off", ".ply": "mesh_ply", ".obj": "mesh_obj", ".stl": "mesh_stl"}.get(path.suffix)
            if target is not None:
                seeds[target][f"fixture-{path.name}"] = path.read_bytes()
    if args.fixtures is not None and (args.fixtures / "volume/mni_t1.nii.gz").is_file():
        seeds["volume"]["fixture-mni_t1.nii.gz"] = b"\x01" + (args.fixtures / "volume/mni_t1.nii.gz").read_bytes()
    for target, files in seeds.items():
        folder = args.out / target
        folder.mkdir(parents=True, exist_ok=True)
        for name, data in files.items():
            (folder / f"seed-{name}").write_bytes(data)
    lfa = args.out / "lfa_reader"
    lfa.mkdir(parents=True, exist_ok=True)
    if args.bin is not None:
        bake_assets(args.bin, lfa, args.fixtures)
    counts = ", ".join(f"{t} {len(list((args.out / t).iterdir()))}" for t in sorted([*seeds, "lfa_reader"]))
    print(f"seed corpora in {args.out}: {counts}")


if __name__ == "__main__":
    main()
