//! Every reader on files written here byte by byte (each format's own layout), both byte
//! orders, compressed and plain, and the refusals: truncated data, dimensions that do not match
//! the data, hostile sizes, NaN voxels, bad labels, detached data given as bytes.

use std::io::Write;

use super::*;

/// A 3×2×2 ramp, i fastest: value = i + 10·j + 100·k.
const DIMS: [usize; 3] = [3, 2, 2];

fn ramp() -> Vec<f64> {
    let mut v = Vec::new();
    for k in 0..DIMS[2] {
        for j in 0..DIMS[1] {
            for i in 0..DIMS[0] {
                v.push((i + 10 * j + 100 * k) as f64);
            }
        }
    }
    v
}

fn le_u16(values: &[f64]) -> Vec<u8> {
    values
        .iter()
        .flat_map(|&v| (v as u16).to_le_bytes())
        .collect()
}

fn be_f32(values: &[f64]) -> Vec<u8> {
    values
        .iter()
        .flat_map(|&v| (v as f32).to_be_bytes())
        .collect()
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    e.write_all(bytes).expect("gzip");
    e.finish().expect("gzip")
}

fn zlib(bytes: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::fast());
    e.write_all(bytes).expect("zlib");
    e.finish().expect("zlib")
}

fn scalars(v: &Volume) -> Vec<f64> {
    match &v.voxels {
        Voxels::Scalar(s) => s.iter().map(|&x| f64::from(x)).collect(),
        Voxels::Labels(l) => panic!("labels {l:?}"),
    }
}

fn opts() -> LoadOptions {
    LoadOptions::default()
}

/// A NIfTI-1 single-file header (little endian) for `dims`, `datatype`/`bitpix`, with the
/// given sform rows (sform_code 1) or none.
fn nifti_header(
    dims: [u16; 3],
    datatype: i16,
    bitpix: i16,
    slope: f32,
    inter: f32,
    sform: Option<[[f32; 4]; 3]>,
) -> Vec<u8> {
    let mut h = vec![0u8; 352];
    h[0..4].copy_from_slice(&348i32.to_le_bytes());
    let dim: [u16; 8] = [3, dims[0], dims[1], dims[2], 1, 1, 1, 1];
    for (n, d) in dim.iter().enumerate() {
        h[40 + 2 * n..42 + 2 * n].copy_from_slice(&d.to_le_bytes());
    }
    h[70..72].copy_from_slice(&datatype.to_le_bytes());
    h[72..74].copy_from_slice(&bitpix.to_le_bytes());
    let pixdim: [f32; 8] = [1.0, 0.5, 0.25, 2.0, 1.0, 0.0, 0.0, 0.0];
    for (n, p) in pixdim.iter().enumerate() {
        h[76 + 4 * n..80 + 4 * n].copy_from_slice(&p.to_le_bytes());
    }
    h[108..112].copy_from_slice(&352f32.to_le_bytes());
    h[112..116].copy_from_slice(&slope.to_le_bytes());
    h[116..120].copy_from_slice(&inter.to_le_bytes());
    if let Some(rows) = sform {
        h[254..256].copy_from_slice(&1i16.to_le_bytes());
        for (r, row) in rows.iter().enumerate() {
            for (c, x) in row.iter().enumerate() {
                let at = 280 + 16 * r + 4 * c;
                h[at..at + 4].copy_from_slice(&x.to_le_bytes());
            }
        }
    }
    h[344..348].copy_from_slice(b"n+1\0");
    h
}

#[test]
fn nifti_plain_and_gzip_with_scaling_and_sform() {
    let sform = [
        [0.0, 0.0, 2.0, 5.0],
        [0.5, 0.0, 0.0, -1.0],
        [0.0, -0.25, 0.0, 3.0],
    ];
    let mut file = nifti_header([3, 2, 2], 512, 16, 2.0, 1.0, Some(sform));
    file.extend(le_u16(&ramp()));
    for (name, bytes) in [("a.nii", file.clone()), ("a.nii.gz", gzip(&file))] {
        let v = Volume::from_bytes(name, &bytes, &opts()).expect(name);
        assert_eq!(v.dims, [3, 2, 2]);
        assert_eq!(v.voxel_type, VoxelType::U16);
        assert_eq!(v.format, VolumeFormat::Nifti);
        let want: Vec<f64> = ramp().iter().map(|x| 2.0 * x + 1.0).collect();
        assert_eq!(scalars(&v), want, "{name}");
        // Columns are the sform's columns: i steps along world y, j along −z, k along x.
        assert_eq!(
            v.affine,
            [[0.0, 0.5, 0.0], [0.0, 0.0, -0.25], [2.0, 0.0, 0.0]]
        );
        assert_eq!(v.origin, [5.0, -1.0, 3.0]);
        assert_eq!(v.world([1.0, 1.0, 1.0]), [7.0, -0.5, 2.75]);
        assert_eq!(v.spacing(), [0.5, 0.25, 2.0]);
    }
}

#[test]
fn nifti_without_transform_uses_pixdim_and_refuses_bad_headers() {
    let mut file = nifti_header([3, 2, 2], 2, 8, 0.0, 0.0, None);
    file.extend(ramp().iter().map(|&x| x as u8));
    let v = Volume::from_bytes("a.nii", &file, &opts()).expect("pixdim");
    assert_eq!(v.affine, diagonal([0.5, 0.25, 2.0]));
    assert_eq!(v.origin, [0.0; 3]);
    // A slope of 0 means unscaled.
    assert_eq!(scalars(&v), ramp());

    // Truncated: one voxel short.
    let short = &file[..file.len() - 1];
    assert!(matches!(
        Volume::from_bytes("a.nii", short, &opts()),
        Err(VolumeError::DataSize {
            expected: 12,
            found: 11,
            ..
        })
    ));
    // Hostile dimensions: refused before any allocation.
    let mut huge = nifti_header([16000, 16000, 16000], 16, 32, 0.0, 0.0, None);
    huge.extend([0u8; 64]);
    assert!(matches!(
        Volume::from_bytes("a.nii", &huge, &opts()),
        Err(VolumeError::Dimensions(_))
    ));
    assert!(matches!(
        Volume::from_bytes("a.nii.gz", &gzip(&huge), &opts()),
        Err(VolumeError::Dimensions(_))
    ));
    // A 4-D series.
    let mut series = file.clone();
    series[40..42].copy_from_slice(&4u16.to_le_bytes());
    series[48..50].copy_from_slice(&2u16.to_le_bytes());
    let e = Volume::from_bytes("a.nii", &series, &opts()).expect_err("4-D");
    assert!(e.to_string().contains("beyond the third"), "{e}");
    // Complex voxels.
    let mut complex = nifti_header([3, 2, 2], 32, 64, 0.0, 0.0, None);
    complex.extend(vec![0u8; 12 * 8]);
    let e = Volume::from_bytes("a.nii", &complex, &opts()).expect_err("complex");
    assert!(e.to_string().contains("not a scalar"), "{e}");
    // Not NIfTI at all, and too short for a header.
    assert!(Volume::from_bytes("a.nii", b"hello", &opts()).is_err());
    assert!(Volume::from_bytes("a.nii.gz", b"hello", &opts()).is_err());
}

