#!/usr/bin/env bash
# Fetches the real-mesh test fixtures into DIR (default: fixtures/ in the repository root), taken
# out of pinned registry packages so that the bytes never change:
#   mesh/bunny00.off  Stanford bunny, closed, 75k triangles  (Debian libcgal-demo 5.5.1-2, CGAL data)
#   mesh/cow.off      cow, 5.8k triangles                     (same package)
#   mesh/spot.ply     Spot the cow, 5.9k triangles, closed    (PyPI robust-laplacian 1.1.0 sdist, MIT)
#   volume/mni_t1.nii.gz  MNI152 T1 MRI template, 197×233×189 uint8 NIfTI-1 (PyPI nilearn 0.14.1
#                     wheel, BSD-3)
#   lightfield/GUVExperim1/  a raw lenslet light-field microscope image (436×436, 16-bit TIFF) with
#                     its dark frame, radiometry frame and napari-LF metadata (PyPI napari-lf 0.1.7
#                     wheel, BSD-3)
# Every file's SHA-256 is checked before it is moved into DIR (one rename per file), and
# DIR/.fetch-complete is written last: a run that finds the files there and intact only writes the
# marker. Needs apt-get download (the package lists are refreshed when the pinned version is not in
# them), pip (a temporary virtual environment when $PIP does not work), tar, dpkg-deb, sha256sum.
# About 20 s and 50 MB downloaded (7 MB kept).
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
source "$ROOT/scripts/common.sh"
DIR=${1:-$ROOT/fixtures}
SUMS='ab651cb04955c161efaeb079035a1e5e1f0e0d1f816a2df67beaea68f393ff2b  mesh/bunny00.off
1c5a25c3047fc6b14dd0c962d3562b1796671422ab4634f9d46f9f23814cd54a  mesh/cow.off
2d24cc184dec9a03c32281312f7d2e44f70b51180d982dc0a81899e77efc275a  mesh/spot.ply
421a10e872fd6cadae7f61d358dffbcc1795a497d61ee76c5dda2503e1a1e9e6  volume/mni_t1.nii.gz
0b910ed4b52fd9fbb565911fc7f9f285edb0f30fa4913a93143466d439d1092e  anim/AnimatedMorphCube.gltf
4aba93918adba56c1cc688a38c527bc647e26f2c386802e119b4d01b7250dd23  anim/AnimatedMorphCube.bin
2ccb43a4a0a8d2663088684b53e254358308f48e3f4bcafa999e5b5898e2e0fa  anim/simple_skin.gltf
8d0fdffcf9bd72ba2a3f2d2b930409e0c845f2fa2062b6c26502c89f3cd91723  lightfield/GUVExperim1/Lightfield_GUVExperim1.tif
f6490e8f63407891c7665e5e47715562ce7c6cc37e03baadfe6cffb80a49a9e9  lightfield/GUVExperim1/DarkFrame_GUVExperim1.tif
26496eebbae03fe3ad5208d8f6c3b20f7b135107db4798a5c856f687822c83fc  lightfield/GUVExperim1/Radiometry_GUVExperim1.tif
46d17e52b1d2218c89334fbe13164557cedeed106ae01f7b348b039f34467878  lightfield/GUVExperim1/metadata.txt'
CGAL_DEB=libcgal-demo=5.5.1-2
ASSIMP_DEB=assimp-testmodels=5.2.5~ds0-1
SPOT_SDIST='robust-laplacian==1.1.0 --hash=sha256:1db9eeb1a7aa340c3da902b125d2f58c7138feda206a72c2402dd25e702290d2'
NILEARN_WHEEL='nilearn==0.14.1 --hash=sha256:725206484e9fb3f6691f9c2d20204a068759d5072f12055324702ee0cb2bbe8a'
NAPARI_LF_WHEEL='napari-lf==0.1.7 --hash=sha256:c7a9115ef4c0c9658997059150d69fe73adfd8c3cc54eb337294ca5053c960a9'

mkdir -p "$DIR"
DIR=$(cd "$DIR" && pwd)  # the steps below change directory
if (cd "$DIR" && sha256sum -c --quiet --status <<<"$SUMS") 2>/dev/null; then
  touch "$DIR/.fetch-complete"
  echo "fixtures ready in $DIR"
  exit 0
fi
rm -f "$DIR/.fetch-complete"
# Staged inside DIR, so that moving a checked file in is a rename on the same file system.
STAGE=$(mktemp -d "$DIR/.stage.XXXXXX")
trap 'rm -rf "$STAGE"' EXIT
mkdir -p "$STAGE/mesh" "$STAGE/volume" "$STAGE/anim" "$STAGE/lightfield/GUVExperim1"

