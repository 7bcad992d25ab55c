//! NIfTI-1 single-file volumes (`.nii`, magic `n+1`), plain or gzip-compressed (`.nii.gz`).
//! The `nifti` crate parses the 348-byte header (either byte order); the dimensions are checked
//! here before the voxel data is read. Index-to-world transform: the sform when `sform_code >
//! 0`, else the qform when `qform_code > 0` (quaternion, `qfac` from `pixdim[0]`), else
//! `diag(pixdim[1..4])` with origin 0 (the NIfTI-1 standard's order of methods). Values are
//! scaled by `scl_slope`/`scl_inter` when the slope is finite and non-zero. A fourth and later
//! dimension must be 1 (one 3-D volume).

use std::io::Read;

use ::nifti::{NiftiHeader, NiftiType};

use super::{
    RawVolume, Result, VolumeFormat, VoxelType, data_bytes, diagonal, header_error, inflate_exact,
};

const FORMAT: VolumeFormat = VolumeFormat::Nifti;
/// Bytes of a NIfTI-1 header.
const HEADER_BYTES: u64 = 348;

pub(super) fn read(bytes: &[u8], gz: bool) -> Result<RawVolume> {
    let head = if gz {
        inflate_prefix(bytes, HEADER_BYTES)?
    } else {
        bytes.to_vec()
    };
    if (head.len() as u64) < HEADER_BYTES {
        return Err(header_error(
            FORMAT,
            format!(
                "{} bytes is shorter than a NIfTI-1 header (348)",
                head.len()
            ),
        ));
    }
    let header = NiftiHeader::from_reader(&head[..HEADER_BYTES as usize])
        .map_err(|e| header_error(FORMAT, e.to_string()))?;
    if header.sizeof_hdr != 348 {
        return Err(header_error(
            FORMAT,
            format!(
                "sizeof_hdr is {} (NIfTI-1 has 348; NIfTI-2 is not supported)",
                header.sizeof_hdr
            ),
        ));
    }
    if &header.magic != b"n+1\0" {
        return Err(header_error(
            FORMAT,
            format!(
                "magic {:?} is not a single-file NIfTI-1 (\"n+1\"); .hdr/.img pairs are not supported",
                String::from_utf8_lossy(&header.magic)
            ),
        ));
    }
    let ndim = usize::from(header.dim[0]);
    if !(2..=7).contains(&ndim) {
        return Err(header_error(
            FORMAT,
            format!("dim[0] = {ndim} is not 2..=7"),
        ));
    }
    if let Some(extra) = header.dim[4..=ndim.max(3)].iter().find(|&&d| d != 1) {
        return Err(header_error(
            FORMAT,
            format!("a dimension beyond the third is {extra}: only one 3-D volume is supported"),
        ));
    }
    let dims = [
        u64::from(header.dim[1]),
        u64::from(header.dim[2]),
        if ndim >= 3 {
            u64::from(header.dim[3])
        } else {
            1
        },
    ];
    let voxel_type = match header.data_type() {
        Ok(NiftiType::Uint8) => VoxelType::U8,
        Ok(NiftiType::Int8) => VoxelType::I8,
        Ok(NiftiType::Uint16) => VoxelType::U16,
        Ok(NiftiType::Int16) => VoxelType::I16,
        Ok(NiftiType::Uint32) => VoxelType::U32,
        Ok(NiftiType::Int32) => VoxelType::I32,
        Ok(NiftiType::Uint64) => VoxelType::U64,
        Ok(NiftiType::Int64) => VoxelType::I64,
        Ok(NiftiType::Float32) => VoxelType::F32,
        Ok(NiftiType::Float64) => VoxelType::F64,
        Ok(other) => {
            return Err(header_error(
                FORMAT,
                format!("datatype {other:?} is not a scalar integer or float"),
            ));
        }
        Err(_) => {
            return Err(header_error(
                FORMAT,
                format!("datatype code {} is unknown", header.datatype),
            ));
        }
    };
    let expected = data_bytes(&dims, voxel_type)?;
    let offset = header.vox_offset;
    if !(offset.is_finite() && offset >= 348.0 && offset.fract() == 0.0 && offset < 1e12) {
        return Err(header_error(
            FORMAT,
            format!("vox_offset {offset} is not a whole number of bytes ≥ 348"),
        ));
    }
    let offset = offset as u64;
    let data = if gz {
        let all = inflate_exact(
            FORMAT,
            flate2::read::MultiGzDecoder::new(bytes),
            offset + expected,
        )?;
        all[offset as usize..].to_vec()
    } else {
        let data = bytes.get(offset as usize..).unwrap_or_default();
        super::exact(FORMAT, data, expected)?
    };
    let slope = f64::from(header.scl_slope);
    let scale = if slope.is_finite() && slope != 0.0 {
        let inter = f64::from(header.scl_inter);
        (slope, if inter.is_finite() { inter } else { 0.0 })
    } else {
        (1.0, 0.0)
    };
    let (affine, origin) = transform(&header);
    Ok(RawVolume {
        dims,
        voxel_type,
        big_endian: header.endianness == ::nifti::Endianness::Big,
        scale,
        affine,
        origin,
        data,
    })
}

/// The first `n` bytes of a gzip stream (fewer if it is shorter).
fn inflate_prefix(bytes: &[u8], n: u64) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    flate2::read::MultiGzDecoder::new(bytes)
        .take(n)
        .read_to_end(&mut out)
        .map_err(|e| header_error(FORMAT, format!("gzip: {e}")))?;
    Ok(out)
}

/// Index-to-world columns and origin (see the module documentation).
fn transform(h: &NiftiHeader) -> ([[f64; 3]; 3], [f64; 3]) {
    let f = f64::from;
    if h.sform_code > 0 {
        let rows = [h.srow_x, h.srow_y, h.srow_z];
        let column = |c: usize| [f(rows[0][c]), f(rows[1][c]), f(rows[2][c])];
        return (
            [column(0), column(1), column(2)],
            [f(rows[0][3]), f(rows[1][3]), f(rows[2][3])],
        );
    }
    let spacing = [f(h.pixdim[1]), f(h.pixdim[2]), f(h.pixdim[3])];
    if h.qform_code > 0 {
        let (b, c, d) = (f(h.quatern_b), f(h.quatern_c), f(h.quatern_d));
        let a = (1.0 - (b * b + c * c + d * d)).max(0.0).sqrt();
        let r = [
            [
                a * a + b * b - c * c - d * d,
                2.0 * (b * c - a * d),
                2.0 * (b * d + a * c),
            ],
            [
                2.0 * (b * c + a * d),
                a * a + c * c - b * b - d * d,
                2.0 * (c * d - a * b),
            ],
            [
                2.0 * (b * d - a * c),
                2.0 * (c * d + a * b),
                a * a + d * d - c * c - b * b,
            ],
        ];
        let qfac = if h.pixdim[0] < 0.0 { -1.0 } else { 1.0 };
        let scale = [spacing[0], spacing[1], qfac * spacing[2]];
        let column = |k: usize| [r[0][k] * scale[k], r[1][k] * scale[k], r[2][k] * scale[k]];
        return (
            [column(0), column(1), column(2)],
            [f(h.quatern_x), f(h.quatern_y), f(h.quatern_z)],
        );
    }
    (diagonal(spacing), [0.0; 3])
}
