//! Scalar and label volumes in: NIfTI `.nii`/`.nii.gz`, NumPy `.npy`,
//! MetaImage `.mha`/`.mhd`, NRRD `.nrrd`/`.nhdr`, INRIA `.inr`/`.inr.gz` and VTK image data
//! `.vti`, read into one validated [`Volume`] with DESIGN §9's conventions.
//!
//! A volume holds `S[k][j][i]` with `i` fastest; index `(i, j, k)` sits at world
//! `M·(i, j, k) + o`, with `M` the file's 3×3 affine ([`Volume::affine`], default
//! `diag(spacing)`) and origin `o` ([`Volume::origin`]). Values are the voxel values after the
//! file's own scaling (NIfTI `scl_slope`/`scl_inter`, INRIA `SCALE`), stored as `f32` for
//! scalar volumes; label volumes (`labels`) keep non-negative integer labels as `u32` and refuse
//! anything else, since labels are never interpolated or scaled into fractions.
//!
//! Every reader checks the header's dimensions against [`MAX_VOXELS`] and against the bytes
//! actually present before it allocates for the voxels, and reads compressed data through a
//! limit of the expected size, so a forged header gets a [`VolumeError`], never a giant
//! allocation. NaN and infinite voxels are refused ([`VolumeError::NonFinite`]) with the first
//! voxel's index.

pub mod bake;
mod inr;
pub mod layers;
mod metaimage;
mod nifti;
mod npy;
mod nrrd;
pub mod raycast;
pub mod tf;
mod vti;

use std::io::Read;
use std::path::{Path, PathBuf};

/// Most voxels a volume may hold (1024³: 4 GiB as `f32`).
pub const MAX_VOXELS: u64 = 1 << 30;
/// Largest side along any axis, voxels.
pub const MAX_SIDE: u64 = 16_384;
/// Largest header a text-header format may have before its data, bytes.
pub const MAX_HEADER_BYTES: usize = 1 << 20;

/// Why a volume is refused.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum VolumeError {
    /// The file (or a detached data file) cannot be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file name's extension is none of the supported formats.
    #[error(
        "{0}: unknown volume format (expected .nii, .nii.gz, .npy, .mha, .mhd, .nrrd, .nhdr, .inr, \
         .inr.gz or .vti)"
    )]
    UnknownFormat(String),
    /// The header is malformed or says something unsupported.
    #[error("{format}: {message}")]
    Header {
        /// The format.
        format: VolumeFormat,
        /// What is wrong.
        message: String,
    },
    /// The voxel data is shorter (or longer) than the header says.
    #[error("{format}: the header declares {expected} voxel data bytes but the file holds {found}")]
    DataSize {
        /// The format.
        format: VolumeFormat,
        /// Bytes the header's dimensions and voxel type need.
        expected: u64,
        /// Bytes present (at most `expected + 1` are read from compressed data).
        found: u64,
    },
    /// The dimensions exceed [`MAX_VOXELS`] or [`MAX_SIDE`], or one is zero.
    #[error(
        "dimensions {0:?} are not allowed: every side must be 1..={MAX_SIDE} and the volume at \
         most {MAX_VOXELS} voxels"
    )]
    Dimensions(Vec<u64>),
    /// A voxel is NaN or infinite (after scaling).
    #[error("voxel (i={i}, j={j}, k={k}) is {value}: volumes must be finite")]
    NonFinite {
        /// Column.
        i: u32,
        /// Row.
        j: u32,
        /// Slice.
        k: u32,
        /// The value.
        value: f64,
    },
    /// A label volume holds a value that is not a non-negative integer label.
    #[error(
        "voxel (i={i}, j={j}, k={k}) is {value}: a label volume needs integer labels in 0..={max}",
        max = u32::MAX
    )]
    NotALabel {
        /// Column.
        i: u32,
        /// Row.
        j: u32,
        /// Slice.
        k: u32,
        /// The value.
        value: f64,
    },
    /// The affine or origin is not finite, or the affine is singular.
    #[error("the index-to-world transform {0}")]
    Transform(String),
    /// `spacing` was given for a format that carries its own.
    #[error("spacing applies to .npy volumes only; {0} files carry their own spacing")]
    SpacingNotAllowed(VolumeFormat),
    /// A format whose data lives in another file was given as bytes only.
    #[error("{0}: the header names a detached data file ({1}); give the header's path instead")]
    Detached(VolumeFormat, String),
}

/// Shorthand for results of this module.
pub type Result<T, E = VolumeError> = std::result::Result<T, E>;

