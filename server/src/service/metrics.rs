//! Prometheus metrics of the service, served at `/metrics` in the text exposition format.

use prometheus_client::encoding::text::encode;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{Histogram, exponential_buckets};
use prometheus_client::registry::Registry;

type Labels = Vec<(&'static str, String)>;

fn latency_histogram() -> Histogram {
    // 0.5 ms .. ~16 s in factors of two: covers a cached 64² JPEG up to a 4K lavapipe render.
    Histogram::new(exponential_buckets(0.0005, 2.0, 16))
}

/// Every metric the service exports; cheap to update from any task.
pub struct Metrics {
    registry: Registry,
    frames: Family<Labels, Counter>,
    render_seconds: Family<Labels, Histogram, fn() -> Histogram>,
    encode_seconds: Family<Labels, Histogram, fn() -> Histogram>,
    sessions: Gauge,
    dropped_frames: Counter,
    bytes_sent: Family<Labels, Counter>,
    errors: Family<Labels, Counter>,
    assets: Gauge,
    light_fields: Gauge,
    asset_memory: Gauge,
    asset_memory_budget: Gauge,
    memory_used: Gauge,
    memory_budget: Gauge,
    devices_lost: Counter,
    adapted_frames: Family<Labels, Counter>,
    link_bandwidth: Histogram,
    link_round_trip: Histogram,
    page_hits: Counter,
    page_faults: Counter,
    pages_loaded: Counter,
    page_bytes_uploaded: Counter,
    degraded_pixels: Counter,
    degraded_frames: Counter,
    overview_pixels: Counter,
    page_read_errors: Counter,
}

impl Default for Metrics {
    fn default() -> Self {
        Self::new()
    }
}

impl Metrics {
    /// Creates and registers every metric under the `lumigraph_` prefix.
    pub fn new() -> Self {
        let mut registry = Registry::with_prefix("lumigraph");
        let frames = Family::<Labels, Counter>::default();
        let render_seconds =
            Family::<Labels, Histogram, fn() -> Histogram>::new_with_constructor(latency_histogram);
        let encode_seconds =
            Family::<Labels, Histogram, fn() -> Histogram>::new_with_constructor(latency_histogram);
        let sessions = Gauge::default();
        let dropped_frames = Counter::default();
        let bytes_sent = Family::<Labels, Counter>::default();
        let errors = Family::<Labels, Counter>::default();
        let assets = Gauge::default();
        let light_fields = Gauge::default();
        let asset_memory = Gauge::default();
        let asset_memory_budget = Gauge::default();
        let memory_used = Gauge::default();
        let devices_lost = Counter::default();
        let memory_budget = Gauge::default();
        let adapted_frames = Family::<Labels, Counter>::default();
        // 10 kB/s .. 655 MB/s in factors of four: a phone on a bad cell to a LAN.
        let link_bandwidth = Histogram::new(exponential_buckets(1e4, 4.0, 9));
        let link_round_trip = latency_histogram();
        let page_hits = Counter::default();
        let page_faults = Counter::default();
        let pages_loaded = Counter::default();
        let page_bytes_uploaded = Counter::default();
        let degraded_pixels = Counter::default();
        let degraded_frames = Counter::default();
        let overview_pixels = Counter::default();
        let page_read_errors = Counter::default();
        for (name, help, counter) in [
            (
                "page_cache_hits",
                "Pages paged frames touched that were resident when the frame started",
                &page_hits,
            ),
            (
                "page_cache_faults",
                "Pages paged frames touched that were not resident when the frame started",
                &page_faults,
            ),
            (
                "page_cache_pages_loaded",
                "Pages read from asset files into page caches (needed and prefetched)",
                &pages_loaded,
            ),
            (
                "page_cache_uploaded_bytes",
                "Bytes of pages uploaded into page caches",
                &page_bytes_uploaded,
            ),
            (
                "page_cache_degraded_pixels",
                "Pixels of paged frames that read the coarse level for a page not resident",
                &degraded_pixels,
            ),
            (
                "page_cache_degraded_frames",
                "Paged frames with at least one degraded pixel",
                &degraded_frames,
            ),
            (
                "page_cache_overview_pixels",
                "Pixels of paged frames that spanned 2 or more st texels and read a downsampled \
                 level by choice (a page level, or the coarse level and no page from its factor on)",
                &overview_pixels,
            ),
            (
                "page_cache_read_errors",
                "Page reads that failed (the frame was degraded there and logged)",
                &page_read_errors,
            ),
        ] {
            registry.register(name, help, counter.clone());
        }
        registry.register(
            "frames",
            "Frames rendered and sent, by source (http, stream) and quality (interactive, full)",
            frames.clone(),
        );
        registry.register(
            "render_seconds",
            "Render latency (GPU work plus readback) by source",
            render_seconds.clone(),
        );
        registry.register(
            "encode_seconds",
            "Image encode latency by codec",
            encode_seconds.clone(),
        );
        registry.register(
            "stream_sessions",
            "Open WebSocket stream sessions",
            sessions.clone(),
        );
        registry.register(
            "dropped_frames",
            "Stream requests superseded by a newer one before they were rendered",
            dropped_frames.clone(),
        );
        registry.register(
            "bytes_sent",
            "Image bytes sent, by source",
            bytes_sent.clone(),
        );
        registry.register(
            "errors",
            "Errors answered to clients, by kind",
            errors.clone(),
        );
        registry.register("assets", "Assets loaded and servable", assets.clone());
        registry.register(
            "gpu_light_fields",
            "Assets resident on the GPU: loaded, or deleted and still held by a render or stream",
            light_fields.clone(),
        );
        registry.register(
            "asset_memory_bytes",
            "Texture bytes of the resident assets, charged to the asset memory budget",
            asset_memory.clone(),
        );
        registry.register(
            "asset_memory_budget_bytes",
            "The asset memory budget (--asset-memory-budget)",
            asset_memory_budget.clone(),
        );
        registry.register(
            "memory_used_bytes",
            "Bytes charged to the server's memory budget: resident assets and frames in flight",
            memory_used.clone(),
        );
        registry.register(
            "memory_budget_bytes",
            "The server's memory budget (--memory-budget)",
            memory_budget.clone(),
        );
        registry.register(
            "gpu_devices_lost",
            "GPU devices lost and replaced by a new one (assets uploaded again)",
            devices_lost.clone(),
        );
        registry.register(
            "stream_adapted_frames",
            "Stream frames changed for the client's measured link, by what: interactive (quality or scale lowered), still_fallback (lossless resting frame sent as JPEG)",
            adapted_frames.clone(),
        );
        registry.register(
            "stream_link_bandwidth_bytes_per_second",
            "Stream sessions' estimated link bandwidth (from acks with receive times), observed per frame sent",
            link_bandwidth.clone(),
        );
        registry.register(
            "stream_link_round_trip_seconds",
            "Stream sessions' smoothed time from sending a frame to its ack, observed per frame sent",
            link_round_trip.clone(),
        );
        Self {
            registry,
            frames,
            render_seconds,
            encode_seconds,
            sessions,
            dropped_frames,
            bytes_sent,
            errors,
            assets,
            light_fields,
            asset_memory,
            asset_memory_budget,
            memory_used,
            memory_budget,
            devices_lost,
            adapted_frames,
            link_bandwidth,
            link_round_trip,
            page_hits,
            page_faults,
            pages_loaded,
            page_bytes_uploaded,
            degraded_pixels,
            degraded_frames,
            overview_pixels,
            page_read_errors,
        }
    }

    /// Counts a frame rendered through a page cache.
    pub fn pages(&self, stats: &lumigraph_core::page_cache::PageFrameStats) {
        self.page_hits
            .inc_by(u64::from(stats.pages_touched.saturating_sub(stats.faults)));
        self.page_faults.inc_by(u64::from(stats.faults));
        self.pages_loaded.inc_by(u64::from(stats.pages_loaded));
        self.page_bytes_uploaded.inc_by(stats.bytes_uploaded);
        self.degraded_pixels.inc_by(stats.degraded_px);
        self.overview_pixels.inc_by(stats.overview_px);
        if stats.degraded_px > 0 {
            self.degraded_frames.inc();
        }
        self.page_read_errors.inc_by(stats.read_errors.len() as u64);
    }

    /// Observes a stream session's link estimate (each when known).
    pub fn link(&self, bytes_per_s: Option<f64>, round_trip_ms: Option<f64>) {
        if let Some(bytes_per_s) = bytes_per_s {
            self.link_bandwidth.observe(bytes_per_s);
        }
        if let Some(round_trip_ms) = round_trip_ms {
            self.link_round_trip.observe(round_trip_ms / 1e3);
        }
    }

    /// Counts a stream frame adapted to its client's link.
    pub fn adapted(&self, what: &'static str) {
        self.adapted_frames
            .get_or_create(&vec![("what", what.to_owned())])
            .inc();
    }

    /// Counts one frame delivered to a client.
    pub fn frame(
        &self,
        source: &'static str,
        quality: &'static str,
        bytes: usize,
        render_ms: f64,
        encode_ms: f64,
        codec: &'static str,
    ) {
        self.frames
            .get_or_create(&vec![
                ("source", source.to_owned()),
                ("quality", quality.to_owned()),
            ])
            .inc();
        self.render_seconds
            .get_or_create(&vec![("source", source.to_owned())])
            .observe(render_ms / 1e3);
        self.encode_seconds
            .get_or_create(&vec![("codec", codec.to_owned())])
            .observe(encode_ms / 1e3);
        self.bytes_sent
            .get_or_create(&vec![("source", source.to_owned())])
            .inc_by(bytes as u64);
    }

    /// Counts one error by kind.
    pub fn error(&self, kind: &str) {
        self.errors
            .get_or_create(&vec![("kind", kind.to_owned())])
            .inc();
    }

    /// Counts frames dropped for a slow client or superseded by a newer request.
    pub fn dropped(&self, count: u64) {
        self.dropped_frames.inc_by(count);
    }

    /// Adds `delta` to the open sessions gauge.
    pub fn sessions_add(&self, delta: i64) {
        self.sessions.inc_by(delta);
    }

    /// Counts a lost device.
    pub fn device_lost(&self) {
        self.devices_lost.inc();
    }

    /// Sets the number of loaded assets.
    pub fn set_assets(&self, count: usize) {
        self.assets.set(count as i64);
    }

    /// Sets the resident light fields, their texture bytes and the budget they are charged to.
    pub fn set_asset_memory(&self, light_fields: usize, bytes: u64, budget: u64) {
        let gauge = |v: u64| i64::try_from(v).unwrap_or(i64::MAX);
        self.light_fields.set(gauge(light_fields as u64));
        self.asset_memory.set(gauge(bytes));
        self.asset_memory_budget.set(gauge(budget));
    }

    /// Sets the server memory budget's gauges.
    pub fn set_memory(&self, used: u64, budget: u64) {
        let gauge = |v: u64| i64::try_from(v).unwrap_or(i64::MAX);
        self.memory_used.set(gauge(used));
        self.memory_budget.set(gauge(budget));
    }

    /// The text exposition of every metric.
    pub fn encode(&self) -> String {
        let mut out = String::new();
        // Writing into a String cannot fail.
        let _ = encode(&mut out, &self.registry);
        out
    }
}