fn npy(descr: &str, fortran: bool, shape: &str, data: &[u8]) -> Vec<u8> {
    let dict = format!(
        "{{'descr': '{descr}', 'fortran_order': {}, 'shape': {shape}, }}",
        if fortran { "True" } else { "False" }
    );
    let mut header = dict.into_bytes();
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(b' ');
    }
    header.push(b'\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend((header.len() as u16).to_le_bytes());
    out.extend(header);
    out.extend(data);
    out
}

#[test]
fn npy_c_and_fortran_order_both_byte_orders_with_spacing() {
    let c = npy("<u2", false, "(2, 2, 3)", &le_u16(&ramp()));
    let spacing = LoadOptions {
        spacing: Some([0.5, 1.0, 2.0]),
        ..opts()
    };
    let v = Volume::from_bytes("v.npy", &c, &spacing).expect("C order");
    assert_eq!(v.dims, [3, 2, 2]);
    assert_eq!(scalars(&v), ramp());
    assert_eq!(v.affine, diagonal([0.5, 1.0, 2.0]));
    // Fortran order: element [k, j, i] at k + 2·(j + 2·i).
    let mut f = vec![0.0; 12];
    for (n, &x) in ramp().iter().enumerate() {
        let (i, j, k) = (n % 3, (n / 3) % 2, n / 6);
        f[k + 2 * (j + 2 * i)] = x;
    }
    let fortran = npy(">f4", true, "(2, 2, 3)", &be_f32(&f));
    let v = Volume::from_bytes("v.npy", &fortran, &opts()).expect("Fortran order");
    assert_eq!(scalars(&v), ramp());
    assert_eq!(v.voxel_type, VoxelType::F32);
    assert_eq!(v.affine, diagonal([1.0; 3]));
    // 2-D, wrong data size, hostile shape, complex dtype.
    assert!(
        Volume::from_bytes(
            "v.npy",
            &npy("<u2", false, "(4, 3)", &le_u16(&ramp())),
            &opts()
        )
        .is_err()
    );
    assert!(matches!(
        Volume::from_bytes(
            "v.npy",
            &npy("<u2", false, "(2, 2, 4)", &le_u16(&ramp())),
            &opts()
        ),
        Err(VolumeError::DataSize { .. })
    ));
    assert!(matches!(
        Volume::from_bytes(
            "v.npy",
            &npy("<u2", false, "(4096, 4096, 4096)", &[0; 8]),
            &opts()
        ),
        Err(VolumeError::Dimensions(_))
    ));
    assert!(
        Volume::from_bytes("v.npy", &npy("<c8", false, "(1, 1, 1)", &[0; 8]), &opts()).is_err()
    );
}

#[test]
fn nan_voxels_and_labels() {
    let mut values = ramp();
    values[7] = f64::NAN;
    let file = npy(">f4", false, "(2, 2, 3)", &be_f32(&values));
    let e = Volume::from_bytes("v.npy", &file, &opts()).expect_err("NaN");
    // Voxel 7 = (i 1, j 0, k 1).
    assert!(
        matches!(
            e,
            VolumeError::NonFinite {
                i: 1,
                j: 0,
                k: 1,
                ..
            }
        ),
        "{e}"
    );
    values[7] = f64::INFINITY;
    let file = npy(">f4", false, "(2, 2, 3)", &be_f32(&values));
    assert!(matches!(
        Volume::from_bytes("v.npy", &file, &opts()),
        Err(VolumeError::NonFinite { .. })
    ));
    let labels = LoadOptions {
        labels: true,
        ..opts()
    };
    let ints = npy("<u2", false, "(2, 2, 3)", &le_u16(&ramp()));
    let v = Volume::from_bytes("v.npy", &ints, &labels).expect("labels");
    assert_eq!(
        v.voxels,
        Voxels::Labels(ramp().iter().map(|&x| x as u32).collect())
    );
    let mut fractional = ramp();
    fractional[2] = 1.5;
    let file = npy(
        "<f8",
        false,
        "(2, 2, 3)",
        &fractional
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect::<Vec<_>>(),
    );
    assert!(matches!(
        Volume::from_bytes("v.npy", &file, &labels),
        Err(VolumeError::NotALabel {
            i: 2,
            j: 0,
            k: 0,
            ..
        })
    ));
    let negative = npy("|i1", false, "(1, 1, 1)", &[0xff]);
    assert!(matches!(
        Volume::from_bytes("v.npy", &negative, &labels),
        Err(VolumeError::NotALabel { .. })
    ));
}

#[test]
fn metaimage_attached_compressed_and_detached() {
    let header = |extra: &str, data_file: &str| {
        format!(
            "ObjectType = Image\nNDims = 3\nDimSize = 3 2 2\nElementType = MET_USHORT\n\
             ElementSpacing = 0.5 1 2\nOffset = 1 2 3\n\
             TransformMatrix = 0 1 0 -1 0 0 0 0 1\n{extra}ElementDataFile = {data_file}\n"
        )
        .into_bytes()
    };
    let mut mha = header("BinaryDataByteOrderMSB = False\n", "LOCAL");
    mha.extend(le_u16(&ramp()));
    let v = Volume::from_bytes("v.mha", &mha, &opts()).expect("mha");
    assert_eq!(scalars(&v), ramp());
    // The first three numbers are the i axis's direction, scaled by its spacing.
    assert_eq!(
        v.affine,
        [[0.0, 0.5, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 2.0]]
    );
    assert_eq!(v.origin, [1.0, 2.0, 3.0]);

    let big: Vec<u8> = ramp()
        .iter()
        .flat_map(|&x| (x as u16).to_be_bytes())
        .collect();
    let mut compressed = header(
        &format!(
            "ElementByteOrderMSB = True\nCompressedData = True\nCompressedDataSize = {}\n",
            zlib(&big).len()
        ),
        "LOCAL",
    );
    compressed.extend(zlib(&big));
    let v = Volume::from_bytes("v.mha", &compressed, &opts()).expect("compressed");
    assert_eq!(scalars(&v), ramp());

    let dir = tempfile::tempdir().expect("temp dir");
    std::fs::write(dir.path().join("v.raw"), le_u16(&ramp())).expect("write raw");
    let mhd = header("", "v.raw");
    std::fs::write(dir.path().join("v.mhd"), &mhd).expect("write mhd");
    let v = Volume::load(&dir.path().join("v.mhd"), &opts()).expect("mhd");
    assert_eq!(scalars(&v), ramp());
    assert!(matches!(
        Volume::from_bytes("v.mhd", &mhd, &opts()),
        Err(VolumeError::Detached(..))
    ));
    // Missing data file, truncated data, no ElementDataFile, vector voxels.
    let e = Volume::load(&dir.path().join("none.mhd"), &opts()).expect_err("no header");
    assert!(matches!(e, VolumeError::Io { .. }), "{e}");
    assert!(matches!(
        Volume::from_bytes("v.mha", &mha[..mha.len() - 2], &opts()),
        Err(VolumeError::DataSize { .. })
    ));
    assert!(Volume::from_bytes("v.mha", b"NDims = 3\nDimSize = 1 1 1\n", &opts()).is_err());
    let mut rgb = header("ElementNumberOfChannels = 3\n", "LOCAL");
    rgb.extend(vec![0; 72]);
    assert!(Volume::from_bytes("v.mha", &rgb, &opts()).is_err());
}