# bunny and cow: CGAL's demo data, a tarball inside the Debian package.
chmod 755 "$STAGE"  # apt-get download runs as the _apt user where it can
if ! (cd "$STAGE" && apt-get download -q "$CGAL_DEB" >"$STAGE/apt.log" 2>&1); then
  as_root apt-get update -qq
  (cd "$STAGE" && apt-get download -q "$CGAL_DEB" >"$STAGE/apt.log" 2>&1) || { cat "$STAGE/apt.log" >&2; exit 1; }
fi
dpkg-deb --fsys-tarfile "$STAGE"/libcgal-demo_*.deb | tar -xO ./usr/share/doc/libcgal-dev/data.tar.gz \
  | tar -xz -C "$STAGE" data/meshes/bunny00.off data/meshes/cow.off
mv "$STAGE"/data/meshes/bunny00.off "$STAGE"/data/meshes/cow.off "$STAGE/mesh/"

# animated glTF: a morph-target cube and a simple skin, glTF samples in assimp's test models.
(cd "$STAGE" && apt-get download -q "$ASSIMP_DEB" >"$STAGE/apt.log" 2>&1) || { cat "$STAGE/apt.log" >&2; exit 1; }
MODELS=./usr/share/assimp/models/glTF2
dpkg-deb --fsys-tarfile "$STAGE"/assimp-testmodels_*.deb | tar -x -C "$STAGE" \
  "$MODELS/glTF-Sample-Models/AnimatedMorphCube-glTF/AnimatedMorphCube.gltf" \
  "$MODELS/glTF-Sample-Models/AnimatedMorphCube-glTF/AnimatedMorphCube.bin" \
  "$MODELS/simple_skin/simple_skin.gltf"
mv "$STAGE/$MODELS"/glTF-Sample-Models/AnimatedMorphCube-glTF/AnimatedMorphCube.* "$STAGE/$MODELS/simple_skin/simple_skin.gltf" "$STAGE/anim/"

# spot: a test asset of geometry-central, vendored in the robust-laplacian source distribution
# (its hash pinned, so pip refuses any other bytes).
PIP=${PIP:-python3 -m pip}
if ! $PIP --version >/dev/null 2>&1; then
  make_venv "$STAGE/venv" 8 >&2
  PIP="$STAGE/venv/bin/python -m pip"
fi
echo "$SPOT_SDIST" >"$STAGE/requirements.txt"
$PIP download -q --disable-pip-version-check --no-deps --no-binary robust-laplacian --require-hashes \
  -r "$STAGE/requirements.txt" -d "$STAGE"
tar -xzf "$STAGE"/robust_laplacian-1.1.0.tar.gz -C "$STAGE" \
  robust_laplacian-1.1.0/deps/geometry-central/test/assets/spot.ply
mv "$STAGE"/robust_laplacian-1.1.0/deps/geometry-central/test/assets/spot.ply "$STAGE/mesh/"

# the MRI volume: a data file of nilearn's wheel (a zip, read with Python's zipfile).
echo "$NILEARN_WHEEL" >"$STAGE/requirements.txt"
$PIP download -q --disable-pip-version-check --no-deps --only-binary :all: --require-hashes \
  -r "$STAGE/requirements.txt" -d "$STAGE"
python3 - "$STAGE"/nilearn-0.14.1-py3-none-any.whl "$STAGE/volume/mni_t1.nii.gz" <<'PY'
import sys, zipfile
member = "nilearn/datasets/data/mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz"
with zipfile.ZipFile(sys.argv[1]) as wheel, open(sys.argv[2], "wb") as out:
    out.write(wheel.read(member))
PY

# the lenslet light field: example data of napari-LF's wheel.
echo "$NAPARI_LF_WHEEL" >"$STAGE/requirements.txt"
$PIP download -q --disable-pip-version-check --no-deps --only-binary :all: --require-hashes \
  -r "$STAGE/requirements.txt" -d "$STAGE"
python3 - "$STAGE"/napari_LF-0.1.7-py3-none-any.whl "$STAGE/lightfield/GUVExperim1" <<'PY'
import os, sys, zipfile
names = ["Lightfield_GUVExperim1.tif", "DarkFrame_GUVExperim1.tif", "Radiometry_GUVExperim1.tif",
         "metadata.txt"]
with zipfile.ZipFile(sys.argv[1]) as wheel:
    for name in names:
        with open(os.path.join(sys.argv[2], name), "wb") as out:
            out.write(wheel.read("napari_lf/examples/GUVExperim1/" + name))
PY

(cd "$STAGE" && sha256sum -c --quiet <<<"$SUMS")
mkdir -p "$DIR/mesh" "$DIR/volume" "$DIR/anim" "$DIR/lightfield/GUVExperim1"
while read -r _ file; do
  mv -f "$STAGE/$file" "$DIR/$file"
done <<<"$SUMS"
touch "$DIR/.fetch-complete"
echo "fixtures ready in $DIR"
