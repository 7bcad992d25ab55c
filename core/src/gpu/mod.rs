//! The one headless GPU device per process (DESIGN §6) and small helpers shared by the
//! pipelines: buffer readback and texture-array uploads.
//!
//! On CPU-only servers the adapter is Mesa's lavapipe (Vulkan) or llvmpipe (GL); on machines with
//! a GPU it is the GPU. `LUMIGRAPH_BACKEND` (vulkan | gl | metal | dx12 | auto) restricts the
//! backend; `LUMIGRAPH_ADAPTER` (auto | gpu | software | a name) picks the adapter among those the
//! backend offers ([`AdapterChoice`]).

use std::path::{Path, PathBuf};
use std::sync::{Arc, Once, OnceLock};

/// Errors while creating the device or talking to it.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GpuError {
    /// `LUMIGRAPH_BACKEND` holds an unknown value.
    #[error("LUMIGRAPH_BACKEND={0:?} is not one of vulkan, gl, metal, dx12, auto")]
    BadBackend(String),
    /// `LUMIGRAPH_ADAPTER` holds an empty or unusable value.
    #[error(
        "LUMIGRAPH_ADAPTER={0:?} is not auto, gpu, software or a non-empty part of an adapter name"
    )]
    BadAdapterChoice(String),
    /// An adapter was asked for by kind or name and none of those found is one.
    #[error("LUMIGRAPH_ADAPTER={choice}: no such adapter; found {found}{hint}")]
    AdapterNotFound {
        /// What was asked for.
        choice: String,
        /// The adapters there are, one `name [kind, backend]` each, or "none".
        found: String,
        /// What to do about it.
        hint: &'static str,
    },
    /// No adapter was found.
    #[error(
        "no GPU adapter found for backend {backend}: on a CPU-only Debian/Ubuntu machine install Mesa's \
         software Vulkan driver with `apt-get install -y mesa-vulkan-drivers libvulkan1` ({detail})"
    )]
    NoAdapter {
        /// The backends that were tried.
        backend: String,
        /// wgpu's reason.
        detail: String,
    },
    /// The adapter refused to create a device.
    #[error("cannot open the GPU device {adapter}: {detail}")]
    Device {
        /// Adapter name.
        adapter: String,
        /// wgpu's reason.
        detail: String,
    },
    /// The process-wide device could not be opened ([`Gpu::shared`] repeats the first
    /// attempt's error, kept as text).
    #[error("{0}")]
    Unavailable(String),
    /// A readback or submission failed.
    #[error("GPU operation failed: {0}")]
    Operation(String),
    /// The device is lost (driver reset, GPU removed, or [`Gpu::inject_device_loss`]): nothing
    /// more can run on it; open a new one and upload again.
    #[error("the GPU device is lost: {0}")]
    DeviceLost(String),
    /// A request exceeds what the device supports.
    #[error("{what} needs {needed} but the device allows at most {limit}")]
    Limit {
        /// What was asked for.
        what: &'static str,
        /// Needed amount.
        needed: u64,
        /// Device limit.
        limit: u64,
    },
}

/// The headless device with its queue; create once ([`Gpu::shared`]) and share.
pub struct Gpu {
    /// The wgpu device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// What the adapter reported.
    pub adapter_info: wgpu::AdapterInfo,
    /// Whether the adapter is a software rasterizer (lavapipe/llvmpipe).
    pub is_software: bool,
    /// The first uncaptured device error since the last check (wgpu would otherwise panic).
    device_error: Arc<std::sync::Mutex<Option<String>>>,
    /// Why the device is lost, once it is: set by wgpu's device-lost callback or by
    /// [`Gpu::inject_device_loss`]; never cleared.
    lost: Arc<std::sync::Mutex<Option<String>>>,
}

/// Unmaps buffers when dropped ([`Gpu::map_read_many`]), so no path out, a failed wait
/// included, leaves one mapped or pending (the next submission may not use it then); not those
/// whose mapping failed, for unmapping an unmapped buffer is itself an error.
struct Unmap<'a> {
    buffers: &'a [&'a wgpu::Buffer],
    failed: Vec<bool>,
}

impl Drop for Unmap<'_> {
    fn drop(&mut self) {
        for (buffer, failed) in self.buffers.iter().zip(&self.failed) {
            if !failed {
                buffer.unmap();
            }
        }
    }
}