#[test]
fn nrrd_raw_gzip_ascii_and_detached() {
    let header = |encoding: &str, extra: &str| {
        format!(
            "NRRD0004\n# a comment\ntype: float\ndimension: 3\nsizes: 3 2 2\nendian: big\n\
             encoding: {encoding}\nspace: right-anterior-superior\n\
             space directions: (0,0.5,0) (1,0,0) (0,0,2)\nspace origin: (1,2,3)\nfoo:=bar\n{extra}"
        )
        .into_bytes()
    };
    let mut raw = header("raw", "\n");
    raw.extend(be_f32(&ramp()));
    let v = Volume::from_bytes("v.nrrd", &raw, &opts()).expect("raw");
    assert_eq!(scalars(&v), ramp());
    assert_eq!(
        v.affine,
        [[0.0, 0.5, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 2.0]]
    );
    assert_eq!(v.origin, [1.0, 2.0, 3.0]);

    let mut gz = header("gzip", "\n");
    gz.extend(gzip(&be_f32(&ramp())));
    assert_eq!(
        scalars(&Volume::from_bytes("v.nrrd", &gz, &opts()).expect("gzip")),
        ramp()
    );

    let mut text = header("ascii", "\n");
    let words: Vec<String> = ramp().iter().map(f64::to_string).collect();
    text.extend(words.join("\n").into_bytes());
    assert_eq!(
        scalars(&Volume::from_bytes("v.nrrd", &text, &opts()).expect("ascii")),
        ramp()
    );
    let short_text = &text[..text.len() - 4];
    assert!(matches!(
        Volume::from_bytes("v.nrrd", short_text, &opts()),
        Err(VolumeError::DataSize { .. })
    ));

    let dir = tempfile::tempdir().expect("temp dir");
    std::fs::write(dir.path().join("v.raw.gz"), gzip(&be_f32(&ramp()))).expect("write data");
    let nhdr = header("gzip", "data file: v.raw.gz\n");
    std::fs::write(dir.path().join("v.nhdr"), &nhdr).expect("write nhdr");
    assert_eq!(
        scalars(&Volume::load(&dir.path().join("v.nhdr"), &opts()).expect("nhdr")),
        ramp()
    );
    assert!(matches!(
        Volume::from_bytes("v.nhdr", &nhdr, &opts()),
        Err(VolumeError::Detached(..))
    ));
    // Singular directions, a missing endian, a gzip bomb that claims few voxels.
    let edited = |from: &str, to: &str| {
        let mut file = String::from_utf8_lossy(&header("raw", "\n"))
            .replace(from, to)
            .into_bytes();
        file.extend(be_f32(&ramp()));
        Volume::from_bytes("v.nrrd", &file, &opts())
    };
    assert!(matches!(
        edited("(1,0,0)", "(0,1,0)"),
        Err(VolumeError::Transform(_))
    ));
    let e = edited("endian: big\n", "").expect_err("no endian");
    assert!(e.to_string().contains("endian is missing"), "{e}");
    let e = edited("(0,0,2)", "none").expect_err("none");
    assert!(e.to_string().contains("no `none`"), "{e}");
    let mut bomb = header("gzip", "\n");
    bomb.extend(gzip(&vec![0u8; 1 << 20]));
    assert!(matches!(
        Volume::from_bytes("v.nrrd", &bomb, &opts()),
        Err(VolumeError::DataSize {
            expected: 48,
            found: 49,
            ..
        })
    ));
}

fn inr(fields: &str, data: &[u8]) -> Vec<u8> {
    let mut header = format!("#INRIMAGE-4#{{\n{fields}").into_bytes();
    while (header.len() + 4) % 256 != 0 {
        header.push(b'\n');
    }
    header.extend(b"##}\n");
    header.extend(data);
    header
}

#[test]
fn inria_plain_gzip_scale_and_byte_order() {
    let fields = "XDIM=3\nYDIM=2\nZDIM=2\nVDIM=1\nTYPE=unsigned fixed\nPIXSIZE=16 bits\nSCALE=2**1\nCPU=decm\nVX=0.5\nVY=1\nVZ=2\n";
    let file = inr(fields, &le_u16(&ramp()));
    assert_eq!(file.len(), 256 + 24);
    for (name, bytes) in [("v.inr", file.clone()), ("v.inr.gz", gzip(&file))] {
        let v = Volume::from_bytes(name, &bytes, &opts()).expect(name);
        let half: Vec<f64> = ramp().iter().map(|x| x / 2.0).collect();
        assert_eq!(scalars(&v), half, "{name}");
        assert_eq!(v.affine, diagonal([0.5, 1.0, 2.0]));
    }
    let big = inr(
        "XDIM=3\nYDIM=2\nZDIM=2\nTYPE=float\nPIXSIZE=32 bits\nCPU=sun\n",
        &be_f32(&ramp()),
    );
    assert_eq!(
        scalars(&Volume::from_bytes("v.inr", &big, &opts()).expect("sun")),
        ramp()
    );
    assert!(matches!(
        Volume::from_bytes("v.inr", &file[..file.len() - 1], &opts()),
        Err(VolumeError::DataSize { .. })
    ));
    assert!(
        Volume::from_bytes(
            "v.inr",
            &inr("XDIM=3\nYDIM=2\nVDIM=3\nTYPE=float\nPIXSIZE=32 bits\n", &[]),
            &opts()
        )
        .is_err()
    );
    assert!(Volume::from_bytes("v.inr", b"#INRIMAGE-4#{\nXDIM=1\n", &opts()).is_err());
}