/// A supported volume file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum VolumeFormat {
    /// NIfTI-1 `.nii` / `.nii.gz`.
    Nifti,
    /// NumPy `.npy`.
    Npy,
    /// MetaImage `.mha` (data attached) / `.mhd` (data in a file it names).
    MetaImage,
    /// NRRD `.nrrd` (attached) / `.nhdr` (detached).
    Nrrd,
    /// INRIA `.inr` / `.inr.gz`.
    Inria,
    /// VTK XML image data `.vti`.
    Vti,
}

impl std::fmt::Display for VolumeFormat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            VolumeFormat::Nifti => "NIfTI",
            VolumeFormat::Npy => "NPY",
            VolumeFormat::MetaImage => "MetaImage",
            VolumeFormat::Nrrd => "NRRD",
            VolumeFormat::Inria => "INRIA",
            VolumeFormat::Vti => "VTK image data",
        })
    }
}

impl VolumeFormat {
    /// The format a file name's extension names (case-insensitive), with whether it is
    /// gzip-compressed as a whole (`.nii.gz`, `.inr.gz`).
    pub fn from_name(name: &str) -> Option<(VolumeFormat, bool)> {
        let lower = name.to_ascii_lowercase();
        let (stem, gz) = match lower.strip_suffix(".gz") {
            Some(stem) => (stem, true),
            None => (lower.as_str(), false),
        };
        let format = match Path::new(stem).extension()?.to_str()? {
            "nii" => VolumeFormat::Nifti,
            "inr" => VolumeFormat::Inria,
            "npy" if !gz => VolumeFormat::Npy,
            "mha" | "mhd" if !gz => VolumeFormat::MetaImage,
            "nrrd" | "nhdr" if !gz => VolumeFormat::Nrrd,
            "vti" if !gz => VolumeFormat::Vti,
            _ => return None,
        };
        Some((format, gz))
    }
}

/// The element type a file stores its voxels in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum VoxelType {
    /// Unsigned 8-bit integer.
    U8,
    /// Signed 8-bit integer.
    I8,
    /// Unsigned 16-bit integer.
    U16,
    /// Signed 16-bit integer.
    I16,
    /// Unsigned 32-bit integer.
    U32,
    /// Signed 32-bit integer.
    I32,
    /// Unsigned 64-bit integer.
    U64,
    /// Signed 64-bit integer.
    I64,
    /// 32-bit float.
    F32,
    /// 64-bit float.
    F64,
}

impl VoxelType {
    /// Bytes per voxel.
    pub fn bytes(self) -> usize {
        match self {
            VoxelType::U8 | VoxelType::I8 => 1,
            VoxelType::U16 | VoxelType::I16 => 2,
            VoxelType::U32 | VoxelType::I32 | VoxelType::F32 => 4,
            VoxelType::U64 | VoxelType::I64 | VoxelType::F64 => 8,
        }
    }

    /// Decodes one voxel from exactly [`Self::bytes`] bytes.
    fn decode(self, b: &[u8], big_endian: bool) -> f64 {
        macro_rules! num {
            ($t:ty) => {{
                let mut a = [0u8; std::mem::size_of::<$t>()];
                a.copy_from_slice(b);
                if big_endian {
                    <$t>::from_be_bytes(a)
                } else {
                    <$t>::from_le_bytes(a)
                }
            }};
        }
        match self {
            VoxelType::U8 => f64::from(b[0]),
            VoxelType::I8 => f64::from(b[0] as i8),
            VoxelType::U16 => f64::from(num!(u16)),
            VoxelType::I16 => f64::from(num!(i16)),
            VoxelType::U32 => f64::from(num!(u32)),
            VoxelType::I32 => f64::from(num!(i32)),
            VoxelType::U64 => num!(u64) as f64,
            VoxelType::I64 => num!(i64) as f64,
            VoxelType::F32 => f64::from(num!(f32)),
            VoxelType::F64 => num!(f64),
        }
    }
}

/// The voxel values.
#[derive(Clone, Debug, PartialEq)]
pub enum Voxels {
    /// Scalar values, sampled trilinearly.
    Scalar(Vec<f32>),
    /// Integer labels, sampled by nearest voxel.
    Labels(Vec<u32>),
}

impl Voxels {
    /// Number of voxels.
    pub fn len(&self) -> usize {
        match self {
            Voxels::Scalar(v) => v.len(),
            Voxels::Labels(v) => v.len(),
        }
    }

