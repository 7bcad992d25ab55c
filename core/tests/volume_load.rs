//! The volume readers on a real file made by others: the MNI152 T1 template shipped in
//! nilearn's wheel (dev fixtures, `scripts/fixtures.sh`), a gzip-compressed NIfTI-1 with an
//! sform. The expected numbers were read from the file independently, with Python's `gzip` and
//! `struct` on the raw header fields and bytes (exact: integer voxels, exactly representable
//! transform values).

mod common;

use lumigraph_core::volume::{LoadOptions, Volume, VolumeFormat, VoxelType, Voxels};

#[test]
fn mni_t1_template_reads_with_its_sform_and_exact_values() {
    let path = common::fixtures_dir().join("volume/mni_t1.nii.gz");
    let volume = Volume::load(&path, &LoadOptions::default()).expect("MNI T1");
    assert_eq!(volume.format, VolumeFormat::Nifti);
    assert_eq!(volume.voxel_type, VoxelType::U8);
    assert_eq!(volume.dims, [197, 233, 189]);
    // sform_code 2: identity columns (1 mm voxels), origin (−98, −134, −72) mm.
    assert_eq!(
        volume.affine,
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    );
    assert_eq!(volume.origin, [-98.0, -134.0, -72.0]);
    assert_eq!(volume.world([98.0, 134.0, 72.0]), [0.0, 0.0, 0.0]);
    let Voxels::Scalar(values) = &volume.voxels else {
        panic!("scalar volume expected");
    };
    assert_eq!(values.len(), 197 * 233 * 189);
    // Sum and non-zero count over all 8 675 289 voxels, and one voxel inside the brain.
    let sum: f64 = values.iter().map(|&v| f64::from(v)).sum();
    assert_eq!(sum, 333_468_829.0);
    assert_eq!(values.iter().filter(|&&v| v > 0.0).count(), 1_886_539);
    assert_eq!(values[98 + 197 * (116 + 233 * 94)], 198.0);
    assert_eq!(volume.range(), (0.0, 255.0));

    // The same file as labels (integer voxels) and from its bytes.
    let bytes = std::fs::read(&path).expect("read");
    let labels = Volume::from_bytes(
        "mni_t1.nii.gz",
        &bytes,
        &LoadOptions {
            labels: true,
            ..LoadOptions::default()
        },
    )
    .expect("labels");
    let Voxels::Labels(labels) = &labels.voxels else {
        panic!("labels expected");
    };
    assert_eq!(
        labels.iter().map(|&l| u64::from(l)).sum::<u64>(),
        333_468_829
    );

    // Every truncation of the compressed file is refused with an error, never a panic.
    for cut in [10, 200, bytes.len() / 2, bytes.len() - 1] {
        assert!(
            Volume::from_bytes("mni_t1.nii.gz", &bytes[..cut], &LoadOptions::default()).is_err(),
            "cut at {cut}"
        );
    }
}

/// The reference ray caster on the real MRI with the `mri-brain` preset: a head-shaped
/// footprint, opaque white matter giving depths inside the head's box, nothing non-finite.
#[test]
fn mni_t1_ray_casts_with_the_mri_brain_preset() {
    use lumigraph_core::view::View;
    use lumigraph_core::volume::raycast::{RaycastOptions, raycast};
    use lumigraph_core::volume::tf::TransferFunction;

    let path = common::fixtures_dir().join("volume/mni_t1.nii.gz");
    let volume = Volume::load(&path, &LoadOptions::default()).expect("MNI T1");
    let tf = TransferFunction::preset("mri-brain").expect("preset");
    // From the front (+y in MNI space is anterior), 300 mm away, the head fills the frame's middle.
    let view = View::look_at([0.0, 300.0, 0.0], [0.0, -18.0, 22.0], 45.0, 96, 96);
    let options = RaycastOptions {
        shade: true,
        ..RaycastOptions::default()
    };
    let image = raycast(&volume, &tf, &view, &options).expect("ray cast");
    let covered = image.coverage().iter().filter(|&&c| c).count();
    let total = 96 * 96;
    // The head's box (197 × 189 mm seen from the front) spans about 60 % of the frame; the
    // head within it covers about half of the box.
    assert!(
        (total / 10..total * 7 / 10).contains(&covered),
        "{covered} of {total} pixels covered"
    );
    assert!(
        image
            .rgba
            .iter()
            .flatten()
            .all(|x| x.is_finite() && (0.0..=1.0 + 1e-12).contains(x))
    );
    let deep: Vec<f64> = image
        .depth
        .iter()
        .copied()
        .filter(|d| d.is_finite())
        .collect();
    assert!(!deep.is_empty(), "white matter reaches τ_d somewhere");
    // Depths lie within the head's box: the eye is 300 mm from the origin, the box ±117 mm deep.
    assert!(
        deep.iter()
            .all(|&d| (300.0 - 18.0 - 120.0..300.0 + 120.0).contains(&d)),
        "{deep:?}"
    );
}
