//! Block compression of pages (docs/format.md §7.1): BC1 and BC7 colour, BC4 depth codes, in
//! 4 × 4 texel blocks that GPUs sample directly.
//!
//! Encoders: BC1 through `texpresso` (libsquish's cluster fit, with BC1's punch-through alpha,
//! which the coverage in the alpha channel needs: a texel with A < 128 decodes to (0, 0, 0, 0));
//! BC4 and BC7 through `block_compression` (Intel's ISPC texture compressor ported to Rust).
//! Decoders: the same crates, bit-exact to the BC specification's integer decoding.

use serde::{Deserialize, Serialize};

use super::header::{Channel, Encoding};

/// Texels per block side.
pub const BLOCK: u32 = 4;

/// How a channel's pages are block-compressed: the decoded texels are in the channel's encoding.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BlockCodec {
    /// 8 bytes per block (4 bits per texel): two RGB565 end points and 2-bit indices; alpha
    /// 255 or 0 (then the texel is (0, 0, 0, 0)). Colour in `rgba8`.
    Bc1,
    /// 16 bytes per block (8 bits per texel): RGBA with partitions and modes. Colour in
    /// `rgba8` or `rgba8_premultiplied`.
    Bc7,
    /// 8 bytes per block (4 bits per texel): one channel, two 8-bit end points and 3-bit
    /// indices. Depth in `r8`.
    Bc4,
}

impl BlockCodec {
    /// Every codec.
    pub const ALL: [BlockCodec; 3] = [BlockCodec::Bc1, BlockCodec::Bc7, BlockCodec::Bc4];