    /// Whether there are no voxels (never, for a loaded volume).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// How to read a volume.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LoadOptions {
    /// Keep integer labels ([`Voxels::Labels`]) instead of scalar values.
    pub labels: bool,
    /// Voxel spacing of a `.npy` volume (default 1, 1, 1); refused for other formats.
    pub spacing: Option<[f64; 3]>,
}

/// A validated volume (see the module documentation for its conventions).
#[derive(Clone, Debug, PartialEq)]
pub struct Volume {
    /// `(nx, ny, nz)`: voxels along i, j, k.
    pub dims: [u32; 3],
    /// `nx·ny·nz` values, i fastest, then j, then k.
    pub voxels: Voxels,
    /// `M` column-major: `affine[c]` is the world step of index axis c (`m[column][row]`).
    pub affine: [[f64; 3]; 3],
    /// World position of voxel (0, 0, 0)'s centre.
    pub origin: [f64; 3],
    /// The element type stored in the file.
    pub voxel_type: VoxelType,
    /// The file's format.
    pub format: VolumeFormat,
}

impl Volume {
    /// Reads a volume file; the format comes from the name's extension. MetaImage `.mhd` and
    /// NRRD `.nhdr` headers read their data file relative to the header's folder.
    pub fn load(path: &Path, options: &LoadOptions) -> Result<Volume> {
        let name = path.to_string_lossy();
        let (format, gz) = VolumeFormat::from_name(&name)
            .ok_or_else(|| VolumeError::UnknownFormat(name.into()))?;
        let bytes = std::fs::read(path).map_err(|source| VolumeError::Io {
            path: path.to_owned(),
            source,
        })?;
        decode(format, gz, &bytes, path.parent(), options)
    }

    /// Reads a volume from its bytes, the format named by `name`'s extension (an upload's file
    /// name). Formats with a detached data file are refused ([`VolumeError::Detached`]).
    pub fn from_bytes(name: &str, bytes: &[u8], options: &LoadOptions) -> Result<Volume> {
        let (format, gz) =
            VolumeFormat::from_name(name).ok_or_else(|| VolumeError::UnknownFormat(name.into()))?;
        decode(format, gz, bytes, None, options)
    }

    /// A volume from values already in memory (i fastest, `dims[0]·dims[1]·dims[2]` of them),
    /// with the checks a file gets: dimensions, a finite non-singular transform, finite values;
    /// labels as given.
    pub fn from_values(
        dims: [u32; 3],
        voxels: Voxels,
        affine: [[f64; 3]; 3],
        origin: [f64; 3],
    ) -> Result<Volume> {
        let dims_u64 = dims.map(u64::from);
        check_dims(&dims_u64)?;
        check_transform(&affine, &origin)?;
        let count = dims_u64.iter().product::<u64>();
        if voxels.len() as u64 != count {
            return Err(VolumeError::DataSize {
                format: VolumeFormat::Npy,
                expected: count,
                found: voxels.len() as u64,
            });
        }
        let (nx, ny) = (dims[0] as usize, dims[1] as usize);
        let voxel_type = match &voxels {
            Voxels::Scalar(v) => {
                if let Some(n) = v.iter().position(|x| !x.is_finite()) {
                    return Err(VolumeError::NonFinite {
                        i: (n % nx) as u32,
                        j: ((n / nx) % ny) as u32,
                        k: (n / (nx * ny)) as u32,
                        value: f64::from(v[n]),
                    });
                }
                VoxelType::F32
            }
            Voxels::Labels(_) => VoxelType::U32,
        };
        Ok(Volume {
            dims,
            voxels,
            affine,
            origin,
            voxel_type,
            format: VolumeFormat::Npy,
        })
    }

    /// Number of voxels.
    pub fn voxel_count(&self) -> u64 {
        self.dims.iter().map(|&d| u64::from(d)).product()
    }

    /// The world position of index `(i, j, k)` (fractional indices allowed).
    pub fn world(&self, index: [f64; 3]) -> [f64; 3] {
        let mut p = self.origin;
        for (c, &x) in index.iter().enumerate() {
            for (r, pr) in p.iter_mut().enumerate() {
                *pr += self.affine[c][r] * x;
            }
        }
        p
    }

    /// The spacing along each index axis: the norms of `M`'s columns.
    pub fn spacing(&self) -> [f64; 3] {
        self.affine
            .map(|c| c.iter().map(|x| x * x).sum::<f64>().sqrt())
    }

