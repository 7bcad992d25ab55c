//! Adaptation to the client's link: a per-session estimate of bandwidth and round trip from the
//! receive times clients report in their acks, and the choice of interactive quality and scale
//! (and of the resting frame's codec) that keeps the frame rate near `target_fps`.
//!
//! Client and server clocks are never compared: a bandwidth sample uses the difference of two
//! client receive times and the difference of two server times only (docs/protocol.md, "Adaptive
//! streaming").

use std::collections::VecDeque;
use std::time::Instant;

/// Frames remembered for matching acks; older acks are ignored.
const REMEMBERED_FRAMES: usize = 16;
/// Largest bandwidth a sample may report (10 Gbit/s in bytes/s): a bound for the arithmetic,
/// far above any link whose speed matters here.
const MAX_BYTES_PER_S: f64 = 1.25e9;
/// Weight of a new sample from a saturated link in the moving average.
const BUSY_WEIGHT: f64 = 0.25;
/// Growth of the estimate per frame sent onto an idle link: probes for a faster link without
/// waiting for a sample to prove it.
const IDLE_PROBE: f64 = 1.03;
/// Share of the link one frame interval may fill: the rest absorbs estimate noise, so the
/// link's queue drains instead of growing.
const LINK_SHARE: f64 = 0.8;
/// The longest a resting frame may take on the link before a lossless codec is replaced by JPEG.
pub(super) const STILL_BUDGET_MS: f64 = 1000.0;
/// Smallest interactive scale adaptation chooses (as for the render-cost scale).
const MIN_SCALE: f64 = 0.25;
/// JPEG qualities tried at the render scale before the scale is lowered, and after it.
const QUALITY_BEFORE_SCALE: [u8; 2] = [40, 30];
const QUALITY_AFTER_SCALE: [u8; 3] = [20, 15, 10];
/// Largest client receive time accepted, ms (about 285 years of `performance.now()`); larger
/// values are refused when the ack is parsed.
pub(super) const MAX_RECEIVED_MS: f64 = 9.0e12;

/// A frame the sender wrote to the socket.
#[derive(Clone, Debug)]
struct SentFrame {
    id: u32,
    bytes: usize,
    sent: Instant,
    /// Server time the ack arrived.
    acked: Option<Instant>,
    /// Client receive time from the ack, ms on the client's clock.
    received_ms: Option<f64>,
}

/// Per-session estimate of the link's bandwidth and frame round trip.
#[derive(Debug, Default)]
pub(super) struct LinkEstimator {
    sent: VecDeque<SentFrame>,
    bytes_per_s: Option<f64>,
    round_trip_ms: Option<f64>,
}

impl LinkEstimator {
    /// Records a frame of `bytes` written to the socket at `at`.
    pub(super) fn on_sent(&mut self, id: u32, bytes: usize, at: Instant) {
        if self.sent.len() == REMEMBERED_FRAMES {
            self.sent.pop_front();
        }
        self.sent.push_back(SentFrame {
            id,
            bytes,
            sent: at,
            acked: None,
            received_ms: None,
        });
    }

    /// Takes the ack of frame `id` that arrived at `at`, with the client's receive time.
    ///
    /// Acks of unknown or already acknowledged frames are ignored; so is a receive time that
    /// does not come after the previous frame's (out of order, or a clock step).
    pub(super) fn on_ack(&mut self, id: u32, received_ms: Option<f64>, at: Instant) {
        let Some(index) = self.sent.iter().position(|f| f.id == id) else {
            return;
        };
        if self.sent[index].acked.is_some() {
            return;
        }
        let received_ms =
            received_ms.filter(|r| r.is_finite() && (0.0..=MAX_RECEIVED_MS).contains(r));
        let frame = &mut self.sent[index];
        frame.acked = Some(at);
        frame.received_ms = received_ms;
        let round_trip_ms = at.saturating_duration_since(frame.sent).as_secs_f64() * 1e3;
        self.round_trip_ms = Some(
            self.round_trip_ms
                .map_or(round_trip_ms, |old| 0.8 * old + 0.2 * round_trip_ms),
        );
        let (Some(received_ms), Some(previous)) =
            (received_ms, index.checked_sub(1).map(|i| &self.sent[i]))
        else {
            return;
        };
        let frame = &self.sent[index];
        let (Some(previous_received), Some(previous_acked)) =
            (previous.received_ms, previous.acked)
        else {
            return;
        };
        if previous.id.wrapping_add(1) != frame.id {
            return;
        }
        // The frame's bytes arrived after the previous frame's: between the two receive times,
        // less the time the link stood idle because the frame was sent only after the previous
        // one's ack came back (a server-clock difference). The idle part that the round trip
        // hides stays in, so a sample never overstates the link.
        let idle_ms = frame
            .sent
            .saturating_duration_since(previous_acked)
            .as_secs_f64()
            * 1e3;
        let transfer_ms = received_ms - previous_received - idle_ms;
        if received_ms <= previous_received || transfer_ms <= 0.0 {
            return;
        }
        let sample = (frame.bytes as f64 / (transfer_ms / 1e3)).min(MAX_BYTES_PER_S);
        let link_was_busy = idle_ms == 0.0;
        self.bytes_per_s = Some(match self.bytes_per_s {
            None => sample,
            Some(old) if link_was_busy => (1.0 - BUSY_WEIGHT) * old + BUSY_WEIGHT * sample,
            // An idle link only shows a lower bound: raise, never lower.
            Some(old) => sample.max((old * IDLE_PROBE).min(MAX_BYTES_PER_S)),
        });
    }