    /// Its name in headers and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            BlockCodec::Bc1 => "bc1",
            BlockCodec::Bc7 => "bc7",
            BlockCodec::Bc4 => "bc4",
        }
    }

    /// Bytes per 4 × 4 block.
    pub fn block_bytes(self) -> u32 {
        match self {
            BlockCodec::Bc1 | BlockCodec::Bc4 => 8,
            BlockCodec::Bc7 => 16,
        }
    }

    /// Whether `channel` stored in `encoding` may use this codec.
    pub fn allowed_for(self, channel: Channel, encoding: Encoding) -> bool {
        match self {
            BlockCodec::Bc1 => channel == Channel::Color && encoding == Encoding::Rgba8,
            BlockCodec::Bc7 => {
                channel == Channel::Color
                    && matches!(encoding, Encoding::Rgba8 | Encoding::Rgba8Premultiplied)
            }
            BlockCodec::Bc4 => channel == Channel::Depth && encoding == Encoding::R8,
        }
    }

    /// Bytes of one decoded texel: 4 (RGBA8 colour), 1 (BC4's 8-bit depth code).
    pub fn texel_bytes(self) -> usize {
        match self {
            BlockCodec::Bc1 | BlockCodec::Bc7 => 4,
            BlockCodec::Bc4 => 1,
        }
    }

    /// Stored bytes of a `width × height` texel rectangle (both multiples of [`BLOCK`]).
    pub fn stored_bytes(self, width: u32, height: u32) -> u64 {
        u64::from(width / BLOCK) * u64::from(height / BLOCK) * u64::from(self.block_bytes())
    }

    /// The wgpu format that samples these blocks as the decoded texels, where the adapter has
    /// `TEXTURE_COMPRESSION_BC` (`None` for BC4: depth codes are decoded on the host).
    pub fn texture_format(self) -> Option<wgpu::TextureFormat> {
        match self {
            BlockCodec::Bc1 => Some(wgpu::TextureFormat::Bc1RgbaUnorm),
            BlockCodec::Bc7 => Some(wgpu::TextureFormat::Bc7RgbaUnorm),
            BlockCodec::Bc4 => None,
        }
    }

    /// Compresses `texels` (`width × height`, row-major, 4 bytes per texel for the colour
    /// codecs, 1 for BC4) of a channel in `encoding`. Both sides must be multiples of
    /// [`BLOCK`] and `texels` the right length; callers (the page writer) check both, and this
    /// returns `None` otherwise. `rgba8` colour loses its edge texels (docs/format.md §8.5: a
    /// texel without A = 255 becomes (0, 0, 0, 0)), whose bit-packed depth codes no block
    /// codec keeps; readers that ignore edge texels see the same maps.
    pub fn encode(
        self,
        encoding: Encoding,
        texels: &[u8],
        width: u32,
        height: u32,
    ) -> Option<Vec<u8>> {
        if !width.is_multiple_of(BLOCK) || !height.is_multiple_of(BLOCK) {
            return None;
        }
        let stripped;
        let texels = if encoding == Encoding::Rgba8 {
            stripped = texels
                .chunks_exact(4)
                .flat_map(|p| {
                    if p[3] == 255 {
                        [p[0], p[1], p[2], 255]
                    } else {
                        [0; 4]
                    }
                })
                .collect::<Vec<u8>>();
            stripped.as_slice()
        } else {
            texels
        };
        if texels.len() != width as usize * height as usize * self.texel_bytes() {
            return None;
        }
        let mut out = vec![0u8; usize::try_from(self.stored_bytes(width, height)).ok()?];
        match self {
            BlockCodec::Bc1 => {
                let params = texpresso::Params {
                    algorithm: texpresso::Algorithm::ClusterFit,
                    ..texpresso::Params::default()
                };
                texpresso::Format::Bc1.compress(
                    texels,
                    width as usize,
                    height as usize,
                    params,
                    &mut out,
                );
            }
            BlockCodec::Bc7 => {
                let settings = block_compression::BC7Settings::alpha_ultrafast();
                block_compression::encode::compress_rgba8(
                    block_compression::CompressionVariant::BC7(settings),
                    texels,
                    &mut out,
                    width,
                    height,
                    width * 4,
                );
            }
            BlockCodec::Bc4 => {
                let rgba: Vec<u8> = texels.iter().flat_map(|&v| [v, 0, 0, 255]).collect();
                block_compression::encode::compress_rgba8(
                    block_compression::CompressionVariant::BC4,
                    &rgba,
                    &mut out,
                    width,
                    height,
                    width * 4,
                );
            }
        }
        Some(out)
    }

    /// Decodes `blocks` of a `width × height` rectangle of a channel in `encoding` into texels
    /// (4 bytes each for the colour codecs, 1 for BC4); `None` where the sizes disagree.
    /// `rgba8` colour comes back with its coverage exact: A ≥ 128 is a hit (A = 255), below
    /// it the texel is (0, 0, 0, 0).
    pub fn decode(
        self,
        encoding: Encoding,
        blocks: &[u8],
        width: u32,
        height: u32,
    ) -> Option<Vec<u8>> {
        let mut texels = self.decode_blocks(blocks, width, height)?;
        if encoding == Encoding::Rgba8 && self != BlockCodec::Bc4 {
            for p in texels.chunks_exact_mut(4) {
                if p[3] >= 128 {
                    p[3] = 255;
                } else {
                    p.copy_from_slice(&[0; 4]);
                }
            }
        }
        Some(texels)
    }

    fn decode_blocks(self, blocks: &[u8], width: u32, height: u32) -> Option<Vec<u8>> {
        if !width.is_multiple_of(BLOCK)
            || !height.is_multiple_of(BLOCK)
            || blocks.len() as u64 != self.stored_bytes(width, height)
        {
            return None;
        }
        let texel_count = width as usize * height as usize;
        let mut rgba = vec![0u8; texel_count * 4];
        match self {
            BlockCodec::Bc1 => {
                texpresso::Format::Bc1.decompress(
                    blocks,
                    width as usize,
                    height as usize,
                    &mut rgba,
                );
                Some(rgba)
            }
            BlockCodec::Bc7 => {
                let settings = block_compression::BC7Settings::alpha_ultrafast();
                block_compression::decode::decompress_blocks_as_rgba8(
                    block_compression::CompressionVariant::BC7(settings),
                    width,
                    height,
                    blocks,
                    &mut rgba,
                );
                Some(rgba)
            }
            BlockCodec::Bc4 => {
                block_compression::decode::decompress_blocks_as_rgba8(
                    block_compression::CompressionVariant::BC4,
                    width,
                    height,
                    blocks,
                    &mut rgba,
                );
                Some(rgba.chunks_exact(4).map(|p| p[0]).collect())
            }
        }
    }
}