    /// `(min, max)` of the values (labels as numbers).
    pub fn range(&self) -> (f64, f64) {
        let fold = |(lo, hi): (f64, f64), v: f64| (lo.min(v), hi.max(v));
        match &self.voxels {
            Voxels::Scalar(v) => v
                .iter()
                .map(|&x| f64::from(x))
                .fold((f64::INFINITY, f64::NEG_INFINITY), fold),
            Voxels::Labels(v) => v
                .iter()
                .map(|&x| f64::from(x))
                .fold((f64::INFINITY, f64::NEG_INFINITY), fold),
        }
    }
}

fn decode(
    format: VolumeFormat,
    gz: bool,
    bytes: &[u8],
    folder: Option<&Path>,
    options: &LoadOptions,
) -> Result<Volume> {
    if options.spacing.is_some() && format != VolumeFormat::Npy {
        return Err(VolumeError::SpacingNotAllowed(format));
    }
    let raw = match format {
        VolumeFormat::Nifti => nifti::read(bytes, gz)?,
        VolumeFormat::Npy => npy::read(bytes, options.spacing)?,
        VolumeFormat::MetaImage => metaimage::read(bytes, folder)?,
        VolumeFormat::Nrrd => nrrd::read(bytes, folder)?,
        VolumeFormat::Inria => inr::read(bytes, gz)?,
        VolumeFormat::Vti => vti::read(bytes)?,
    };
    raw.into_volume(format, options.labels)
}

/// What a format reader hands over: dimensions, transform, and the voxel bytes as stored.
struct RawVolume {
    dims: [u64; 3],
    voxel_type: VoxelType,
    big_endian: bool,
    /// `value = slope·raw + inter`.
    scale: (f64, f64),
    affine: [[f64; 3]; 3],
    origin: [f64; 3],
    /// Exactly `dims` product × voxel bytes, i fastest.
    data: Vec<u8>,
}

impl RawVolume {
    fn into_volume(self, format: VolumeFormat, labels: bool) -> Result<Volume> {
        let dims = check_dims(&self.dims)?;
        check_transform(&self.affine, &self.origin)?;
        let size = self.voxel_type.bytes();
        let count = self.data.len() / size;
        debug_assert_eq!(count as u64, self.dims.iter().product::<u64>());
        let (slope, inter) = self.scale;
        let (nx, ny) = (self.dims[0] as usize, self.dims[1] as usize);
        let index = |n: usize| {
            (
                (n % nx) as u32,
                ((n / nx) % ny) as u32,
                (n / (nx * ny)) as u32,
            )
        };
        let values = self
            .data
            .chunks_exact(size)
            .map(|b| slope * self.voxel_type.decode(b, self.big_endian) + inter);
        let voxels = if labels {
            let mut out = Vec::with_capacity(count);
            for (n, value) in values.enumerate() {
                if !(value >= 0.0 && value <= f64::from(u32::MAX) && value.fract() == 0.0) {
                    let (i, j, k) = index(n);
                    return Err(VolumeError::NotALabel { i, j, k, value });
                }
                out.push(value as u32);
            }
            Voxels::Labels(out)
        } else {
            let mut out = Vec::with_capacity(count);
            for (n, value) in values.enumerate() {
                let v = value as f32;
                if !v.is_finite() {
                    let (i, j, k) = index(n);
                    return Err(VolumeError::NonFinite { i, j, k, value });
                }
                out.push(v);
            }
            Voxels::Scalar(out)
        };
        Ok(Volume {
            dims,
            voxels,
            affine: self.affine,
            origin: self.origin,
            voxel_type: self.voxel_type,
            format,
        })
    }
}

/// Checks dimensions against [`MAX_SIDE`] and [`MAX_VOXELS`] (overflow-safe).
fn check_dims(dims: &[u64]) -> Result<[u32; 3]> {
    let bad = || VolumeError::Dimensions(dims.to_vec());
    if dims.len() != 3 || dims.iter().any(|&d| d == 0 || d > MAX_SIDE) {
        return Err(bad());
    }
    let total = dims
        .iter()
        .try_fold(1u64, |a, &d| a.checked_mul(d))
        .ok_or_else(bad)?;
    if total > MAX_VOXELS {
        return Err(bad());
    }
    Ok([dims[0] as u32, dims[1] as u32, dims[2] as u32])
}

/// Bytes of voxel data `dims` need, after checking the dimensions.
fn data_bytes(dims: &[u64; 3], voxel_type: VoxelType) -> Result<u64> {
    check_dims(dims)?;
    Ok(dims.iter().product::<u64>() * voxel_type.bytes() as u64)
}

