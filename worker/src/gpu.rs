//! The GPU a worker computes on: adapter, device and queue, requested with
//! every limit the adapter offers (lavapipe allows 32 storage buffers per
//! stage where wgpu's defaults allow 8).

use anyhow::Context;
use serde::Serialize;

/// Mesa's variable for lavapipe's SIMD width (llvmpipe runs a shader's
/// invocations as the lanes of one CPU vector).
pub const LAVAPIPE_WIDTH_VAR: &str = "LP_NATIVE_VECTOR_WIDTH";

/// Asks lavapipe for 4-lane (128-bit) vectors instead of the 8 lanes AVX2
/// allows, unless the user chose: rays of one vector diverge, and with half
/// as many lanes fewer wait on the longest (Mesa 25 on this project's
/// 2-core machine: frames 13 % faster, the reference's err² × s 0.127
/// against 0.139, the GPU LB 18.8 against 15.9 MLUPS; docs/tracing.md).
/// Other drivers ignore the variable.
///
/// # Safety
/// Sets an environment variable: call it before any other thread exists
/// (first thing in `main`), and before the first Vulkan instance.
pub unsafe fn prefer_narrow_lavapipe_lanes() {
    if std::env::var_os(LAVAPIPE_WIDTH_VAR).is_none() {
        // SAFETY: the caller guarantees no other thread reads the environment.
        unsafe { std::env::set_var(LAVAPIPE_WIDTH_VAR, "128") };
    }
}

/// Set to 1, the device is opened without ray queries even where the
/// adapter has them (a driver whose ray queries misbehave; measuring what
/// the feature costs the other kernels).
pub const NO_RAY_QUERIES_VAR: &str = "SYLVA_NO_RAY_QUERIES";

/// An open GPU device (cheap to clone: wgpu's handles are shared).
#[derive(Clone)]
pub struct GpuContext {
    /// The adapter the device was opened on.
    pub adapter: wgpu::Adapter,
    /// The logical device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// The device's limits (the adapter's own).
    pub limits: wgpu::Limits,
    /// Compiled kernels kept on disk, once a folder is given
    /// ([`GpuContext::keep_kernels_in`]).
    kept: std::sync::Arc<std::sync::OnceLock<KeptKernels>>,
    /// The LB solver's kernels and grids kept on this device across solves
    /// (channels, suns, frames).
    pub(crate) lb: std::sync::Arc<std::sync::Mutex<crate::lb::DeviceLb>>,
}

/// The most bytes of kept kernels read back: a bound on what a file may
/// make this process hold, far above a pipeline cache of this project's
/// few dozen kernels; a larger file is not read, and the kernels are
/// compiled over it.
const MAX_KEPT_KERNELS_BYTES: u64 = 256 << 20;

/// The driver's compiled kernels (a Vulkan pipeline cache) kept in a file
/// between processes, so a warm process compiles nothing it compiled
/// before. The file is named by the adapter and driver, and holds the
/// BLAKE3 of its data before the data: what is read is checked before the
/// driver sees it (wgpu checks only the header, the driver its own).
struct KeptKernels {
    cache: wgpu::PipelineCache,
    path: std::path::PathBuf,
    /// Bytes of the data last written (or read): nothing new, nothing written.
    saved: std::sync::atomic::AtomicUsize,
}

impl GpuContext {
    /// Opens the highest-performance adapter wgpu can find.
    pub fn new() -> anyhow::Result<Self> {
        pollster::block_on(Self::open())
    }