static SHARED: OnceLock<Result<Arc<Gpu>, String>> = OnceLock::new();

/// Gives the process a private runtime directory when `XDG_RUNTIME_DIR` is unset, relative or
/// not a directory, so that nothing but lumigraph speaks on stderr: Mesa's device-select Vulkan
/// layer looks for a Wayland compositor while it lists adapters, and without a usable runtime
/// directory libwayland prints "error: XDG_RUNTIME_DIR is invalid or not set in the environment."
/// twice (no instance flag or backend choice avoids it: wgpu enables `VK_KHR_wayland_surface`
/// wherever the driver offers it, and that is what makes the layer look).
///
/// The directory is `<temp dir>/lumigraph-xdg-<uid>`, created with mode 700; one that exists is
/// used only when it is a directory (not a link) owned by this user and closed to others, else
/// the environment is left as it is. Runs at most once per process. The `lumigraph` binary and
/// the Python module call it before any thread starts; [`Gpu::new`] calls it too, for every
/// other caller.
pub fn ensure_runtime_dir() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        let usable = std::env::var_os("XDG_RUNTIME_DIR")
            .map(PathBuf::from)
            .is_some_and(|dir| dir.is_absolute() && dir.is_dir());
        if usable {
            return;
        }
        match private_runtime_dir() {
            Ok(dir) => set_runtime_dir(&dir),
            Err(error) => tracing::debug!("no private runtime directory: {error}"),
        }
    });
}

/// Creates (or checks) `<temp dir>/lumigraph-xdg-<uid>`: see [`ensure_runtime_dir`].
#[cfg(unix)]
fn private_runtime_dir() -> std::io::Result<PathBuf> {
    use std::os::unix::fs::{DirBuilderExt, MetadataExt};
    let uid = rustix::process::geteuid().as_raw();
    let dir = std::env::temp_dir().join(format!("lumigraph-xdg-{uid}"));
    if !dir.is_absolute() {
        return Err(std::io::Error::other(format!(
            "{} is not an absolute path",
            dir.display()
        )));
    }
    match std::fs::DirBuilder::new().mode(0o700).create(&dir) {
        Ok(()) => {}
        Err(error) if error.kind() == std::io::ErrorKind::AlreadyExists => {}
        Err(error) => return Err(error),
    }
    // Made now or by an earlier run, or by someone else: trusted only if ours and private.
    let meta = std::fs::symlink_metadata(&dir)?;
    if !meta.is_dir() || meta.uid() != uid || meta.mode() & 0o077 != 0 {
        return Err(std::io::Error::other(format!(
            "{} is not a private directory of this user",
            dir.display()
        )));
    }
    Ok(dir)
}

#[cfg(not(unix))]
fn private_runtime_dir() -> std::io::Result<PathBuf> {
    Err(std::io::ErrorKind::Unsupported.into())
}

#[allow(unsafe_code)]
fn set_runtime_dir(dir: &Path) {
    // SAFETY: `set_var` is unsound only while another thread reads or writes the environment
    // (libc's `getenv` included). This runs at most once per process (the `Once` in
    // `ensure_runtime_dir`): first thing in the `lumigraph` binary's `main` and in the Python
    // module's initialisation, before any thread of ours exists; otherwise in `Gpu::new` before
    // the process's first GPU instance, where the caller must not touch the environment from
    // another thread at the same moment (the reason the fronts call it early).
    unsafe { std::env::set_var("XDG_RUNTIME_DIR", dir) };
}

/// Which adapter to open, from `LUMIGRAPH_ADAPTER`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum AdapterChoice {
    /// wgpu's high-performance choice: the GPU where there is one, else the software rasterizer
    /// (the default; unset or `auto`).
    Auto,
    /// A hardware adapter, discrete before integrated; none is an error
    /// ([`GpuError::AdapterNotFound`]) instead of falling back to the CPU (`gpu`).
    Gpu,
    /// The software rasterizer (lavapipe, llvmpipe) even where a GPU exists (`software`).
    Software,
    /// The first adapter whose name contains this text, case-insensitive (e.g. `H200`).
    Name(String),
}

