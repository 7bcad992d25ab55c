//! NumPy `.npy` volumes: a 3-D array indexed `[k, j, i]` (shape `(nz, ny, nx)`, what
//! `numpy.save` writes for a C-order `vol[z, y, x]`); Fortran-order files hold the same array
//! column-major and are reordered. Integer, unsigned and float dtypes of 1–8 bytes, either byte
//! order. Spacing comes from the caller (`--spacing`), origin 0.

use super::{RawVolume, Result, VolumeFormat, VoxelType, data_bytes, diagonal, header_error};

const FORMAT: VolumeFormat = VolumeFormat::Npy;

pub(super) fn read(bytes: &[u8], spacing: Option<[f64; 3]>) -> Result<RawVolume> {
    const MAGIC: &[u8] = b"\x93NUMPY";
    if bytes.len() < 10 || !bytes.starts_with(MAGIC) {
        return Err(header_error(FORMAT, "not an .npy file (bad magic)"));
    }
    let (len_bytes, header_start) = match bytes[6] {
        1 => (2, 10),
        2 | 3 => (4, 12),
        v => {
            return Err(header_error(
                FORMAT,
                format!("unsupported .npy version {v}"),
            ));
        }
    };
    let len_field = bytes
        .get(8..8 + len_bytes)
        .ok_or_else(|| header_error(FORMAT, "truncated header"))?;
    let header_len = len_field
        .iter()
        .rev()
        .fold(0_usize, |acc, &b| (acc << 8) | usize::from(b));
    let data_offset = header_start + header_len;
    if data_offset > bytes.len() {
        return Err(header_error(FORMAT, "truncated header"));
    }
    // npyz parses the header dictionary only here; the data is decoded below, after the shape
    // was checked against the bytes present.
    let header = npyz::NpyHeader::from_reader(&bytes[..data_offset])
        .map_err(|e| header_error(FORMAT, e.to_string()))?;
    let npyz::DType::Plain(ty) = header.dtype() else {
        return Err(header_error(
            FORMAT,
            format!(
                "dtype {} is not a plain number type",
                header.dtype().descr()
            ),
        ));
    };
    let voxel_type = match (ty.type_char(), ty.size_field()) {
        (npyz::TypeChar::Uint | npyz::TypeChar::Bool, 1) => VoxelType::U8,
        (npyz::TypeChar::Int, 1) => VoxelType::I8,
        (npyz::TypeChar::Uint, 2) => VoxelType::U16,
        (npyz::TypeChar::Int, 2) => VoxelType::I16,
        (npyz::TypeChar::Uint, 4) => VoxelType::U32,
        (npyz::TypeChar::Int, 4) => VoxelType::I32,
        (npyz::TypeChar::Uint, 8) => VoxelType::U64,
        (npyz::TypeChar::Int, 8) => VoxelType::I64,
        (npyz::TypeChar::Float, 4) => VoxelType::F32,
        (npyz::TypeChar::Float, 8) => VoxelType::F64,
        _ => {
            return Err(header_error(
                FORMAT,
                format!("dtype {ty} is not an 8-64 bit integer or a 32/64-bit float"),
            ));
        }
    };
    let big_endian = ty.endianness() == npyz::Endianness::Big;
    let shape = header.shape();
    let [nz, ny, nx] = shape else {
        return Err(header_error(
            FORMAT,
            format!("shape {shape:?} is not 3-D (nz, ny, nx)"),
        ));
    };
    let dims = [*nx, *ny, *nz];
    let expected = data_bytes(&dims, voxel_type)?;
    let data = super::exact(FORMAT, &bytes[data_offset..], expected)?;
    let data = match header.order() {
        npyz::Order::C => data,
        npyz::Order::Fortran => {
            // Column-major (nz, ny, nx): element [k, j, i] at k + nz·(j + ny·i).
            let size = voxel_type.bytes();
            let (nx, ny, nz) = (*nx as usize, *ny as usize, *nz as usize);
            let mut out = Vec::with_capacity(data.len());
            for k in 0..nz {
                for j in 0..ny {
                    for i in 0..nx {
                        let at = (k + nz * (j + ny * i)) * size;
                        out.extend_from_slice(&data[at..at + size]);
                    }
                }
            }
            out
        }
    };
    Ok(RawVolume {
        dims,
        voxel_type,
        big_endian,
        scale: (1.0, 0.0),
        affine: diagonal(spacing.unwrap_or([1.0; 3])),
        origin: [0.0; 3],
        data,
    })
}