#[test]
fn names_spacing_and_missing_files() {
    assert_eq!(
        VolumeFormat::from_name("A.NII.GZ"),
        Some((VolumeFormat::Nifti, true))
    );
    assert_eq!(
        VolumeFormat::from_name("x.nhdr"),
        Some((VolumeFormat::Nrrd, false))
    );
    assert_eq!(VolumeFormat::from_name("x.npy.gz"), None);
    assert!(matches!(
        Volume::from_bytes("x.vol", b"", &opts()),
        Err(VolumeError::UnknownFormat(_))
    ));
    let spacing = LoadOptions {
        spacing: Some([1.0; 3]),
        ..opts()
    };
    assert!(matches!(
        Volume::from_bytes("x.nii", b"", &spacing),
        Err(VolumeError::SpacingNotAllowed(VolumeFormat::Nifti))
    ));
    assert!(matches!(
        Volume::load(Path::new("/nonexistent/x.nii"), &opts()),
        Err(VolumeError::Io { .. })
    ));
    // Zero or non-finite spacing makes a singular or non-finite transform.
    let file = npy("|u1", false, "(1, 1, 1)", &[7]);
    for bad in [[0.0, 1.0, 1.0], [f64::NAN, 1.0, 1.0]] {
        let options = LoadOptions {
            spacing: Some(bad),
            ..opts()
        };
        assert!(matches!(
            Volume::from_bytes("x.npy", &file, &options),
            Err(VolumeError::Transform(_))
        ));
    }
}

/// A `.vti` around one point-data array element (`data_array`) and optional appended data.
fn vti(file_attrs: &str, data_array: &str, appended: Option<(&str, &[u8])>) -> Vec<u8> {
    let mut out = format!(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"ImageData\" version=\"1.0\" {file_attrs}>\n\
         <ImageData WholeExtent=\"1 3 0 1 2 3\" Origin=\"10 20 30\" Spacing=\"0.5 1 2\" \
         Direction=\"0 -1 0 1 0 0 0 0 1\">\n<Piece Extent=\"1 3 0 1 2 3\">\n\
         <PointData Scalars=\"density\">\n<DataArray type=\"Float32\" Name=\"other\" format=\"ascii\">1</DataArray>\n\
         {data_array}\n</PointData>\n<CellData/>\n</Piece>\n</ImageData>\n"
    )
    .into_bytes();
    if let Some((encoding, bytes)) = appended {
        out.extend(format!("<AppendedData encoding=\"{encoding}\">\n_").into_bytes());
        out.extend(bytes);
        out.extend(b"\n</AppendedData>\n");
    }
    out.extend(b"</VTKFile>\n");
    out
}