    /// Estimated bandwidth, bytes per second; `None` before the first sample.
    pub(super) fn bytes_per_s(&self) -> Option<f64> {
        self.bytes_per_s
    }

    /// Smoothed time from sending a frame to its ack, ms (transfer included).
    pub(super) fn round_trip_ms(&self) -> Option<f64> {
        self.round_trip_ms
    }
}

/// JPEG bytes relative to quality 50, interpolated between these qualities: the usual shape of
/// the size curve of baseline JPEG with the standard quantisation tables. Only the ratios are
/// used: the session learns the absolute bytes per pixel from its own frames, so an error in a
/// ratio only moves the choice a step, and the next frame's measurement corrects it.
const JPEG_SIZE_CURVE: [(u8, f64); 10] = [
    (1, 0.3),
    (10, 0.45),
    (20, 0.62),
    (30, 0.76),
    (40, 0.89),
    (50, 1.0),
    (70, 1.3),
    (80, 1.62),
    (90, 2.35),
    (100, 5.0),
];

/// JPEG bytes at `quality` relative to quality 50.
pub(super) fn jpeg_size_factor(quality: u8) -> f64 {
    let q = f64::from(quality.clamp(1, 100));
    JPEG_SIZE_CURVE
        .windows(2)
        .find(|w| q <= f64::from(w[1].0))
        .map_or(JPEG_SIZE_CURVE[JPEG_SIZE_CURVE.len() - 1].1, |w| {
            let (q0, f0) = (f64::from(w[0].0), w[0].1);
            let (q1, f1) = (f64::from(w[1].0), w[1].1);
            f0 + (f1 - f0) * (q - q0) / (q1 - q0)
        })
}

/// What the link needs to be known about for a choice.
#[derive(Clone, Copy, Debug)]
pub(super) struct Link {
    /// Estimated bandwidth, bytes/s.
    pub(super) bytes_per_s: f64,
    /// Measured interactive JPEG bytes per pixel, normalised to quality 50.
    pub(super) bytes_per_px_q50: f64,
    /// Measured depth-image bytes per pixel when frames carry depth (0 otherwise); it does
    /// not shrink with the JPEG quality, only with the scale.
    pub(super) depth_bytes_per_px: f64,
}

/// The interactive frame's scale and JPEG quality.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct InteractiveChoice {
    pub(super) scale: f64,
    pub(super) quality: u8,
    /// The link made the server go below the best the settings allow.
    pub(super) link_limited: bool,
}