fn check_transform(affine: &[[f64; 3]; 3], origin: &[f64; 3]) -> Result<()> {
    if !affine.iter().flatten().chain(origin).all(|x| x.is_finite()) {
        return Err(VolumeError::Transform(format!(
            "is not finite (columns {affine:?}, origin {origin:?})"
        )));
    }
    let [a, b, c] = affine;
    let det = a[0] * (b[1] * c[2] - b[2] * c[1]) - b[0] * (a[1] * c[2] - a[2] * c[1])
        + c[0] * (a[1] * b[2] - a[2] * b[1]);
    let scale: f64 = affine
        .iter()
        .map(|col| col.iter().map(|x| x * x).sum::<f64>().sqrt())
        .product();
    // |det| relative to the product of the column norms: 1 for orthogonal columns, 0 for
    // linearly dependent ones; 1e-9 refuses only (numerically) singular transforms.
    if !(scale > 0.0 && scale.is_finite() && (det / scale).abs() > 1e-9) {
        return Err(VolumeError::Transform(format!(
            "is singular (columns {affine:?}): every spacing must be non-zero and the axes \
             independent"
        )));
    }
    Ok(())
}

/// `diag(spacing)` column-major.
fn diagonal(spacing: [f64; 3]) -> [[f64; 3]; 3] {
    [
        [spacing[0], 0.0, 0.0],
        [0.0, spacing[1], 0.0],
        [0.0, 0.0, spacing[2]],
    ]
}

/// Takes exactly `expected` bytes of voxel data from `data` (raw, attached); more or fewer is a
/// [`VolumeError::DataSize`].
fn exact(format: VolumeFormat, data: &[u8], expected: u64) -> Result<Vec<u8>> {
    if data.len() as u64 != expected {
        return Err(VolumeError::DataSize {
            format,
            expected,
            found: data.len() as u64,
        });
    }
    Ok(data.to_vec())
}

/// Reads exactly `expected` bytes from a decompressing reader, never more than `expected + 1`
/// (so a forged size cannot make it inflate without bound).
fn inflate_exact(format: VolumeFormat, reader: impl Read, expected: u64) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    reader
        .take(expected.saturating_add(1))
        .read_to_end(&mut out)
        .map_err(|e| VolumeError::Header {
            format,
            message: format!("compressed voxel data: {e}"),
        })?;
    if out.len() as u64 != expected {
        return Err(VolumeError::DataSize {
            format,
            expected,
            found: out.len() as u64,
        });
    }
    Ok(out)
}

/// A [`VolumeError::Header`] of `format`.
fn header_error(format: VolumeFormat, message: impl Into<String>) -> VolumeError {
    VolumeError::Header {
        format,
        message: message.into(),
    }
}

/// The next line of a text header starting at `*at` (without its `\n` or `\r`), moving `*at`
/// past it; `None` at the end of the bytes. Headers over [`MAX_HEADER_BYTES`] or not UTF-8 are
/// refused.
fn header_line<'a>(
    format: VolumeFormat,
    bytes: &'a [u8],
    at: &mut usize,
) -> Result<Option<&'a str>> {
    if *at >= bytes.len() {
        return Ok(None);
    }
    if *at > MAX_HEADER_BYTES {
        return Err(header_error(format, "the header is longer than 1 MiB"));
    }
    let end = bytes[*at..]
        .iter()
        .position(|&b| b == b'\n')
        .map_or(bytes.len(), |p| *at + p);
    let line = std::str::from_utf8(&bytes[*at..end])
        .map_err(|_| header_error(format, "the header is not text"))?;
    *at = end + 1;
    Ok(Some(line.trim_end_matches('\r')))
}

/// Reads a detached data file named in a header, relative to the header's folder.
fn read_detached(format: VolumeFormat, folder: Option<&Path>, name: &str) -> Result<Vec<u8>> {
    let Some(folder) = folder else {
        return Err(VolumeError::Detached(format, name.to_owned()));
    };
    let path = folder.join(name);
    std::fs::read(&path).map_err(|source| VolumeError::Io { path, source })
}

/// Parses `n` whitespace-separated numbers.
fn numbers<const N: usize>(format: VolumeFormat, key: &str, value: &str) -> Result<[f64; N]> {
    let parsed: Vec<f64> = value
        .split(|c: char| c.is_whitespace() || c == ',' || c == '(' || c == ')')
        .filter(|s| !s.is_empty())
        .map(str::parse)
        .collect::<Result<_, _>>()
        .map_err(|_| header_error(format, format!("{key} {value:?} is not a list of numbers")))?;
    parsed.try_into().map_err(|v: Vec<f64>| {
        header_error(
            format,
            format!("{key} needs {N} numbers, found {}", v.len()),
        )
    })
}

#[cfg(test)]
mod tests;