impl std::fmt::Display for BlockCodec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for BlockCodec {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        BlockCodec::ALL
            .into_iter()
            .find(|c| c.name() == s)
            .ok_or_else(|| format!("unknown block codec {s:?}: bc1, bc7 or bc4"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth gradient with a disc of coverage: what a light-field map looks like.
    fn map(n: u32) -> Vec<u8> {
        let mut out = Vec::new();
        for i in 0..n {
            for j in 0..n {
                let (x, y) = (
                    f64::from(j) / f64::from(n) - 0.5,
                    f64::from(i) / f64::from(n) - 0.5,
                );
                if x * x + y * y < 0.16 {
                    out.extend([
                        (200.0 * (x + 0.5)) as u8,
                        (150.0 * (y + 0.5)) as u8 + 40,
                        90,
                        255,
                    ]);
                } else {
                    out.extend([0, 0, 0, 0]);
                }
            }
        }
        out
    }

    /// BC1 keeps coverage exactly (punch-through alpha: empty texels decode to (0, 0, 0, 0),
    /// covered ones to A = 255) and colour within 12 codes on a gradient (RGB565 end points:
    /// 8 codes of red/blue quantisation, plus the 2-bit palette); BC7 (the encoder's fastest
    /// setting, which the writer uses) within 6 codes everywhere, alpha included.
    #[test]
    fn colour_codecs_round_trip_within_their_precision() {
        let n = 64;
        let texels = map(n);
        for (codec, tolerance) in [(BlockCodec::Bc1, 12), (BlockCodec::Bc7, 6)] {
            let blocks = codec
                .encode(Encoding::Rgba8, &texels, n, n)
                .expect("encode");
            assert_eq!(blocks.len() as u64, codec.stored_bytes(n, n));
            let back = codec
                .decode(Encoding::Rgba8, &blocks, n, n)
                .expect("decode");
            for (a, b) in texels.chunks_exact(4).zip(back.chunks_exact(4)) {
                if codec == BlockCodec::Bc1 {
                    assert_eq!(a[3], b[3], "{codec}: alpha {a:?} → {b:?}");
                    if a[3] == 0 {
                        assert_eq!(b, [0, 0, 0, 0]);
                    }
                }
                for k in 0..4 {
                    assert!(a[k].abs_diff(b[k]) <= tolerance, "{codec}: {a:?} → {b:?}");
                }
            }
        }
    }

    /// BC4 reproduces a block of two values exactly (both are end points) and a ramp within 2
    /// codes (8 palette entries across the block's range of ≤ 28 codes here).
    #[test]
    fn bc4_round_trips_depth_codes() {
        let n = 16;
        let two: Vec<u8> = (0..n * n)
            .map(|i| if i % 3 == 0 { 255 } else { 37 })
            .collect();
        let r8 = Encoding::R8;
        let back = BlockCodec::Bc4
            .decode(
                r8,
                &BlockCodec::Bc4.encode(r8, &two, n, n).expect("encode"),
                n,
                n,
            )
            .expect("decode");
        assert_eq!(back, two);
        let ramp: Vec<u8> = (0..n * n)
            .map(|i| (100 + (i % n) + (i / n)) as u8)
            .collect();
        let back = BlockCodec::Bc4
            .decode(
                r8,
                &BlockCodec::Bc4.encode(r8, &ramp, n, n).expect("encode"),
                n,
                n,
            )
            .expect("decode");
        for (a, b) in ramp.iter().zip(&back) {
            assert!(a.abs_diff(*b) <= 2, "{a} → {b}");
        }
    }

    /// An edge texel (no hit, A in 1..=254, a depth code in R | G) is dropped by every colour
    /// codec: it decodes to (0, 0, 0, 0).
    #[test]
    fn edge_texels_are_dropped() {
        let mut texels = vec![0u8; 4 * 4 * 4];
        texels[..4].copy_from_slice(&[120, 200, 0, 200]);
        texels[4..8].copy_from_slice(&[10, 20, 30, 255]);
        for codec in [BlockCodec::Bc1, BlockCodec::Bc7] {
            let blocks = codec
                .encode(Encoding::Rgba8, &texels, 4, 4)
                .expect("encode");
            let back = codec
                .decode(Encoding::Rgba8, &blocks, 4, 4)
                .expect("decode");
            assert_eq!(&back[..4], &[0, 0, 0, 0], "{codec}");
            assert_eq!(back[7], 255, "{codec}");
        }
    }

    #[test]
    fn sizes_that_are_not_whole_blocks_are_refused() {
        let (rgba, r8) = (Encoding::Rgba8, Encoding::R8);
        assert!(
            BlockCodec::Bc7
                .encode(rgba, &[0; 6 * 4 * 4], 6, 4)
                .is_none()
        );
        assert!(BlockCodec::Bc7.encode(rgba, &[0; 3], 4, 4).is_none());
        assert!(BlockCodec::Bc1.decode(rgba, &[0; 7], 4, 4).is_none());
        assert!(BlockCodec::Bc4.decode(r8, &[0; 8], 4, 6).is_none());
        assert_eq!("bc7".parse::<BlockCodec>(), Ok(BlockCodec::Bc7));
        assert!("dxt1".parse::<BlockCodec>().is_err());
    }

    #[test]
    fn codecs_fit_their_channels() {
        assert!(BlockCodec::Bc1.allowed_for(Channel::Color, Encoding::Rgba8));
        assert!(!BlockCodec::Bc1.allowed_for(Channel::Color, Encoding::Rgba8Premultiplied));
        assert!(BlockCodec::Bc7.allowed_for(Channel::Color, Encoding::Rgba8Premultiplied));
        assert!(BlockCodec::Bc4.allowed_for(Channel::Depth, Encoding::R8));
        assert!(!BlockCodec::Bc4.allowed_for(Channel::Depth, Encoding::R16));
        assert!(!BlockCodec::Bc7.allowed_for(Channel::Depth, Encoding::R8));
    }
}