/// Chooses the interactive frame's scale and quality so that its predicted bytes fit the link's
/// share of one frame interval at `target_fps`.
///
/// `best_scale` is the scale the render cost allows (or the client's fixed scale, when
/// `scale_fixed`); `best_quality` the client's `interactive_quality`. Without a `link`
/// measurement both are kept. The order of concessions: quality down to 30, then the scale in
/// steps of 1/8 down to 0.25 (not when fixed), then quality down to 10; the first that fits
/// wins, the last is used when none fits.
pub(super) fn choose_interactive(
    full_px: f64,
    best_scale: f64,
    scale_fixed: bool,
    best_quality: u8,
    target_fps: f32,
    link: Option<Link>,
) -> InteractiveChoice {
    let best = InteractiveChoice {
        scale: best_scale,
        quality: best_quality,
        link_limited: false,
    };
    let Some(link) = link.filter(|l| {
        l.bytes_per_s.is_finite()
            && l.bytes_per_s > 0.0
            && l.bytes_per_px_q50.is_finite()
            && l.bytes_per_px_q50 > 0.0
    }) else {
        return best;
    };
    let budget_bytes = link.bytes_per_s * LINK_SHARE / f64::from(target_fps.max(1.0));
    let depth_bytes_per_px = if link.depth_bytes_per_px.is_finite() {
        link.depth_bytes_per_px.max(0.0)
    } else {
        0.0
    };
    let bytes = |scale: f64, quality: u8| {
        full_px
            * scale
            * scale
            * (link.bytes_per_px_q50 * jpeg_size_factor(quality) + depth_bytes_per_px)
    };
    let mut candidates = vec![(best_scale, best_quality)];
    let lower = |q: &&u8| **q < best_quality;
    candidates.extend(
        QUALITY_BEFORE_SCALE
            .iter()
            .filter(lower)
            .map(|&q| (best_scale, q)),
    );
    let middle_quality = candidates[candidates.len() - 1].1;
    if !scale_fixed {
        let mut scale = best_scale;
        while scale - 0.125 >= MIN_SCALE - 1e-9 {
            scale -= 0.125;
            candidates.push((scale, middle_quality));
        }
    }
    let smallest_scale = candidates[candidates.len() - 1].0;
    candidates.extend(
        QUALITY_AFTER_SCALE
            .iter()
            .filter(lower)
            .map(|&q| (smallest_scale, q)),
    );
    let (scale, quality) = candidates
        .iter()
        .copied()
        .find(|&(s, q)| bytes(s, q) <= budget_bytes)
        .unwrap_or(candidates[candidates.len() - 1]);
    InteractiveChoice {
        scale,
        quality,
        link_limited: (scale, quality) != (best_scale, best_quality),
    }
}