impl AdapterChoice {
    /// Parses `auto`, `gpu`, `software` (also `cpu`) or a name part.
    ///
    /// # Errors
    /// [`GpuError::BadAdapterChoice`] for an empty value.
    pub fn parse(value: &str) -> Result<AdapterChoice, GpuError> {
        let trimmed = value.trim();
        Ok(match trimmed.to_ascii_lowercase().as_str() {
            "" => return Err(GpuError::BadAdapterChoice(value.to_owned())),
            "auto" => AdapterChoice::Auto,
            "gpu" | "hardware" => AdapterChoice::Gpu,
            "software" | "cpu" => AdapterChoice::Software,
            _ => AdapterChoice::Name(trimmed.to_owned()),
        })
    }

    /// The choice `LUMIGRAPH_ADAPTER` makes (unset: [`AdapterChoice::Auto`]).
    ///
    /// # Errors
    /// [`GpuError::BadAdapterChoice`] for an empty or non-UTF-8 value.
    pub fn from_env() -> Result<AdapterChoice, GpuError> {
        match std::env::var("LUMIGRAPH_ADAPTER") {
            Ok(value) => AdapterChoice::parse(&value),
            Err(std::env::VarError::NotPresent) => Ok(AdapterChoice::Auto),
            Err(std::env::VarError::NotUnicode(raw)) => Err(GpuError::BadAdapterChoice(
                raw.to_string_lossy().into_owned(),
            )),
        }
    }

    fn describe(&self) -> String {
        match self {
            AdapterChoice::Auto => "auto".to_owned(),
            AdapterChoice::Gpu => "gpu".to_owned(),
            AdapterChoice::Software => "software".to_owned(),
            AdapterChoice::Name(name) => format!("{name:?}"),
        }
    }

    /// The rank of an adapter for this choice (lower is better), or `None` where it does not
    /// qualify.
    fn rank(&self, name: &str, device_type: wgpu::DeviceType) -> Option<u8> {
        let software = is_software_adapter(name, device_type);
        match self {
            AdapterChoice::Auto => Some(0),
            AdapterChoice::Gpu if software => None,
            AdapterChoice::Gpu => Some(match device_type {
                wgpu::DeviceType::DiscreteGpu => 0,
                wgpu::DeviceType::IntegratedGpu => 1,
                _ => 2,
            }),
            AdapterChoice::Software => software.then_some(0),
            AdapterChoice::Name(part) => name
                .to_lowercase()
                .contains(&part.to_lowercase())
                .then_some(0),
        }
    }
}

/// Whether wgpu's adapter is a software rasterizer (lavapipe, llvmpipe, any CPU device).
fn is_software_adapter(name: &str, device_type: wgpu::DeviceType) -> bool {
    device_type == wgpu::DeviceType::Cpu || name.contains("llvmpipe") || name.contains("lavapipe")
}

fn backends_from_env() -> Result<(wgpu::Backends, String), GpuError> {
    let value = std::env::var("LUMIGRAPH_BACKEND").unwrap_or_else(|_| "auto".to_owned());
    let backends = match value.to_ascii_lowercase().as_str() {
        "" | "auto" => wgpu::Backends::all(),
        "vulkan" => wgpu::Backends::VULKAN,
        "gl" | "gles" | "opengl" => wgpu::Backends::GL,
        "metal" => wgpu::Backends::METAL,
        "dx12" => wgpu::Backends::DX12,
        _ => return Err(GpuError::BadBackend(value)),
    };
    Ok((backends, value))
}

impl Gpu {
    /// The process-wide device, created on first use. Later calls return the same device (or the
    /// same error).
    ///
    /// # Errors
    /// See [`Gpu::new`].
    pub fn shared() -> Result<Arc<Gpu>, GpuError> {
        SHARED
            .get_or_init(|| Gpu::new().map(Arc::new).map_err(|e| e.to_string()))
            .clone()
            .map_err(GpuError::Unavailable)
    }

