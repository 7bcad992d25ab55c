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
/// axis in world units (`+inf` where nothing is hit) and coverage: derived from depth for an
/// opaque frame, from alpha for a [translucent](Frame::translucent) one.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Frame {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width * height * 4` bytes; outside coverage it holds the request's background.
    pub color: Vec<u8>,
    /// `width * height` z-depths in world units; `+inf` where not covered (and, in a
    /// translucent frame, where the accumulated opacity stays below the depth threshold).
    pub depth: Vec<f32>,
    /// A semi-transparent frame (a volume, DESIGN §9): `color` holds straight colour and
    /// alpha `round(255·A)` as PNG does, coverage is alpha ≥ 1, and over a background `bg` the
    /// displayed colour is `C + (1 − A)·bg`. `false`: every covered pixel is opaque.
    pub translucent: bool,
    /// Statistics of the render.
    pub stats: FrameStats,
}

impl Frame {
    /// Number of pixels.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Coverage mask: true where the object is hit (depth finite), or in a translucent frame
    /// where alpha ≥ 1.
    pub fn coverage(&self) -> Vec<bool> {
        if self.translucent {
            return self.color.chunks_exact(4).map(|p| p[3] >= 1).collect();
        }
        self.depth.iter().map(|d| d.is_finite()).collect()
    }

    /// Number of covered pixels.
    pub fn covered_count(&self) -> usize {
        if self.translucent {
            return self.color.chunks_exact(4).filter(|p| p[3] >= 1).count();
        }
        self.depth.iter().filter(|d| d.is_finite()).count()
    }

    /// Colour with every pixel outside coverage replaced by `background` (RGBA8); in a
    /// translucent frame every pixel is composited over it (`C + (1 − A)·bg`, Porter–Duff
    /// "over" with straight alpha out), so a transparent background keeps the frame as it is.
    pub fn with_background(&self, background: [u8; 4]) -> Vec<u8> {
        let mut out = self.color.clone();
        if self.translucent {
            let bg_a = f32::from(background[3]) / 255.0;
            for px in out.chunks_exact_mut(4) {
                let a = f32::from(px[3]) / 255.0;
                let out_a = a + (1.0 - a) * bg_a;
                if out_a <= 0.0 {
                    px.copy_from_slice(&background);
                    continue;
                }
                for c in 0..3 {
                    let premultiplied = f32::from(px[c]) / 255.0 * a
                        + (1.0 - a) * bg_a * f32::from(background[c]) / 255.0;
                    px[c] = (255.0 * premultiplied / out_a).round().clamp(0.0, 255.0) as u8;
                }
                px[3] = (255.0 * out_a).round().clamp(0.0, 255.0) as u8;
            }
            return out;
        }
        for (px, d) in out.chunks_exact_mut(4).zip(&self.depth) {
            if !d.is_finite() {
                px.copy_from_slice(&background);
            }
        }
        out
    }
}
