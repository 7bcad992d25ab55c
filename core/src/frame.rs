//! The output of every renderer: colour, depth and coverage per pixel, plus statistics (DESIGN §3).

use serde::{Deserialize, Serialize};

/// Timing and work counters for one rendered frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FrameStats {
    /// GPU work plus readback, milliseconds.
    pub render_ms: f64,
    /// Pixels whose ray met the object's bounding sphere.
    pub rays: u64,
    /// March steps taken over all pixels, where the renderer counts them.
    pub steps: u64,
    /// Texture fetches over all pixels, where the renderer counts them.
    pub fetches: u64,
}

/// A rendered image: colour RGBA8 (row-major, top row first), z-depth along the view's forward
/// axis in world units (`+inf` where nothing is hit) and coverage (derived from depth).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Frame {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width * height * 4` bytes; outside coverage it holds the request's background.
    pub color: Vec<u8>,
    /// `width * height` z-depths in world units; `+inf` where not covered.
    pub depth: Vec<f32>,
    /// Statistics of the render.
    pub stats: FrameStats,
}

impl Frame {
    /// Number of pixels.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Coverage mask: true where the object is hit (depth finite).
    pub fn coverage(&self) -> Vec<bool> {
        self.depth.iter().map(|d| d.is_finite()).collect()
    }

    /// Number of covered pixels.
    pub fn covered_count(&self) -> usize {
        self.depth.iter().filter(|d| d.is_finite()).count()
    }

    /// Colour with every pixel outside coverage replaced by `background` (RGBA8).
    pub fn with_background(&self, background: [u8; 4]) -> Vec<u8> {
        let mut out = self.color.clone();
        for (px, d) in out.chunks_exact_mut(4).zip(&self.depth) {
            if !d.is_finite() {
                px.copy_from_slice(&background);
            }
        }
        out
    }
}