    /// Opens a new headless device on the backend `LUMIGRAPH_BACKEND` selects.
    ///
    /// # Errors
    /// [`GpuError::BadBackend`], [`GpuError::NoAdapter`] (the message names the package to
    /// install), [`GpuError::Device`].
    pub fn new() -> Result<Gpu, GpuError> {
        ensure_runtime_dir();
        let (backends, backend_name) = backends_from_env()?;
        let choice = AdapterChoice::from_env()?;
        // `auto` tries the native backends first (Vulkan/Metal/DX12: lavapipe on CPU-only Linux)
        // and falls back to GL only when none has an adapter.
        let attempts = if backends == wgpu::Backends::all() {
            vec![wgpu::Backends::PRIMARY, wgpu::Backends::GL]
        } else {
            vec![backends]
        };
        let mut last_error = String::from("no backend tried");
        let mut found = None;
        let mut seen = Vec::new();
        for attempt in attempts {
            let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
            desc.backends = attempt;
            let instance = wgpu::Instance::new(desc);
            if choice != AdapterChoice::Auto {
                let adapters = pollster::block_on(instance.enumerate_adapters(attempt));
                let best = adapters
                    .into_iter()
                    .filter_map(|adapter| {
                        let info = adapter.get_info();
                        seen.push(format!(
                            "{} [{:?}, {:?}]",
                            info.name, info.device_type, info.backend
                        ));
                        choice
                            .rank(&info.name, info.device_type)
                            .map(|rank| (rank, adapter))
                    })
                    .min_by_key(|(rank, _)| *rank);
                if let Some((_, adapter)) = best {
                    found = Some(adapter);
                    break;
                }
                continue;
            }
            match pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
                power_preference: wgpu::PowerPreference::HighPerformance,
                force_fallback_adapter: false,
                compatible_surface: None,
                apply_limit_buckets: false,
            })) {
                Ok(adapter) => {
                    found = Some(adapter);
                    break;
                }
                Err(e) => last_error = e.to_string(),
            }
        }
        let adapter = match found {
            Some(adapter) => adapter,
            None if choice == AdapterChoice::Auto => {
                return Err(GpuError::NoAdapter {
                    backend: backend_name,
                    detail: last_error,
                });
            }
            None => {
                return Err(GpuError::AdapterNotFound {
                    choice: choice.describe(),
                    found: if seen.is_empty() {
                        "none".to_owned()
                    } else {
                        seen.join(", ")
                    },
                    hint: match choice {
                        AdapterChoice::Gpu => {
                            " (only software rasterizers: in a container, give it the GPU, e.g. \
                             the NVIDIA container toolkit with --gpus all, which mounts the \
                             driver's Vulkan ICD; or set LUMIGRAPH_ADAPTER=auto to accept the CPU)"
                        }
                        AdapterChoice::Software => {
                            " (install Mesa's software Vulkan driver: apt-get install -y \
                             mesa-vulkan-drivers libvulkan1)"
                        }
                        _ => "",
                    },
                });
            }
        };
        let adapter_info = adapter.get_info();
        let is_software = is_software_adapter(&adapter_info.name, adapter_info.device_type);
        // Ask for everything the adapter can do: camera arrays need up to 642+1 layers and large
        // storage buffers, far above wgpu's portable defaults.
        let limits = adapter.limits();
        // Subgroup operations, where there are any, cut the marcher's counter atomics 8-fold
        // (`render::shader_source`).
        // On a CPU adapter "device" memory is host memory: results are mapped where the shaders
        // wrote them instead of copied to a staging buffer first (`maps_primary_buffers`). On a
        // discrete GPU that would make the shaders write across the bus, so it is not asked for.
        // Block-compressed textures (BC1-7) where the adapter samples them: block-compressed
        // assets then stay compressed on the device (`asset::BlockCodec`).
        let mut wanted = wgpu::Features::FLOAT32_FILTERABLE
            | wgpu::Features::SUBGROUP
            | wgpu::Features::TEXTURE_COMPRESSION_BC;
        if is_software {
            wanted |= wgpu::Features::MAPPABLE_PRIMARY_BUFFERS;
        }
        let features = adapter.features() & wanted;
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("lumigraph"),
            required_features: features,
            required_limits: limits,
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| GpuError::Device {
            adapter: adapter_info.name.clone(),
            detail: e.to_string(),
        })?;
        // Validation or out-of-memory errors become `GpuError`s at the next wait instead of a
        // panic inside wgpu's default handler.
        let device_error: Arc<std::sync::Mutex<Option<String>>> = Arc::default();
        let sink = device_error.clone();
        device.on_uncaptured_error(Arc::new(move |error: wgpu::Error| {
            tracing::error!("GPU error: {error}");
            let mut slot = sink
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            if slot.is_none() {
                *slot = Some(error.to_string());
            }
        }));
        let lost: Arc<std::sync::Mutex<Option<String>>> = Arc::default();
        let lost_sink = lost.clone();
        device.set_device_lost_callback(move |reason, message| {
            tracing::error!(?reason, message, "the GPU device is lost");
            lost_sink
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .get_or_insert_with(|| format!("{reason:?}: {message}"));
        });
        let gpu = Gpu {
            device,
            queue,
            adapter_info,
            is_software,
            device_error,
            lost,
        };
        tracing::info!("{}", gpu.adapter_summary());
        if gpu.is_software {
            tracing::info!("the adapter is a software rasterizer: rendering runs on the CPU cores");
        }
        Ok(gpu)
    }

    /// One line naming the adapter, driver and backend.
    pub fn adapter_summary(&self) -> String {
        let info = &self.adapter_info;
        format!(
            "GPU adapter: {} ({:?}, {:?} backend, driver {} {}){}",
            info.name,
            info.device_type,
            info.backend,
            info.driver,
            info.driver_info,
            if self.is_software {
                " [software rasterizer]"
            } else {
                ""
            }
        )
    }

    /// Whether buffers the shaders write can be mapped for reading directly (a CPU adapter
    /// offering `MAPPABLE_PRIMARY_BUFFERS`): results are then read where they were written,
    /// without a copy to a staging buffer.
    pub fn maps_primary_buffers(&self) -> bool {
        self.device
            .features()
            .contains(wgpu::Features::MAPPABLE_PRIMARY_BUFFERS)
    }

    /// Whether the device samples BC1-7 block-compressed textures.
    pub fn samples_bc(&self) -> bool {
        self.device
            .features()
            .contains(wgpu::Features::TEXTURE_COMPRESSION_BC)
    }

    /// Whether textures of `codec` should stay compressed on this device: it samples BC, and the
    /// codec is cheap to sample there. A CPU adapter decodes every fetch in software, which
    /// for BC7 costs 6-15× the frame time of RGBA8 on lavapipe (BENCHMARKS.md "Block
    /// compression"), so BC7 is decoded on the host there; BC1 samples as fast as RGBA8.
    /// `LUMIGRAPH_BC_ON_DEVICE=all` keeps every codec the device samples compressed (to
    /// measure the cost).
    pub fn keeps_compressed(&self, codec: crate::asset::BlockCodec) -> bool {
        let all = std::env::var("LUMIGRAPH_BC_ON_DEVICE").is_ok_and(|v| v == "all");
        codec.texture_format().is_some()
            && self.samples_bc()
            && (all || codec == crate::asset::BlockCodec::Bc1 || !self.is_software)
    }

    /// Why the device is lost, or `None` while it works.
    pub fn lost(&self) -> Option<String> {
        self.lost
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
    }

    /// Marks the device lost, as a driver reset would: every later wait (so every render,
    /// upload, bake and readback) fails with [`GpuError::DeviceLost`]. A software adapter cannot
    /// lose its device, so recovery paths are tested with this hook.
    pub fn inject_device_loss(&self, why: &str) {
        tracing::warn!(why, "device loss injected");
        self.lost
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .get_or_insert_with(|| format!("injected: {why}"));
    }

    /// Blocks until the submitted work is done.
    ///
    /// # Errors
    /// [`GpuError::DeviceLost`] when the device is lost; [`GpuError::Operation`] when the wait
    /// or earlier work failed.
    pub fn wait(&self) -> Result<(), GpuError> {
        if let Some(why) = self.lost() {
            return Err(GpuError::DeviceLost(why));
        }
        let polled = self.device.poll(wgpu::PollType::wait_indefinitely());
        if let Some(why) = self.lost() {
            return Err(GpuError::DeviceLost(why));
        }
        polled.map_err(|e| GpuError::Operation(e.to_string()))?;
        let error = self
            .device_error
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .take();
        match error {
            Some(message) => Err(GpuError::Operation(message)),
            None => Ok(()),
        }
    }

    /// Copies `size` bytes of `source` (which needs `COPY_SRC`) back to the CPU.
    ///
    /// # Errors
    /// [`GpuError::Operation`] when mapping fails.
    pub fn read_buffer(&self, source: &wgpu::Buffer, size: u64) -> Result<Vec<u8>, GpuError> {
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("readback"),
            });
        encoder.copy_buffer_to_buffer(source, 0, &staging, 0, size);
        self.queue.submit([encoder.finish()]);
        self.map_read(&staging)
    }

    /// Maps a `MAP_READ` buffer and copies it out.
    ///
    /// # Errors
    /// [`GpuError::Operation`] when mapping fails.
    pub fn map_read(&self, staging: &wgpu::Buffer) -> Result<Vec<u8>, GpuError> {
        self.map_read_with(staging, <[u8]>::to_vec)
    }

    /// Maps a `MAP_READ` buffer and hands its bytes to `read` (no intermediate copy).
    ///
    /// # Errors
    /// [`GpuError::Operation`] when mapping fails.
    pub fn map_read_with<T>(
        &self,
        staging: &wgpu::Buffer,
        read: impl FnOnce(&[u8]) -> T,
    ) -> Result<T, GpuError> {
        self.map_read_many(&[staging], |bytes| read(bytes[0]))
    }

    /// Maps several `MAP_READ` buffers at once (one wait) and hands their bytes to `read`, in
    /// order; every buffer is unmapped again afterwards, whatever happened.
    ///
    /// # Errors
    /// [`GpuError::Operation`] when mapping fails.
    pub fn map_read_many<T>(
        &self,
        buffers: &[&wgpu::Buffer],
        read: impl FnOnce(&[&[u8]]) -> T,
    ) -> Result<T, GpuError> {
        let (sender, receiver) = std::sync::mpsc::channel();
        for (index, buffer) in buffers.iter().enumerate() {
            let sender = sender.clone();
            buffer
                .slice(..)
                .map_async(wgpu::MapMode::Read, move |result| {
                    let _ = sender.send((index, result));
                });
        }
        drop(sender);
        let mut guard = Unmap {
            buffers,
            failed: vec![false; buffers.len()],
        };
        self.wait()?;
        let mut first_error = None;
        for _ in buffers {
            let (index, result) = receiver
                .recv()
                .map_err(|e| GpuError::Operation(e.to_string()))?;
            if let Err(e) = result {
                guard.failed[index] = true;
                first_error.get_or_insert(GpuError::Operation(e.to_string()));
            }
        }
        if let Some(e) = first_error {
            return Err(e);
        }
        let views = buffers
            .iter()
            .map(|b| {
                b.slice(..)
                    .get_mapped_range()
                    .map_err(|e| GpuError::Operation(e.to_string()))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let bytes: Vec<&[u8]> = views.iter().map(|v| &v[..]).collect();
        let value = read(&bytes);
        drop(bytes);
        drop(views);
        Ok(value)
    }

    /// Layer count to allocate for `layers` images of a square texture array: one extra layer
    /// when the count is a multiple of 6, because wgpu's GL backend silently treats such arrays
    /// as cube-map arrays (PLATFORM.md).
    /// A single layer is padded to two for the same reason: GL would bind it as a plain 2D
    /// texture, not an array.
    pub fn padded_layers(layers: u32) -> u32 {
        if layers <= 1 {
            2
        } else if layers.is_multiple_of(6) {
            layers + 1
        } else {
            layers
        }
    }

    /// Checks `layers` against the device's texture-array limit.
    ///
    /// # Errors
    /// [`GpuError::Limit`].
    pub fn check_layers(&self, layers: u32) -> Result<(), GpuError> {
        let limit = self.device.limits().max_texture_array_layers;
        if layers > limit {
            return Err(GpuError::Limit {
                what: "texture array layers",
                needed: layers.into(),
                limit: limit.into(),
            });
        }
        Ok(())
    }

    /// Checks a storage buffer size against the device limits.
    ///
    /// # Errors
    /// [`GpuError::Limit`].
    pub fn check_storage(&self, what: &'static str, bytes: u64) -> Result<(), GpuError> {
        let limits = self.device.limits();
        let limit = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        if bytes > limit {
            return Err(GpuError::Limit {
                what,
                needed: bytes,
                limit,
            });
        }
        Ok(())
    }
}

/// Creates a storage buffer initialised with `contents` (never empty: wgpu rejects zero-size
/// bindings, so an empty slice becomes 16 zero bytes).
pub(crate) fn storage_buffer(
    gpu: &Gpu,
    label: &str,
    contents: &[u8],
    extra: wgpu::BufferUsages,
) -> wgpu::Buffer {
    use wgpu::util::DeviceExt;
    let zeros = [0u8; 16];
    let data = if contents.is_empty() {
        &zeros[..]
    } else {
        contents
    };
    gpu.device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: data,
            usage: wgpu::BufferUsages::STORAGE | extra,
        })
}