    async fn open() -> anyhow::Result<Self> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let adapter = instance
            .request_adapter(&wgpu::RequestAdapterOptions { power_preference: wgpu::PowerPreference::HighPerformance, ..Default::default() })
            .await
            .context(
                "no GPU adapter found: install a Vulkan driver (on Debian, `apt-get install mesa-vulkan-drivers` gives the lavapipe CPU driver)",
            )?;
        let limits = adapter.limits();
        // Ray queries where the adapter has them (the `rq` backend). wgpu
        // calls the feature experimental: its API may change between
        // releases, which this crate's pinned wgpu version absorbs.
        let mut ray_queries = adapter.features() & wgpu::Features::EXPERIMENTAL_RAY_QUERY;
        if std::env::var_os(NO_RAY_QUERIES_VAR).is_some_and(|v| v == "1") {
            ray_queries = wgpu::Features::empty();
        }
        // GPU timestamps where the adapter has them: kernels timed by the
        // device itself, apart from uploads and read-backs (`bench trace`).
        let timestamps = adapter.features() & wgpu::Features::TIMESTAMP_QUERY;
        // A cache of compiled kernels the process can keep on disk.
        let pipeline_cache = adapter.features() & wgpu::Features::PIPELINE_CACHE;
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("sylva"),
                required_features: ray_queries | timestamps | pipeline_cache,
                required_limits: limits.clone(),
                // SAFETY: only the ray-query feature is experimental, and
                // wgpu validates its use like any other feature's.
                experimental_features: unsafe { wgpu::ExperimentalFeatures::enabled() },
                ..Default::default()
            })
            .await
            .with_context(|| format!("cannot open a device on {}", adapter.get_info().name))?;
        device.on_uncaptured_error(std::sync::Arc::new(|e| tracing::error!("wgpu: {e}")));
        let ctx = Self {
            adapter,
            device,
            queue,
            limits,
            kept: Default::default(),
            lb: Default::default(),
        };
        tracing::info!(adapter = %ctx.adapter_name(), "GPU opened");
        Ok(ctx)
    }

    /// Keeps the driver's compiled kernels in `dir` (the prepared-data
    /// cache's folder): reads what an earlier process left for this
    /// adapter and driver, checked, and from then on every kernel compiled
    /// goes through it. Call it before compiling; later calls do nothing,
    /// and neither does an adapter without pipeline caches.
    pub fn keep_kernels_in(&self, dir: &std::path::Path) {
        if self.kept.get().is_some()
            || !self.device.features().contains(wgpu::Features::PIPELINE_CACHE)
        {
            return;
        }
        let info = self.adapter.get_info();
        let Some(key) = wgpu::util::pipeline_cache_key(&info) else { return };
        let driver = blake3::hash(format!("{} {}", info.driver, info.driver_info).as_bytes());
        let path = dir.join(format!("{key}_{}.kernels", &driver.to_hex()[..16]));
        // Larger than any set of kernels a driver keeps: not read at all.
        let bounded = std::fs::metadata(&path).is_ok_and(|m| m.len() <= MAX_KEPT_KERNELS_BYTES);
        let data = bounded.then(|| std::fs::read(&path).ok()).flatten().and_then(|raw| {
            let checked = raw.len() > 64
                && blake3::hash(&raw[64..]).to_hex().as_bytes() == &raw[..64];
            if !checked {
                tracing::warn!(file = %path.display(), "kept kernels refused: their bytes do not match their hash; compiling anew");
                let _ = std::fs::remove_file(&path);
            }
            checked.then(|| raw[64..].to_vec())
        });
        let read = data.as_ref().map_or(0, Vec::len);
        // SAFETY: the data is what `PipelineCache::get_data` returned for
        // this adapter and driver (the file's name), unchanged since (its
        // hash); wgpu and the driver check their headers, and `fallback`
        // starts an empty cache where they refuse it.
        let cache = unsafe {
            self.device.create_pipeline_cache(&wgpu::PipelineCacheDescriptor {
                label: Some("kept kernels"),
                data: data.as_deref(),
                fallback: true,
            })
        };
        if read > 0 {
            tracing::info!(file = %path.display(), bytes = read, "compiled kernels read from the cache");
        }
        let _ = self.kept.set(KeptKernels { cache, path, saved: read.into() });
    }

    /// The pipeline cache every kernel compiles through, once one is kept.
    pub fn pipeline_cache(&self) -> Option<&wgpu::PipelineCache> {
        self.kept.get().map(|k| &k.cache)
    }

    /// Writes the kept kernels to their file when they grew (whole or not
    /// at all: a temporary file renamed into place); failures are logged,
    /// as the cache only ever saves work.
    pub fn save_kernels(&self) {
        use std::sync::atomic::Ordering;
        let Some(k) = self.kept.get() else { return };
        let Some(data) = k.cache.get_data() else { return };
        if data.is_empty() || data.len() == k.saved.load(Ordering::Relaxed) {
            return;
        }
        let mut bytes = blake3::hash(&data).to_hex().as_bytes().to_vec();
        bytes.extend_from_slice(&data);
        let tmp = k.path.with_extension(format!("{}.tmp", std::process::id()));
        let written = std::fs::write(&tmp, &bytes).and_then(|_| std::fs::rename(&tmp, &k.path));
        match written {
            Ok(()) => k.saved.store(data.len(), Ordering::Relaxed),
            Err(e) => {
                let _ = std::fs::remove_file(&tmp);
                tracing::warn!(file = %k.path.display(), "compiled kernels not kept: {e}");
            }
        }
    }

    /// Whether the device can time its own passes (timestamp queries).
    pub fn has_timestamps(&self) -> bool {
        self.device.features().contains(wgpu::Features::TIMESTAMP_QUERY)
    }

    /// Whether the device traces rays in hardware through ray queries
    /// (the `rq` backend; lavapipe emulates them).
    pub fn has_ray_queries(&self) -> bool {
        self.device.features().contains(wgpu::Features::EXPERIMENTAL_RAY_QUERY)
    }

    /// Whether the adapter is the CPU itself (lavapipe, llvmpipe): work a
    /// GPU does in milliseconds may take it minutes.
    pub fn is_cpu(&self) -> bool {
        self.adapter.get_info().device_type == wgpu::DeviceType::Cpu
    }

    /// The adapter's name and driver, as reports print it.
    pub fn adapter_name(&self) -> String {
        let i = self.adapter.get_info();
        let driver = if i.driver.is_empty() {
            String::new()
        } else {
            format!(", {} {}", i.driver, i.driver_info)
        };
        format!("{} ({:?}{driver})", i.name, i.backend)
    }

    /// A summary for JSON reports.
    pub fn summary(&self) -> AdapterSummary {
        let i = self.adapter.get_info();
        AdapterSummary {
            name: i.name,
            backend: format!("{:?}", i.backend),
            device_type: format!("{:?}", i.device_type),
            driver: format!("{} {}", i.driver, i.driver_info).trim().to_string(),
            max_storage_binding_bytes: self.limits.max_storage_buffer_binding_size,
            max_buffer_bytes: self.limits.max_buffer_size,
            ray_queries: self.has_ray_queries(),
        }
    }

    /// Runs `f` inside validation and out-of-memory error scopes, so a wgpu
    /// error becomes this call's error rather than a log line.
    pub fn checked<T>(
        &self,
        what: &str,
        f: impl FnOnce() -> anyhow::Result<T>,
    ) -> anyhow::Result<T> {
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let invalid = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let out = f();
        let errors = [pollster::block_on(invalid.pop()), pollster::block_on(oom.pop())];
        if let Some(e) = errors.into_iter().flatten().next() {
            anyhow::bail!("{what} on {}: {e}", self.adapter_name());
        }
        out
    }

    /// Compiles WGSL without the bounds checks, loop counters and division
    /// checks wgpu would add: they cost the LB step and the traversal
    /// kernels dearly on lavapipe, and these kernels only index the buffers
    /// their own Rust side sizes (the GPU-against-CPU tests cover them).
    pub fn trusted_module(&self, label: &str, source: String) -> wgpu::ShaderModule {
        let desc = wgpu::ShaderModuleDescriptor {
            label: Some(label),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        };
        // SAFETY: see above; every buffer a kernel indexes is sized by the
        // code that dispatches it, and all loops are bounded by data we build.
        unsafe {
            self.device.create_shader_module_trusted(desc, wgpu::ShaderRuntimeChecks::unchecked())
        }
    }

    /// Waits for all submitted work.
    pub fn wait(&self) -> anyhow::Result<()> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .context("GPU device lost while waiting")?;
        Ok(())
    }

    /// Copies `buffer[..bytes]` back to the host (the buffer needs `COPY_SRC`).
    pub fn read_back(&self, buffer: &wgpu::Buffer, bytes: u64) -> anyhow::Result<Vec<u8>> {
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("read-back"),
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = self.device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(buffer, 0, &staging, 0, bytes);
        self.queue.submit([enc.finish()]);
        self.map_read(&staging)
    }

    /// Maps a `MAP_READ` buffer, copies it out and unmaps it.
    pub fn map_read(&self, staging: &wgpu::Buffer) -> anyhow::Result<Vec<u8>> {
        let (tx, rx) = std::sync::mpsc::channel();
        staging.map_async(wgpu::MapMode::Read, .., move |r| {
            let _ = tx.send(r);
        });
        self.wait()?;
        rx.recv().context("GPU map callback dropped")?.context("cannot map a read-back buffer")?;
        let bytes = staging.get_mapped_range(..).context("cannot read a mapped buffer")?.to_vec();
        staging.unmap();
        Ok(bytes)
    }
}

/// A compute kernel's storage-buffer binding, read-only or not.
pub fn storage_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// What reports say about the GPU.
#[derive(Clone, Debug, Serialize)]
pub struct AdapterSummary {
    /// Adapter name ("llvmpipe (LLVM 15.0.6, 256 bits)", "NVIDIA H100 …").
    pub name: String,
    /// Backend ("Vulkan").
    pub backend: String,
    /// Kind of device ("Cpu", "DiscreteGpu").
    pub device_type: String,
    /// Driver name and version.
    pub driver: String,
    /// Largest storage binding, in bytes.
    pub max_storage_binding_bytes: u64,
    /// Largest buffer, in bytes.
    pub max_buffer_bytes: u64,
    /// Whether it offers ray queries (the `rq` backend).
    pub ray_queries: bool,
}