fn b64(bytes: &[u8]) -> String {
    use base64::Engine;
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

/// The VTK zlib framing: `[blocks, block, last, sizes…]` as u64 little endian, then the blocks.
fn vtk_zlib(data: &[u8], block: usize) -> (Vec<u8>, Vec<u8>) {
    let chunks: Vec<Vec<u8>> = data.chunks(block).map(zlib).collect();
    let last = data.len() - block * (chunks.len() - 1);
    let mut header: Vec<u64> = vec![chunks.len() as u64, block as u64, last as u64];
    header.extend(chunks.iter().map(|c| c.len() as u64));
    (
        header.iter().flat_map(|w| w.to_le_bytes()).collect(),
        chunks.concat(),
    )
}

#[test]
fn vti_every_data_format_and_its_transform() {
    let data: Vec<u8> = ramp()
        .iter()
        .flat_map(|&x| (x as f32).to_le_bytes())
        .collect();
    let array = |format: &str, extra: &str, body: &str| {
        format!(
            "<DataArray type=\"Float32\" Name=\"density\" format=\"{format}\" {extra}>{body}</DataArray>"
        )
    };
    let words: Vec<String> = ramp().iter().map(f64::to_string).collect();
    let mut one_stream = 48u32.to_le_bytes().to_vec();
    one_stream.extend(&data);
    let (zheader, zblocks) = vtk_zlib(&data, 20);
    let mut appended_raw = 48u32.to_le_bytes().to_vec();
    appended_raw.extend(&data);
    let mut appended_z = zheader.clone();
    appended_z.extend(&zblocks);
    let cases: Vec<(&str, Vec<u8>)> = vec![
        (
            "ascii",
            vti("", &array("ascii", "", &words.join(" ")), None),
        ),
        (
            "binary",
            vti("", &array("binary", "", &b64(&one_stream)), None),
        ),
        (
            "binary, header encoded apart",
            vti(
                "",
                &array(
                    "binary",
                    "",
                    &format!("{}{}", b64(&48u32.to_le_bytes()), b64(&data)),
                ),
                None,
            ),
        ),
        (
            "binary, zlib",
            vti(
                "header_type=\"UInt64\" compressor=\"vtkZLibDataCompressor\"",
                &array("binary", "", &format!("{}{}", b64(&zheader), b64(&zblocks))),
                None,
            ),
        ),
        (
            "appended raw",
            vti(
                "",
                &array("appended", "offset=\"0\"", ""),
                Some(("raw", &appended_raw)),
            ),
        ),
        (
            "appended raw, zlib",
            vti(
                "header_type=\"UInt64\" compressor=\"vtkZLibDataCompressor\"",
                &array("appended", "offset=\"0\"", ""),
                Some(("raw", &appended_z)),
            ),
        ),
        (
            "appended base64 at an offset",
            vti(
                "",
                &array("appended", "offset=\"4\"", ""),
                Some(("base64", format!("AAAA{}", b64(&one_stream)).as_bytes())),
            ),
        ),
    ];
    for (name, file) in &cases {
        let v =
            Volume::from_bytes("v.vti", file, &opts()).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(v.format, VolumeFormat::Vti);
        assert_eq!(v.dims, [3, 2, 2], "{name}");
        assert_eq!(scalars(&v), ramp(), "{name}");
        // Direction rows (0 −1 0; 1 0 0; 0 0 1): i steps along +y, j along −x; spacing scales.
        assert_eq!(
            v.affine,
            [[0.0, 0.5, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 2.0]],
            "{name}"
        );
        // The extent starts at (1, 0, 2): voxel (0, 0, 0) sits at Origin + D·(S ⊙ (1, 0, 2)).
        assert_eq!(v.origin, [10.0, 20.5, 34.0], "{name}");
    }
    // Refusals: truncated appended data, a wrong byte count, several pieces, cell data only,
    // a missing Scalars array, vector data.
    let cut = vti(
        "",
        &array("appended", "offset=\"0\"", ""),
        Some(("raw", &appended_raw[..30])),
    );
    assert!(Volume::from_bytes("v.vti", &cut, &opts()).is_err());
    let mut wrong = 44u32.to_le_bytes().to_vec();
    wrong.extend(&data[..44]);
    let wrong = vti("", &array("binary", "", &b64(&wrong)), None);
    assert!(matches!(
        Volume::from_bytes("v.vti", &wrong, &opts()),
        Err(VolumeError::DataSize { .. })
    ));
    let pieces = String::from_utf8_lossy(&cases[0].1).replace(
        "<Piece Extent=\"1 3 0 1 2 3\"",
        "<Piece Extent=\"1 2 0 1 2 3\"",
    );
    assert!(Volume::from_bytes("v.vti", pieces.as_bytes(), &opts()).is_err());
    let cells = "<?xml version=\"1.0\"?><VTKFile type=\"ImageData\"><ImageData WholeExtent=\"0 1 0 1 0 1\">\
                 <Piece Extent=\"0 1 0 1 0 1\"><CellData><DataArray type=\"UInt8\" format=\"ascii\">1</DataArray>\
                 </CellData></Piece></ImageData></VTKFile>";
    let e = Volume::from_bytes("v.vti", cells.as_bytes(), &opts()).expect_err("cells");
    assert!(e.to_string().contains("cell data"), "{e}");
    let renamed =
        String::from_utf8_lossy(&cases[0].1).replace("Scalars=\"density\"", "Scalars=\"absent\"");
    assert!(Volume::from_bytes("v.vti", renamed.as_bytes(), &opts()).is_err());
    let vector = String::from_utf8_lossy(&cases[0].1).replace(
        "Name=\"density\"",
        "Name=\"density\" NumberOfComponents=\"3\"",
    );
    assert!(Volume::from_bytes("v.vti", vector.as_bytes(), &opts()).is_err());
    assert!(
        Volume::from_bytes("v.vti", b"<VTKFile type=\"PolyData\"></VTKFile>", &opts()).is_err()
    );
    assert!(Volume::from_bytes("v.vti", b"\xff\xfe<", &opts()).is_err());
}

mod transfer_and_raycast {
    //! DESIGN §9's transfer function and integration checked against closed forms: a constant
    //! volume composites to `1 − (1 − a)^(L/ref_step)`, a ramp samples to its own value, labels
    //! take the nearest voxel, shading follows the gradient's angle to the light. Tolerance
    //! 1e-12: the ray caster works in f64 and these are a handful of operations per sample.

    use super::super::raycast::{
        EARLY_STOP_ALPHA, RaycastError, RaycastOptions, Segment, SplitRule, VolumeRays, raycast,
    };
    use super::super::tf::{PRESETS, TfError, TransferFunction, opacity_for_step};
    use super::super::{Volume, VolumeFormat, VoxelType, Voxels, diagonal};
    use crate::view::View;

    const EPS: f64 = 1e-12;

    fn volume(dims: [u32; 3], f: impl Fn(u32, u32, u32) -> f32) -> Volume {
        let mut v = Vec::new();
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    v.push(f(i, j, k));
                }
            }
        }
        Volume {
            dims,
            voxels: Voxels::Scalar(v),
            affine: diagonal([1.0; 3]),
            origin: [0.0; 3],
            voxel_type: VoxelType::F32,
            format: VolumeFormat::Npy,
        }
    }

    /// One pixel looking along +z through index column (x, y).
    fn ray_view(x: f64, y: f64) -> View {
        View::look_at([x, y, -10.0], [x, y, 0.0], 40.0, 1, 1)
    }

    fn constant_tf(rgb: [f64; 3], a: f64) -> TransferFunction {
        TransferFunction::Scalar {
            points: vec![
                [0.0, rgb[0], rgb[1], rgb[2], a],
                [10.0, rgb[0], rgb[1], rgb[2], a],
            ],
            ref_step: None,
        }
    }

    #[test]
    fn transfer_function_json_presets_and_eval() {
        let tf = TransferFunction::from_json(
            r#"{"points": [[0, 0, 0, 0, 0], [10, 1, 0.5, 0, 0.8], [10, 0, 0, 1, 1], [20, 0, 0, 1, 0]], "ref_step": 2}"#,
        )
        .expect("tf");
        assert_eq!(tf.eval(-5.0), [0.0; 4]);
        let mid = tf.eval(5.0);
        assert!(
            (mid[0] - 0.5).abs() < EPS && (mid[1] - 0.25).abs() < EPS && (mid[3] - 0.4).abs() < EPS
        );
        // At a step the later point wins; beyond the end the last point holds.
        assert_eq!(tf.eval(10.0), [0.0, 0.0, 1.0, 1.0]);
        assert_eq!(tf.eval(15.0), [0.0, 0.0, 1.0, 0.5]);
        assert_eq!(tf.eval(99.0), [0.0, 0.0, 1.0, 0.0]);
        let labels =
            TransferFunction::from_json(r#"{"labels": {"3": [1, 0, 0, 0.5]}}"#).expect("labels");
        assert_eq!(labels.eval(3.0), [1.0, 0.0, 0.0, 0.5]);
        assert_eq!(labels.eval(2.0), [0.0; 4]);
        for bad in [
            r#"{"points": [[1, 0, 0, 0, 0], [0, 0, 0, 0, 0]]}"#,
            r#"{"points": [[0, 0, 0, 0, 1.5]]}"#,
            r#"{"points": []}"#,
            r#"{"points": [[0, 0, 0, 0, 0]], "ref_step": 0}"#,
            r#"{"points": [[0, 0, 0, 0, 0]], "labels": {}}"#,
            r#"{"labels": {"-1": [0, 0, 0, 0]}}"#,
            r#"{"labels": {"a": [0, 0, 0, 0]}}"#,
            r#"{"points": [[0, 0, 0, 0, 0]], "extra": 1}"#,
            "[1, 2]",
        ] {
            assert!(TransferFunction::from_json(bad).is_err(), "{bad}");
        }
        for name in PRESETS {
            let tf = TransferFunction::preset(name).expect(name);
            assert_eq!(tf.validate(), Ok(()), "{name}");
        }
        assert_eq!(
            TransferFunction::preset("ct-lung"),
            Err(TfError::UnknownPreset("ct-lung".into()))
        );
        assert!((opacity_for_step(0.5, 1.0, 1.0) - 0.5).abs() < EPS);
        assert!((opacity_for_step(0.5, 0.5, 1.0) - (1.0 - 0.5f64.sqrt())).abs() < EPS);
        assert_eq!(opacity_for_step(1.0, 0.1, 1.0), 1.0);
        assert_eq!(opacity_for_step(0.0, 0.1, 1.0), 0.0);
    }

    #[test]
    fn a_constant_slab_composites_to_the_closed_form() {
        // Box [−½, 3½]³; the ray along +z enters at t = 9.5 and leaves at 13.5 (L = 4).
        let v = volume([4, 4, 4], |_, _, _| 1.0);
        let rgb = [1.0, 0.6, 0.2];
        // Δ = ref_step/2 = 0.5: samples at 9.75, 10.25, …, 13.25 (8 samples).
        let img = raycast(
            &v,
            &constant_tf(rgb, 0.1),
            &ray_view(1.5, 1.5),
            &RaycastOptions::default(),
        )
        .expect("cast");
        let want_a = 1.0 - 0.9f64.powf(4.0);
        let [r, g, b, a] = img.rgba[0];
        assert!((a - want_a).abs() < EPS, "{a} vs {want_a}");
        for (got, c) in [r, g, b].into_iter().zip(rgb) {
            assert!((got - c * want_a).abs() < EPS);
        }
        assert_eq!(img.samples, 8);
        assert!(
            img.depth[0].is_infinite(),
            "A = {a} never reaches τ_d = 0.5"
        );
        assert_eq!(img.coverage(), vec![true]);
        // a = 0.5: A = 1 − 0.5^(n/2) reaches 0.45 at the second sample, t = 10.25.
        // (τ_d = 0.45, not 0.5: 1 − (1 − α)² rounds to just below 0.5 in f64.)
        let options = RaycastOptions {
            depth_threshold: 0.45,
            ..RaycastOptions::default()
        };
        let img = raycast(&v, &constant_tf(rgb, 0.5), &ray_view(1.5, 1.5), &options).expect("cast");
        assert!((img.depth[0] - 10.25).abs() < EPS, "{}", img.depth[0]);
        // a = 0.99: α = 0.9 per sample, A = 0.9, 0.99, 0.999 ≥ 0.995: three samples, then stop.
        let img = raycast(
            &v,
            &constant_tf(rgb, 0.99),
            &ray_view(1.5, 1.5),
            &RaycastOptions::default(),
        )
        .expect("cast");
        assert_eq!(img.samples, 3);
        assert!(img.rgba[0][3] >= EARLY_STOP_ALPHA && (img.rgba[0][3] - 0.999).abs() < EPS);
        // A given step and τ_d: Δ = 4/3 gives samples at 10.1667, 11.5, 12.8333 (3).
        let options = RaycastOptions {
            step: Some(4.0 / 3.0),
            depth_threshold: 0.2,
            ..RaycastOptions::default()
        };
        let img = raycast(&v, &constant_tf(rgb, 0.1), &ray_view(1.5, 1.5), &options).expect("cast");
        assert_eq!(img.samples, 3);
        let want_a = 1.0 - 0.9f64.powf(4.0);
        assert!((img.rgba[0][3] - want_a).abs() < EPS);
        // α per sample 1 − 0.9^(4/3) = 0.1313 < 0.2; two samples give 0.2455: depth 11.5.
        assert!((img.depth[0] - 11.5).abs() < 1e-9, "{}", img.depth[0]);
        // Outside the box: nothing; the eye inside: the ray starts at t = 0 (L = 3.5 − 2 = 1.5).
        let img = raycast(
            &v,
            &constant_tf(rgb, 0.1),
            &ray_view(5.0, 1.5),
            &RaycastOptions::default(),
        )
        .expect("cast");
        assert_eq!(
            (img.rgba[0], img.samples, img.coverage()),
            ([0.0; 4], 0, vec![false])
        );
        let inside = View::look_at([1.5, 1.5, 2.0], [1.5, 1.5, 5.0], 40.0, 1, 1);
        let img = raycast(
            &v,
            &constant_tf(rgb, 0.1),
            &inside,
            &RaycastOptions::default(),
        )
        .expect("cast");
        assert!((img.rgba[0][3] - (1.0 - 0.9f64.powf(1.5))).abs() < EPS);
        let frame = img.to_frame();
        assert_eq!(frame.color[3], (255.0 * img.rgba[0][3]).round() as u8);
        // Straight colour: C/A = rgb, 255·rgb rounded (153 and 51 lie far from a rounding edge).
        let want: Vec<u8> = rgb.iter().map(|c| (255.0 * c).round() as u8).collect();
        assert_eq!(&frame.color[..3], &want[..]);
    }

    #[test]
    fn trilinear_samples_clamp_at_the_edges_and_labels_take_the_nearest_voxel() {
        // Value = i: the straight colour is value / 4 wherever the opacity is constant.
        let ramp = volume([4, 2, 2], |i, _, _| i as f32);
        let tf = TransferFunction::Scalar {
            points: vec![[0.0, 0.0, 0.0, 0.0, 0.05], [4.0, 1.0, 1.0, 1.0, 0.05]],
            ref_step: None,
        };
        for (x, value) in [(1.25, 1.25), (2.5, 2.5), (-0.4, 0.0), (3.4, 3.0)] {
            let img =
                raycast(&ramp, &tf, &ray_view(x, 0.5), &RaycastOptions::default()).expect("cast");
            let [r, _, _, a] = img.rgba[0];
            assert!(
                (r / a - value / 4.0).abs() < EPS,
                "x {x}: {} vs {}",
                r / a,
                value / 4.0
            );
        }
        let labels = Volume {
            voxels: Voxels::Labels((0..16).map(|n| if n % 4 >= 2 { 3 } else { 0 }).collect()),
            ..ramp.clone()
        };
        let tf = TransferFunction::from_json(r#"{"labels": {"3": [0, 1, 0, 0.5]}}"#).expect("tf");
        let at = |x: f64| {
            raycast(&labels, &tf, &ray_view(x, 0.5), &RaycastOptions::default())
                .expect("cast")
                .rgba[0]
        };
        assert_eq!(at(1.4), [0.0; 4]);
        let [r, g, _, a] = at(1.6);
        assert!(r == 0.0 && (g - a).abs() < EPS && a > 0.0);
        // Mismatched TFs and shading on labels are refused.
        assert!(matches!(
            raycast(
                &labels,
                &constant_tf([1.0; 3], 0.5),
                &ray_view(1.0, 0.5),
                &RaycastOptions::default()
            ),
            Err(RaycastError::Mismatch(_))
        ));
        assert!(matches!(
            raycast(&ramp, &tf, &ray_view(1.0, 0.5), &RaycastOptions::default()),
            Err(RaycastError::Mismatch(_))
        ));
        let shade = RaycastOptions {
            shade: true,
            ..RaycastOptions::default()
        };
        assert!(matches!(
            raycast(&labels, &tf, &ray_view(1.0, 0.5), &shade),
            Err(RaycastError::Options(_))
        ));
        for bad in [
            RaycastOptions {
                step: Some(0.0),
                ..RaycastOptions::default()
            },
            RaycastOptions {
                step: Some(f64::NAN),
                ..RaycastOptions::default()
            },
            RaycastOptions {
                step: Some(1e-9),
                ..RaycastOptions::default()
            },
            RaycastOptions {
                depth_threshold: 0.0,
                ..RaycastOptions::default()
            },
            RaycastOptions {
                light: [0.0; 3],
                ..RaycastOptions::default()
            },
            RaycastOptions {
                ambient: 2.0,
                ..RaycastOptions::default()
            },
        ] {
            assert!(
                raycast(
                    &ramp,
                    &constant_tf([1.0; 3], 0.5),
                    &ray_view(1.0, 0.5),
                    &bad
                )
                .is_err(),
                "{bad:?}"
            );
        }
        let bad_view = View::look_at([0.0; 3], [0.0; 3], 40.0, 1, 1);
        assert!(matches!(
            raycast(
                &ramp,
                &constant_tf([1.0; 3], 0.5),
                &bad_view,
                &RaycastOptions::default()
            ),
            Err(RaycastError::View(_))
        ));
    }

    #[test]
    fn shading_follows_the_gradient_and_leaves_flat_regions_unshaded() {
        // S = i: ∇S = (1, 0, 0) in the interior, so the factor is ambient + (1 − ambient)·|ℓx|.
        let ramp = volume([6, 3, 3], |i, _, _| i as f32);
        let options = RaycastOptions {
            shade: true,
            light: [0.6, 0.8, 0.0],
            ambient: 0.25,
            ..RaycastOptions::default()
        };
        let img = raycast(
            &ramp,
            &constant_tf([0.8, 0.8, 0.8], 0.2),
            &ray_view(2.0, 1.0),
            &options,
        )
        .expect("cast");
        let [r, _, _, a] = img.rgba[0];
        assert!((r / a - 0.8 * (0.25 + 0.75 * 0.6)).abs() < EPS, "{}", r / a);
        // A flat volume has no gradient: the TF colour unchanged.
        let flat = volume([6, 3, 3], |_, _, _| 2.0);
        let img = raycast(
            &flat,
            &constant_tf([0.8, 0.8, 0.8], 0.2),
            &ray_view(2.0, 1.0),
            &options,
        )
        .expect("cast");
        assert!((img.rgba[0][0] / img.rgba[0][3] - 0.8).abs() < EPS);
    }

    #[test]
    fn a_permuted_affine_renders_the_same_as_its_axis_aligned_twin() {
        // The same world object stored with i and k swapped: index (i, j, k) of `swapped` is
        // index (k, j, i) of `plain`, and its affine's columns swap too.
        let f = |i: u32, j: u32, k: u32| (i * 3 + j * 7 + k * 11) as f32 % 5.0;
        let plain = Volume {
            affine: diagonal([0.5, 1.0, 2.0]),
            origin: [1.0, -2.0, 3.0],
            ..volume([4, 3, 5], f)
        };
        let swapped = Volume {
            affine: [[0.0, 0.0, 2.0], [0.0, 1.0, 0.0], [0.5, 0.0, 0.0]],
            origin: [1.0, -2.0, 3.0],
            ..volume([5, 3, 4], |i, j, k| f(k, j, i))
        };
        let tf = TransferFunction::Scalar {
            points: vec![[0.0, 1.0, 0.0, 0.0, 0.0], [5.0, 0.0, 0.0, 1.0, 0.6]],
            ref_step: Some(0.5),
        };
        let view = View::look_at([9.0, 2.0, 4.0], [1.75, -1.0, 7.0], 50.0, 24, 16);
        let options = RaycastOptions {
            shade: true,
            ..RaycastOptions::default()
        };
        let a = raycast(&plain, &tf, &view, &options).expect("plain");
        let b = raycast(&swapped, &tf, &view, &options).expect("swapped");
        let covered = a.coverage().iter().filter(|&&c| c).count();
        assert!(covered > 60, "{covered} of 384 pixels covered");
        for (p, q) in a.rgba.iter().zip(&b.rgba) {
            for c in 0..4 {
                assert!((p[c] - q[c]).abs() < 1e-9, "{p:?} vs {q:?}");
            }
        }
        assert_eq!(a.samples, b.samples);
    }

    /// The rays of segment `index` of `split`.
    fn segment_rays<'a>(
        v: &'a Volume,
        tf: &'a TransferFunction,
        options: &RaycastOptions,
        split: &SplitRule,
        index: usize,
    ) -> VolumeRays<'a> {
        VolumeRays::new(v, tf, options)
            .and_then(|r| {
                r.with_segment(Some(Segment {
                    split: split.clone(),
                    index,
                }))
            })
            .expect("segment")
    }

    /// Asserts that `segments` (premultiplied RGBA, nearest first) composited front to back,
    /// `C += (1 − A)·C_i`, `A += (1 − A)·A_i`, give the whole ray's `whole` within EPS (f64
    /// sums of a few hundred terms, regrouped: far below 1e-12).
    fn assert_segments_compose(segments: &[[f64; 4]], whole: [f64; 4], what: &str) {
        let (mut c, mut a) = ([0.0; 3], 0.0);
        for s in segments {
            for k in 0..3 {
                c[k] += (1.0 - a) * s[k];
            }
            a += (1.0 - a) * s[3];
        }
        for k in 0..3 {
            assert!(
                (c[k] - whole[k]).abs() < EPS,
                "{what} {k}: {c:?} vs {whole:?}"
            );
        }
        assert!((a - whole[3]).abs() < EPS, "{what}: A {a} vs {}", whole[3]);
    }

    #[test]
    fn depth_layer_segments_composite_to_the_whole_ray_exactly() {
        // A ramp along z with a dense band: every split rule cuts the ray somewhere inside.
        let v = Volume {
            affine: diagonal([0.7, 0.7, 0.9]),
            ..volume([6, 6, 24], |i, j, k| {
                (k as f32) * 4.0 + if (10..14).contains(&k) { 40.0 } else { 0.0 } + (i + j) as f32
            })
        };
        let tf = TransferFunction::Scalar {
            points: vec![
                [0.0, 0.2, 0.3, 0.9, 0.0],
                [20.0, 0.9, 0.4, 0.2, 0.15],
                [90.0, 1.0, 1.0, 0.6, 0.35],
                [140.0, 0.5, 0.9, 0.5, 0.6],
            ],
            ref_step: Some(0.7),
        };
        let options = RaycastOptions {
            shade: true,
            ..RaycastOptions::default()
        };
        let whole = VolumeRays::new(&v, &tf, &options).expect("rays");
        let eye = [2.0, 1.5, -6.0];
        for split in [
            SplitRule::Opacity(vec![0.2, 0.6]),
            SplitRule::Opacity(vec![0.05, 0.1, 0.15, 0.9]),
            SplitRule::Value(vec![30.0, 80.0]),
            // Isovalues reached at one sample (the band): an empty segment in between.
            SplitRule::Value(vec![60.0, 61.0]),
        ] {
            let n = split.boundary_count() + 1;
            for dir in [[0.0, 0.0, 1.0], [0.1, 0.05, 1.0], [-0.02, 0.2, 1.0]] {
                let dir = glam::DVec3::from(dir).normalize().to_array();
                let full = whole.cast(eye, dir);
                let segments: Vec<[f64; 4]> = (0..n)
                    .map(|index| {
                        segment_rays(&v, &tf, &options, &split, index)
                            .cast(eye, dir)
                            .rgba
                    })
                    .collect();
                let gathered = segments.iter().filter(|s| s[3] > 0.0).count();
                assert_segments_compose(&segments, full.rgba, &format!("{split:?}"));
                // The last rule fires both events at one sample and may leave the rest of the
                // ray to the early stop: only the first three must cut every ray.
                if split != SplitRule::Value(vec![60.0, 61.0]) {
                    assert!(
                        gathered >= 2,
                        "{split:?}: the split cuts the ray ({gathered} segments)"
                    );
                }
            }
        }
        // The opacity rule places its cut where A reaches the threshold: segment 0 ends with the
        // sample that crossed 0.4, so its A is at least 0.4 and less than 0.4 plus that sample.
        let seg0 = VolumeRays::new(&v, &tf, &options)
            .and_then(|r| {
                r.with_segment(Some(Segment {
                    split: SplitRule::Opacity(vec![0.4]),
                    index: 0,
                }))
            })
            .expect("segment")
            .cast(eye, [0.0, 0.0, 1.0]);
        assert!(
            seg0.rgba[3] >= 0.4 && seg0.rgba[3] < 0.55,
            "{:?}",
            seg0.rgba
        );
        // A segment beyond the boundaries, and a value split of labels, are refused.
        let beyond = VolumeRays::new(&v, &tf, &options)
            .expect("rays")
            .with_segment(Some(Segment {
                split: SplitRule::Opacity(vec![0.5]),
                index: 2,
            }));
        assert!(matches!(beyond, Err(RaycastError::Options(_))));
        let labels = Volume {
            voxels: Voxels::Labels(vec![1; 8]),
            ..volume([2, 2, 2], |_, _, _| 0.0)
        };
        let ltf = TransferFunction::from_json(r#"{"labels": {"1": [1, 0, 0, 0.5]}}"#).expect("tf");
        let by_value = VolumeRays::new(&labels, &ltf, &RaycastOptions::default())
            .expect("rays")
            .with_segment(Some(Segment {
                split: SplitRule::Value(vec![1.0]),
                index: 0,
            }));
        assert!(matches!(by_value, Err(RaycastError::Options(_))));
    }

    #[test]
    fn label_transitions_start_a_new_segment_with_the_new_label() {
        // Nested shells: label 1 outside, 2, then 3 at the centre; a ray through the centre
        // meets 1, 2, 3, 2, 1.
        let n = 15u32;
        let c = 7.0f64;
        let mut labels = Vec::new();
        for k in 0..n {
            for j in 0..n {
                for i in 0..n {
                    let r = ((f64::from(i) - c).powi(2)
                        + (f64::from(j) - c).powi(2)
                        + (f64::from(k) - c).powi(2))
                    .sqrt();
                    // 3 inside r 2.5, 2 inside 4.5, 1 inside 6.5, 0 beyond.
                    labels.push([2.5, 4.5, 6.5].iter().filter(|&&edge| r < edge).count() as u32);
                }
            }
        }
        let v = Volume {
            voxels: Voxels::Labels(labels),
            ..volume([n, n, n], |_, _, _| 0.0)
        };
        let tf = TransferFunction::from_json(
            r#"{"labels": {"1": [1, 0, 0, 0.1], "2": [0, 1, 0, 0.15], "3": [0, 0, 1, 0.3]}}"#,
        )
        .expect("tf");
        let options = RaycastOptions::default();
        let (eye, dir) = ([7.0, 7.0, -10.0], [0.0, 0.0, 1.0]);
        let whole = VolumeRays::new(&v, &tf, &options)
            .expect("rays")
            .cast(eye, dir);
        let segment = |transitions: usize, index: usize| {
            segment_rays(&v, &tf, &options, &SplitRule::Labels(transitions), index)
                .cast(eye, dir)
                .rgba
        };
        for transitions in [1, 2, 4, 6] {
            let segments: Vec<[f64; 4]> = (0..=transitions)
                .map(|index| segment(transitions, index))
                .collect();
            assert_segments_compose(&segments, whole.rgba, &format!("{transitions} transitions"));
        }
        // With four transitions each segment holds one shell crossing: its colour is that
        // label's alone (red, green, blue, green, red); a fifth transition never comes.
        let expect = [
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
        ];
        for (index, rgb) in expect.iter().enumerate() {
            let s = segment(4, index);
            assert!(s[3] > 0.0, "segment {index} holds its shell");
            for k in 0..3 {
                assert!((s[k] / s[3] - rgb[k]).abs() < EPS, "segment {index}: {s:?}");
            }
        }
        assert_eq!(segment(6, 5), [0.0; 4]);
        assert_eq!(segment(6, 6), [0.0; 4]);
        // Label transitions are for label volumes only.
        let scalar = volume([2, 2, 2], |_, _, _| 1.0);
        let stf = constant_tf([1.0, 1.0, 1.0], 0.5);
        let refused = VolumeRays::new(&scalar, &stf, &options)
            .expect("rays")
            .with_segment(Some(Segment {
                split: SplitRule::Labels(1),
                index: 0,
            }));
        assert!(matches!(refused, Err(RaycastError::Options(_))));
    }
}