/// A compute bind-group layout entry for a buffer of type `ty`.
pub(crate) fn buffer_entry(
    binding: u32,
    ty: wgpu::BufferBindingType,
) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// A compute bind-group layout entry for a float 2D texture array.
pub(crate) fn texture_entry(binding: u32, filterable: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable },
            view_dimension: wgpu::TextureViewDimension::D2Array,
            multisampled: false,
        },
        count: None,
    }
}

/// A new, empty 2D texture (array) of `layers` layers that shaders sample and copies fill.
pub(crate) fn empty_texture_array(
    gpu: &Gpu,
    label: &str,
    format: wgpu::TextureFormat,
    size: [u32; 3],
) -> wgpu::Texture {
    empty_texture_array_with_mips(gpu, label, format, size, 1)
}

/// [`empty_texture_array`] with `mip_levels` mip levels (each `max(1, side >> level)`).
pub(crate) fn empty_texture_array_with_mips(
    gpu: &Gpu,
    label: &str,
    format: wgpu::TextureFormat,
    [width, height, layers]: [u32; 3],
    mip_levels: u32,
) -> wgpu::Texture {
    gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: layers,
        },
        mip_level_count: mip_levels,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    })
}

/// Uploads `layers` equally sized images into a new 2D texture array (padded per
/// [`Gpu::padded_layers`]).
pub(crate) fn texture_array(
    gpu: &Gpu,
    label: &str,
    format: wgpu::TextureFormat,
    width: u32,
    height: u32,
    images: &[&[u8]],
) -> wgpu::Texture {
    let bytes_per_texel = format.block_copy_size(None).unwrap_or(4);
    let layers = Gpu::padded_layers(u32::try_from(images.len()).unwrap_or(u32::MAX));
    let texture = empty_texture_array(gpu, label, format, [width, height, layers]);
    for (layer, image) in images.iter().enumerate() {
        gpu.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &texture,
                mip_level: 0,
                origin: wgpu::Origin3d {
                    x: 0,
                    y: 0,
                    z: u32::try_from(layer).unwrap_or(0),
                },
                aspect: wgpu::TextureAspect::All,
            },
            image,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(width * bytes_per_texel),
                rows_per_image: Some(height),
            },
            wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
        );
    }
    texture
}