/// Whether a resting frame of `bytes` reaches the client within [`STILL_BUDGET_MS`] at the
/// estimated bandwidth (true without an estimate).
pub(super) fn still_fits(bytes: usize, bytes_per_s: Option<f64>) -> bool {
    bytes_per_s.is_none_or(|bw| bytes as f64 / bw * 1e3 <= STILL_BUDGET_MS)
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;

    /// Feeds `frames` frames of `bytes` through a link of `bytes_per_s` with the sender
    /// pipelining (each frame sent before the previous one arrived), the client's clock offset
    /// by `offset_ms` from the server's.
    fn saturated(bytes_per_s: f64, bytes: usize, frames: u32, offset_ms: f64) -> LinkEstimator {
        let start = Instant::now();
        let mut link = LinkEstimator::default();
        let transfer_ms = bytes as f64 / bytes_per_s * 1e3;
        for id in 1..=frames {
            // Sent well before the link is free; arrives one transfer after the previous.
            let sent = start + Duration::from_secs_f64(f64::from(id - 1) * transfer_ms / 1e3);
            link.on_sent(id, bytes, sent);
            let received_ms = offset_ms + 1.0 + f64::from(id) * transfer_ms;
            let acked = start + Duration::from_secs_f64((f64::from(id) * transfer_ms + 2.0) / 1e3);
            link.on_ack(id, Some(received_ms), acked);
        }
        link
    }

    #[test]
    fn a_saturated_link_is_measured_whatever_the_clock_offset() {
        // 2 Mbit/s = 250 kB/s; 10 kB frames. Samples are exact here, so 1 % covers rounding
        // of the durations to nanoseconds.
        for offset_ms in [0.0, 5.0e6, 1.7e9] {
            let link = saturated(250_000.0, 10_000, 12, offset_ms);
            let bw = link.bytes_per_s().unwrap();
            assert!(
                (bw / 250_000.0 - 1.0).abs() < 0.01,
                "offset {offset_ms}: {bw}"
            );
        }
        let fast = saturated(1.25e8, 50_000, 12, 0.0).bytes_per_s().unwrap();
        assert!((fast / 1.25e8 - 1.0).abs() < 0.01, "{fast}");
    }

    #[test]
    fn idle_gaps_on_the_server_are_not_counted_as_transfer() {
        // 10 kB frames over 1 MB/s (10 ms each), but sent 50 ms after the previous ack: the
        // receive times are 60 ms apart, the link carried the frame in 10 ms.
        let start = Instant::now();
        let mut link = LinkEstimator::default();
        let mut server_ms = 0.0;
        let mut client_ms = 1000.0;
        for id in 1..=6 {
            let sent = start + Duration::from_secs_f64(server_ms / 1e3);
            link.on_sent(id, 10_000, sent);
            client_ms += if id == 1 { 10.0 } else { 50.0 + 10.0 };
            server_ms += 10.0; // arrival, acked at once on a loopback link
            link.on_ack(
                id,
                Some(client_ms),
                start + Duration::from_secs_f64(server_ms / 1e3),
            );
            server_ms += 50.0;
        }
        let bw = link.bytes_per_s().unwrap();
        // The idle sample is exact here, later ones probe upwards by 3 % a frame.
        assert!((1.0e6..1.2e6).contains(&bw), "{bw}");
    }

    #[test]
    fn hostile_or_out_of_order_acks_are_ignored() {
        let mut link = saturated(250_000.0, 10_000, 4, 0.0);
        let before = link.bytes_per_s();
        let now = Instant::now() + Duration::from_secs(1);
        for (id, received) in [
            (5, -1.0),
            (6, f64::NAN),
            (7, f64::INFINITY),
            (8, 1e300),
            (9, 5.0e6),
            (10, 1.0), // before frame 9's time
        ] {
            link.on_sent(id, 10_000, now);
            link.on_ack(id, Some(received), now);
        }
        assert_eq!(link.bytes_per_s(), before);
        // Unknown frames, repeated acks and acks without times change nothing either.
        link.on_ack(999, Some(5.0e6), now);
        link.on_ack(4, Some(5.0e6), now);
        link.on_sent(11, 10_000, now);
        link.on_ack(11, None, now);
        assert_eq!(link.bytes_per_s(), before);
        // A time equal to the previous one (no transfer) is no sample.
        let mut link = LinkEstimator::default();
        link.on_sent(1, 10, now);
        link.on_ack(1, Some(100.0), now);
        link.on_sent(2, 10, now);
        link.on_ack(2, Some(100.0), now);
        assert_eq!(link.bytes_per_s(), None);
    }

    #[test]
    fn round_trip_is_smoothed_from_server_times() {
        let start = Instant::now();
        let mut link = LinkEstimator::default();
        link.on_sent(1, 100, start);
        link.on_ack(1, None, start + Duration::from_millis(40));
        assert!((link.round_trip_ms().unwrap() - 40.0).abs() < 1e-6);
    }

    #[test]
    fn jpeg_size_curve_is_monotonic_and_anchored_at_50() {
        assert!((jpeg_size_factor(50) - 1.0).abs() < 1e-12);
        let sizes: Vec<f64> = (1..=100).map(jpeg_size_factor).collect();
        assert!(sizes.windows(2).all(|w| w[0] < w[1]));
        assert!((jpeg_size_factor(0) - jpeg_size_factor(1)).abs() < 1e-12);
    }

    const FULL_PX: f64 = 1024.0 * 768.0;
    /// About what a q50 JPEG of a rendered object on black takes (bytes per pixel).
    const BPP_Q50: f64 = 0.12;

    fn link(mbit_per_s: f64) -> Link {
        Link {
            bytes_per_s: mbit_per_s * 1e6 / 8.0,
            bytes_per_px_q50: BPP_Q50,
            depth_bytes_per_px: 0.0,
        }
    }

    #[test]
    fn a_fast_link_or_none_measured_keeps_full_quality() {
        for measured in [None, Some(link(1000.0))] {
            let choice = choose_interactive(FULL_PX, 0.75, false, 50, 20.0, measured);
            assert_eq!(
                choice,
                InteractiveChoice {
                    scale: 0.75,
                    quality: 50,
                    link_limited: false
                }
            );
        }
    }

    #[test]
    fn slower_links_get_smaller_frames_that_fit() {
        let budget = |mbit: f64| mbit * 1e6 / 8.0 * LINK_SHARE / 20.0;
        let predicted = |c: InteractiveChoice| {
            FULL_PX * c.scale * c.scale * BPP_Q50 * jpeg_size_factor(c.quality)
        };
        let mut previous = f64::INFINITY;
        for mbit in [50.0, 10.0, 5.0, 2.0, 1.0] {
            let choice = choose_interactive(FULL_PX, 1.0, false, 50, 20.0, Some(link(mbit)));
            let bytes = predicted(choice);
            assert!(bytes <= budget(mbit), "{mbit} Mbit/s: {choice:?} {bytes}");
            assert!(bytes <= previous, "{mbit} Mbit/s: not smaller");
            previous = bytes;
        }
        let slow = choose_interactive(FULL_PX, 1.0, false, 50, 20.0, Some(link(2.0)));
        assert!(
            slow.link_limited && slow.scale < 1.0 && slow.quality <= 30,
            "{slow:?}"
        );
        // Quality is lowered to 30 before the scale.
        let mid = choose_interactive(FULL_PX, 1.0, false, 50, 20.0, Some(link(16.0)));
        assert_eq!((mid.scale, mid.quality), (1.0, 30), "{mid:?}");
    }

    #[test]
    fn a_fixed_scale_stays_and_an_impossible_link_gets_the_smallest_frame() {
        let fixed = choose_interactive(FULL_PX, 0.5, true, 80, 20.0, Some(link(0.5)));
        assert_eq!(fixed.scale, 0.5);
        assert!(fixed.quality < 80 && fixed.link_limited);
        let floor = choose_interactive(FULL_PX, 1.0, false, 50, 120.0, Some(link(0.01)));
        assert_eq!((floor.scale, floor.quality), (0.25, 10));
        // A ceiling below the ladder's steps is never raised.
        let low = choose_interactive(FULL_PX, 1.0, false, 12, 20.0, Some(link(0.01)));
        assert_eq!((low.scale, low.quality), (0.25, 10));
        let low_fast = choose_interactive(FULL_PX, 1.0, false, 12, 20.0, Some(link(1000.0)));
        assert_eq!((low_fast.scale, low_fast.quality), (1.0, 12));
    }

    #[test]
    fn nonsense_measurements_keep_the_settings() {
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let measured = Some(Link {
                bytes_per_s: bad,
                bytes_per_px_q50: BPP_Q50,
                depth_bytes_per_px: 0.0,
            });
            let choice = choose_interactive(FULL_PX, 1.0, false, 50, 20.0, measured);
            assert!(!choice.link_limited);
            let measured = Some(Link {
                bytes_per_s: 1e6,
                bytes_per_px_q50: bad,
                depth_bytes_per_px: 0.0,
            });
            assert!(!choose_interactive(FULL_PX, 1.0, false, 50, 20.0, measured).link_limited);
            // A nonsense depth size counts as none.
            let measured = Some(Link {
                depth_bytes_per_px: bad,
                ..link(1000.0)
            });
            assert!(!choose_interactive(FULL_PX, 1.0, false, 50, 20.0, measured).link_limited);
        }
    }

    /// Frames that carry depth: the depth bytes count against the link too, and only the
    /// scale shrinks them, so the same link gets a smaller scale than without depth.
    #[test]
    fn depth_bytes_count_against_the_link() {
        let with_depth = |mbit: f64| Link {
            // A 16-bit depth PNG is several times the q50 colour.
            depth_bytes_per_px: 5.0 * BPP_Q50,
            ..link(mbit)
        };
        let budget = |mbit: f64| mbit * 1e6 / 8.0 * LINK_SHARE / 20.0;
        for mbit in [50.0, 20.0, 10.0] {
            let plain = choose_interactive(FULL_PX, 1.0, false, 50, 20.0, Some(link(mbit)));
            let deep = choose_interactive(FULL_PX, 1.0, false, 50, 20.0, Some(with_depth(mbit)));
            let bytes = FULL_PX
                * deep.scale
                * deep.scale
                * (BPP_Q50 * jpeg_size_factor(deep.quality) + 5.0 * BPP_Q50);
            assert!(bytes <= budget(mbit), "{mbit} Mbit/s: {deep:?}");
            assert!(deep.scale <= plain.scale, "{mbit}: {deep:?} vs {plain:?}");
            assert!(deep.scale < 1.0 && deep.link_limited, "{mbit}: {deep:?}");
        }
    }

    #[test]
    fn a_lossless_still_is_afforded_only_when_it_arrives_in_time() {
        // 600 kB PNG: 2.4 s at 2 Mbit/s (too long), 0.48 s at 10 Mbit/s.
        assert!(!still_fits(600_000, Some(250_000.0)));
        assert!(still_fits(600_000, Some(1_250_000.0)));
        assert!(still_fits(600_000, None));
    }
}