/// Texture-array view covering every layer.
pub(crate) fn array_view(texture: &wgpu::Texture) -> wgpu::TextureView {
    texture.create_view(&wgpu::TextureViewDescriptor {
        dimension: Some(wgpu::TextureViewDimension::D2Array),
        ..Default::default()
    })
}
pub mod bvh;
pub mod mesh;

#[cfg(test)]
mod tests {
    use super::AdapterChoice;
    use wgpu::DeviceType;

    #[test]
    fn adapter_choices_parse() {
        assert_eq!(AdapterChoice::parse("auto").ok(), Some(AdapterChoice::Auto));
        assert_eq!(AdapterChoice::parse(" GPU ").ok(), Some(AdapterChoice::Gpu));
        assert_eq!(
            AdapterChoice::parse("cpu").ok(),
            Some(AdapterChoice::Software)
        );
        assert_eq!(
            AdapterChoice::parse("H200").ok(),
            Some(AdapterChoice::Name("H200".to_owned()))
        );
        let empty = AdapterChoice::parse("  ").err().map(|e| e.to_string());
        assert!(empty.is_some_and(|m| m.contains("LUMIGRAPH_ADAPTER")));
    }

    #[test]
    fn adapter_choices_rank() {
        let lavapipe = "llvmpipe (LLVM 15.0.6, 256 bits)";
        let gpu = AdapterChoice::Gpu;
        assert_eq!(gpu.rank(lavapipe, DeviceType::Cpu), None);
        assert_eq!(gpu.rank("NVIDIA H200", DeviceType::DiscreteGpu), Some(0));
        assert_eq!(gpu.rank("Intel UHD", DeviceType::IntegratedGpu), Some(1));
        // A software rasterizer that calls itself something else is still software.
        assert_eq!(gpu.rank(lavapipe, DeviceType::Other), None);
        let software = AdapterChoice::Software;
        assert_eq!(software.rank(lavapipe, DeviceType::Cpu), Some(0));
        assert_eq!(software.rank("NVIDIA H200", DeviceType::DiscreteGpu), None);
        let name = AdapterChoice::Name("h200".to_owned());
        assert_eq!(name.rank("NVIDIA H200", DeviceType::DiscreteGpu), Some(0));
        assert_eq!(name.rank(lavapipe, DeviceType::Cpu), None);
    }
}
