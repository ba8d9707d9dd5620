//! The one crate that owns the GPU: wgpu instance, adapter and device, kernel pipelines, buffers.
//!
//! Stage crates get a [`GpuContext`] and build [`Kernel`]s from WGSL sources composed by
//! [`shaders::source`] (a kernel's `// requires:` line names its shared files). Every kernel has a CPU twin in its
//! stage crate; tests hold the two together. [`test_context`] is how tests get a device: with
//! `PC_REQUIRE_GPU=1` a missing adapter fails the test instead of skipping it.

use std::sync::mpsc;
use std::time::Instant;

pub mod shaders;
mod times;

pub use times::{times, GpuTimes};

/// A GPU buffer (wgpu's), as kernels bind it: stage crates name it through here and never
/// depend on wgpu themselves.
pub use wgpu::Buffer;

use wgpu::util::DeviceExt;

/// Errors from the GPU layer.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    #[error("no GPU adapter found (wgpu: {0}); on Debian install mesa-vulkan-drivers for a software Vulkan driver, or use --backend cpu")]
    NoAdapter(String),
    #[error("the GPU adapter `{adapter}` refused a device: {msg}")]
    Device { adapter: String, msg: String },
    #[error("GPU buffer of {need} bytes exceeds the device limit of {limit} bytes ({what})")]
    TooLarge { what: String, need: u64, limit: u64 },
    #[error("GPU readback failed: {0}")]
    Readback(String),
    #[error("GPU dispatch of `{label}` failed: {msg}")]
    Dispatch { label: String, msg: String },
    #[error("WGSL kernel `{label}` failed validation: {msg}")]
    Shader { label: String, msg: String },
}

/// Instance, adapter, device and queue.
pub struct GpuContext {
    pub adapter: wgpu::Adapter,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    /// The device writes timestamps around each dispatch (the adapter has
    /// `TIMESTAMP_QUERY`), so [`times()`] holds the kernels' own time on the GPU's clock.
    timestamps: bool,
    /// A dispatch's timestamp buffers, kept for the next ([`Stamps`]).
    stamps: std::sync::Mutex<Option<Stamps>>,
}

impl GpuContext {
    /// Find an adapter (hardware first, then any software one) and open a device with the
    /// adapter's own limits, so large scenes fit.
    pub fn new() -> Result<GpuContext, GpuError> {
        let adapter = GpuContext::adapter()?;
        GpuContext::open(adapter)
    }

    /// A hardware adapter's context, or None where the adapter found is a software rasterizer
    /// (its device is not opened: on a host without a GPU, opening llvmpipe's device was most
    /// of the 0.1 s that `auto` spent before each stage's CPU work), or there is no adapter.
    pub fn hardware() -> Option<GpuContext> {
        GpuContext::open(hardware_adapter()?.clone()).ok()
    }

    /// Start looking for a hardware adapter on a thread of its own, so that a later
    /// [`GpuContext::hardware`] finds the answer ready (or waits for the rest of it). The look
    /// is the Vulkan loader opening every installed driver: 0.3 s of one core on a host with
    /// Mesa's drivers and no GPU, which the stage's own start (mapping and checking artifacts)
    /// then overlaps.
    pub fn look_for_hardware() {
        if HARDWARE.get().is_some() {
            return;
        }
        let mut looking = LOOKING.lock().unwrap_or_else(|e| e.into_inner());
        if looking.is_none() {
            *looking = Some(std::thread::spawn(|| {
                hardware_adapter();
            }));
        }
    }

    /// Wait for a look that [`GpuContext::look_for_hardware`] started to end. A process must
    /// not exit while the Vulkan loader opens drivers on another thread (their finalizers would
    /// run under it): every stage's exit calls this, also after an early error.
    pub fn done_looking() {
        let thread = LOOKING.lock().unwrap_or_else(|e| e.into_inner()).take();
        if let Some(thread) = thread {
            // A panic in the driver is reported by the thread and found again by the next
            // look (the answer is not kept).
            let _ = thread.join();
        }
    }

    /// The adapter: hardware first, then any software one.
    fn adapter() -> Result<wgpu::Adapter, GpuError> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let mut last_err = String::from("no adapter");
        for fallback in [false, true] {
            let opts = wgpu::RequestAdapterOptions {
                power_preference: wgpu::PowerPreference::HighPerformance,
                force_fallback_adapter: fallback,
                compatible_surface: None,
                ..Default::default()
            };
            match pollster::block_on(instance.request_adapter(&opts)) {
                Ok(a) => return Ok(a),
                Err(e) => last_err = e.to_string(),
            }
        }
        Err(GpuError::NoAdapter(last_err))
    }

    /// A device on `adapter` with the adapter's own limits.
    fn open(adapter: wgpu::Adapter) -> Result<GpuContext, GpuError> {
        let info = adapter.get_info();
        let features = adapter.features() & wgpu::Features::TIMESTAMP_QUERY;
        let desc = wgpu::DeviceDescriptor {
            label: Some("pcgi"),
            required_features: features,
            required_limits: adapter.limits(),
            ..Default::default()
        };
        let (device, queue) =
            pollster::block_on(adapter.request_device(&desc)).map_err(|e| GpuError::Device {
                adapter: info.name.clone(),
                msg: e.to_string(),
            })?;
        Ok(GpuContext {
            adapter,
            device,
            queue,
            info,
            timestamps: !features.is_empty(),
            stamps: Default::default(),
        })
    }

    /// One line naming the adapter, for logs and benchmark tables.
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {:?})",
            self.info.name, self.info.device_type, self.info.backend
        )
    }

    /// True for software rasterizers such as llvmpipe.
    pub fn is_software(&self) -> bool {
        software(&self.info)
    }

    /// The most bytes one storage binding may span (the device's binding and buffer limits).
    pub fn binding_limit(&self) -> u64 {
        let limits = self.device.limits();
        limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size)
    }

    fn check_size(&self, what: &str, need: u64) -> Result<(), GpuError> {
        self.check_limit(what, need, self.binding_limit())
    }

    fn check_limit(&self, what: &str, need: u64, limit: u64) -> Result<(), GpuError> {
        if need > limit {
            return Err(GpuError::TooLarge {
                what: what.to_string(),
                need,
                limit,
            });
        }
        Ok(())
    }

    /// A storage buffer holding `bytes`, zero-padded to at least 256 bytes so that an empty or
    /// short array still binds as a runtime-sized array of any record up to 256 bytes.
    pub fn storage(&self, label: &str, bytes: &[u8]) -> Result<wgpu::Buffer, GpuError> {
        self.check_size(label, bytes.len() as u64)?;
        Ok(self.storage_unchecked(label, bytes))
    }

    /// A storage buffer holding `bytes` that kernels bind in windows ([`Bind::window`]): it may
    /// exceed one binding's limit, not the device's largest buffer.
    pub fn storage_windowed(&self, label: &str, bytes: &[u8]) -> Result<wgpu::Buffer, GpuError> {
        self.check_limit(
            label,
            bytes.len() as u64,
            self.device.limits().max_buffer_size,
        )?;
        Ok(self.storage_unchecked(label, bytes))
    }

    fn storage_unchecked(&self, label: &str, bytes: &[u8]) -> wgpu::Buffer {
        let started = Instant::now();
        let buffer = self.storage_init(label, bytes);
        times::count(times::Op::Upload(bytes.len() as u64), started);
        buffer
    }

    fn storage_init(&self, label: &str, bytes: &[u8]) -> wgpu::Buffer {
        let usage = wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST;
        if bytes.len() < 256 {
            let mut padded = [0u8; 256];
            padded[..bytes.len()].copy_from_slice(bytes);
            return self
                .device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some(label),
                    contents: &padded,
                    usage,
                });
        }
        self.device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: bytes,
                usage,
            })
    }

    /// A zeroed read-write storage buffer of `size` bytes for kernel output.
    pub fn output(&self, label: &str, size: u64) -> Result<wgpu::Buffer, GpuError> {
        self.check_size(label, size)?;
        Ok(self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: size.max(16).next_multiple_of(4),
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        }))
    }

    /// Overwrite the start of `buffer` with `bytes` (queued; done before the next dispatch).
    pub fn write(&self, buffer: &wgpu::Buffer, bytes: &[u8]) {
        let started = Instant::now();
        self.queue.write_buffer(buffer, 0, bytes);
        times::count(times::Op::Upload(bytes.len() as u64), started);
    }

    /// A uniform buffer holding `bytes`.
    pub fn uniform(&self, label: &str, bytes: &[u8]) -> wgpu::Buffer {
        self.device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: bytes,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            })
    }

    /// Copy the first `size` bytes of `buffer` back to the host (blocking).
    pub fn read(&self, buffer: &wgpu::Buffer, size: u64) -> Result<Vec<u8>, GpuError> {
        if size == 0 {
            return Ok(Vec::new());
        }
        Readback::new(self, size).read(self, buffer, size, <[u8]>::to_vec)
    }

    /// Build a compute kernel from WGSL source. `bindings` lists group 0's bindings in order.
    /// The source is validated with naga first so a broken shader is a clear error.
    pub fn kernel(
        &self,
        label: &str,
        source: &str,
        entry: &str,
        bindings: &[Binding],
    ) -> Result<Kernel, GpuError> {
        let started = Instant::now();
        validate_wgsl(source).map_err(|e| match e {
            GpuError::Shader { msg, .. } => GpuError::Shader {
                label: label.to_string(),
                msg,
            },
            e => e,
        })?;
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = self
            .device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            });
        let entries: Vec<wgpu::BindGroupLayoutEntry> = bindings
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupLayoutEntry {
                binding: i as u32,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: match b {
                    Binding::Uniform => wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    Binding::ReadOnly => wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Storage { read_only: true },
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    Binding::ReadWrite => wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Storage { read_only: false },
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                },
                count: None,
            })
            .collect();
        let layout = self
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(label),
                entries: &entries,
            });
        let pipeline_layout = self
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(label),
                bind_group_layouts: &[Some(&layout)],
                immediate_size: 0,
            });
        let pipeline = self
            .device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Shader {
                label: label.to_string(),
                msg: e.to_string(),
            });
        }
        times::count(times::Op::Build, started);
        Ok(Kernel {
            label: label.to_string(),
            pipeline,
            layout,
        })
    }
}

/// The hardware adapter of this process, looked for once ([`GpuContext::hardware`]).
static HARDWARE: std::sync::OnceLock<Option<wgpu::Adapter>> = std::sync::OnceLock::new();

/// The thread of a look started early ([`GpuContext::look_for_hardware`]), until joined.
static LOOKING: std::sync::Mutex<Option<std::thread::JoinHandle<()>>> = std::sync::Mutex::new(None);

/// The hardware adapter, if the first adapter found is one; looked for on the first call (a
/// concurrent caller waits for it) and kept.
fn hardware_adapter() -> Option<&'static wgpu::Adapter> {
    HARDWARE
        .get_or_init(|| {
            let adapter = GpuContext::adapter().ok()?;
            (!software(&adapter.get_info())).then_some(adapter)
        })
        .as_ref()
}

/// Whether an adapter is a software rasterizer such as llvmpipe.
fn software(info: &wgpu::AdapterInfo) -> bool {
    info.device_type == wgpu::DeviceType::Cpu
}

/// The kind of one binding of a kernel's group 0.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Binding {
    Uniform,
    ReadOnly,
    ReadWrite,
}

/// What one binding of a dispatch sees: a whole buffer, or a window of it.
#[derive(Clone, Copy, Debug)]
pub struct Bind<'a> {
    pub buffer: &'a wgpu::Buffer,
    /// Byte offset (a multiple of the device's `min_storage_buffer_offset_alignment`) and
    /// size (0: to the end of the buffer); `None`: the whole buffer.
    pub window: Option<(u64, u64)>,
}

impl<'a> Bind<'a> {
    pub fn whole(buffer: &'a wgpu::Buffer) -> Bind<'a> {
        Bind {
            buffer,
            window: None,
        }
    }

    pub fn window(buffer: &'a wgpu::Buffer, offset: u64, size: u64) -> Bind<'a> {
        Bind {
            buffer,
            window: Some((offset, size)),
        }
    }
}

/// A compute pipeline with its bind-group layout, made once and dispatched many times.
pub struct Kernel {
    label: String,
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

impl Kernel {
    /// Bind `buffers` (in binding order) and dispatch `groups` workgroups, then wait.
    pub fn run(
        &self,
        ctx: &GpuContext,
        buffers: &[&wgpu::Buffer],
        groups: (u32, u32, u32),
    ) -> Result<(), GpuError> {
        let binds: Vec<Bind> = buffers.iter().map(|b| Bind::whole(b)).collect();
        self.run_binds(ctx, &binds, groups)
    }

    /// [`Kernel::run`] with each binding a whole buffer or a window of one.
    pub fn run_binds(
        &self,
        ctx: &GpuContext,
        binds: &[Bind],
        groups: (u32, u32, u32),
    ) -> Result<(), GpuError> {
        let started = Instant::now();
        // Validation errors come back as errors instead of wgpu's default panic.
        let scope = ctx.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let entries: Vec<wgpu::BindGroupEntry> = binds
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: match b.window {
                    None => b.buffer.as_entire_binding(),
                    Some((offset, size)) => wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer: b.buffer,
                        offset,
                        size: wgpu::BufferSize::new(size),
                    }),
                },
            })
            .collect();
        let group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(&self.label),
            layout: &self.layout,
            entries: &entries,
        });
        let mut enc = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some(&self.label),
            });
        let stamps = ctx.timestamps.then(|| {
            let kept = ctx.stamps.lock().map(|mut k| k.take()).ok().flatten();
            kept.unwrap_or_else(|| Stamps::new(ctx))
        });
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some(&self.label),
                timestamp_writes: stamps.as_ref().map(Stamps::writes),
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &group, &[]);
            pass.dispatch_workgroups(groups.0, groups.1, groups.2);
        }
        if let Some(st) = &stamps {
            st.resolve(&mut enc);
        }
        ctx.queue.submit([enc.finish()]);
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Dispatch {
                label: self.label.clone(),
                msg: format!("{e:#}"),
            });
        }
        ctx.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        times::count(times::Op::Dispatch, started);
        if let Some(st) = stamps.and_then(|st| st.count(ctx)) {
            if let Ok(mut kept) = ctx.stamps.lock() {
                *kept = Some(st);
            }
        }
        Ok(())
    }
}

/// Two timestamps around one dispatch, resolved into a buffer the host maps once the dispatch
/// is done: the kernel's own time on the GPU's clock, without the submission, the wait and any
/// work queued before it ([`times::GpuTimes::kernel_seconds`]).
struct Stamps {
    set: wgpu::QuerySet,
    resolved: wgpu::Buffer,
    staging: wgpu::Buffer,
}

impl Stamps {
    const BYTES: u64 = 2 * std::mem::size_of::<u64>() as u64;

    fn new(ctx: &GpuContext) -> Stamps {
        let buffer = |label, usage| {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: Stamps::BYTES,
                usage,
                mapped_at_creation: false,
            })
        };
        use wgpu::BufferUsages as U;
        Stamps {
            set: ctx.device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("dispatch timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: 2,
            }),
            resolved: buffer("timestamps", U::QUERY_RESOLVE | U::COPY_SRC),
            staging: buffer("timestamps read", U::MAP_READ | U::COPY_DST),
        }
    }

    fn writes(&self) -> wgpu::ComputePassTimestampWrites<'_> {
        wgpu::ComputePassTimestampWrites {
            query_set: &self.set,
            beginning_of_pass_write_index: Some(0),
            end_of_pass_write_index: Some(1),
        }
    }

    fn resolve(&self, enc: &mut wgpu::CommandEncoder) {
        enc.resolve_query_set(&self.set, 0..2, &self.resolved, 0);
        enc.copy_buffer_to_buffer(&self.resolved, 0, &self.staging, 0, Stamps::BYTES);
    }

    /// Read the two timestamps (the dispatch is done) and count their span; the buffers back,
    /// unmapped, for the next dispatch. A span that cannot be read is not counted (the counters
    /// say how many dispatches were timed), and its buffers are dropped.
    fn count(self, ctx: &GpuContext) -> Option<Stamps> {
        let t: [u64; 2] = map_read(
            ctx,
            &self.staging,
            Stamps::BYTES,
            bytemuck::pod_read_unaligned,
        )
        .ok()?;
        let ticks = t[1].saturating_sub(t[0]) as f64;
        times::count_kernel(ticks * f64::from(ctx.queue.get_timestamp_period()));
        Some(self)
    }
}

/// Workgroup grid for `n` invocations of `group_size` threads: x at most 65535, the rest in y.
/// Kernels index with `gid.x + gid.y * (num_workgroups.x * group_size)`.
pub fn grid(n: u32, group_size: u32) -> (u32, u32, u32) {
    let groups = n.div_ceil(group_size).max(1);
    if groups <= 65535 {
        (groups, 1, 1)
    } else {
        (65535, groups.div_ceil(65535), 1)
    }
}

/// Parse and validate WGSL with naga; the error is naga's report.
pub fn validate_wgsl(source: &str) -> Result<naga::Module, GpuError> {
    let err = |msg: String| GpuError::Shader {
        label: "(naga)".into(),
        msg,
    };
    let module = naga::front::wgsl::parse_str(source).map_err(|e| err(e.emit_to_string(source)))?;
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::all(),
    )
    .validate(&module)
    .map_err(|e| err(e.emit_to_string(source)))?;
    Ok(module)
}

/// Size, alignment and member offsets of a WGSL struct, as naga lays it out, for tests that hold
/// Rust `#[repr(C)]` records to their WGSL twins.
pub fn wgsl_struct_layout(module: &naga::Module, name: &str) -> Option<(u32, Vec<(String, u32)>)> {
    module.types.iter().find_map(|(_, ty)| match &ty.inner {
        naga::TypeInner::Struct { members, span } if ty.name.as_deref() == Some(name) => Some((
            *span,
            members
                .iter()
                .map(|m| (m.name.clone().unwrap_or_default(), m.offset))
                .collect(),
        )),
        _ => None,
    })
}

/// Whether tests must have a GPU (`PC_REQUIRE_GPU=1`, set in CI).
pub fn gpu_required() -> bool {
    std::env::var("PC_REQUIRE_GPU").is_ok_and(|v| v == "1" || v.eq_ignore_ascii_case("true"))
}

/// The context GPU tests use: `None` when no adapter exists, unless `PC_REQUIRE_GPU=1`, in
/// which case a missing adapter fails the test.
///
/// A skipped comparison says so on the terminal, whatever the test harness captures: the line
/// `SKIPPED GPU comparison <test>: ...` goes to the process's stderr itself (libtest captures
/// only the `print!` macros), so a run that passes without an adapter shows what it skipped.
pub fn test_context() -> Option<GpuContext> {
    match GpuContext::new() {
        Ok(ctx) => Some(ctx),
        Err(e) if gpu_required() => panic!("PC_REQUIRE_GPU=1 but {e}"),
        Err(e) => {
            use std::io::Write;
            let test = std::thread::current()
                .name()
                .unwrap_or("(unnamed)")
                .to_string();
            let _ = writeln!(
                std::io::stderr().lock(),
                "SKIPPED GPU comparison {test}: {e} (PC_REQUIRE_GPU=1 makes this a failure)"
            );
            None
        }
    }
}

/// A host-visible buffer that reads a device buffer back, kept from read to read (a frame after
/// a frame) so that no read allocates and maps fresh memory.
pub struct Readback {
    staging: wgpu::Buffer,
}

impl Readback {
    /// Room for reads of up to `capacity` bytes.
    pub fn new(ctx: &GpuContext, capacity: u64) -> Readback {
        Readback {
            staging: ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("readback"),
                size: capacity
                    .max(4)
                    .next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT),
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
        }
    }

    /// Bytes a read may take.
    pub fn capacity(&self) -> u64 {
        self.staging.size()
    }

    /// Copy the first `size` bytes of `buffer` (at most [`Readback::capacity`]) back and hand
    /// them to `f` while mapped (blocking; counted as a read in [`times()`]).
    pub fn read<R>(
        &self,
        ctx: &GpuContext,
        buffer: &wgpu::Buffer,
        size: u64,
        f: impl FnOnce(&[u8]) -> R,
    ) -> Result<R, GpuError> {
        let started = Instant::now();
        let padded = size.next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT);
        if padded > self.capacity() {
            return Err(GpuError::Readback(format!(
                "{size} bytes do not fit a readback of {}",
                self.capacity()
            )));
        }
        let mut enc = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("readback"),
            });
        enc.copy_buffer_to_buffer(buffer, 0, &self.staging, 0, padded);
        ctx.queue.submit([enc.finish()]);
        let out = map_read(ctx, &self.staging, padded, |bytes| {
            f(&bytes[..size as usize])
        })?;
        times::count(times::Op::Read(size), started);
        Ok(out)
    }
}

/// Map the first `padded` bytes of `staging` (its copy submitted), hand them to `f`, unmap
/// (blocking). Unmapped however this ends once mapped (an error, a panic in `f`), so the next
/// use can map it again; after a failed map there is nothing to unmap, and a caller that keeps
/// the buffer drops it after an error (pc-raytrace's kept frame buffers).
fn map_read<R>(
    ctx: &GpuContext,
    staging: &wgpu::Buffer,
    padded: u64,
    f: impl FnOnce(&[u8]) -> R,
) -> Result<R, GpuError> {
    let err = |e: &dyn std::fmt::Display| GpuError::Readback(e.to_string());
    let (tx, rx) = mpsc::channel();
    staging.map_async(wgpu::MapMode::Read, ..padded, move |r| {
        let _ = tx.send(r);
    });
    ctx.device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| err(&e))?;
    rx.recv().map_err(|e| err(&e))?.map_err(|e| err(&e))?;
    let _unmap = Unmap(staging);
    let view = staging.get_mapped_range(..padded).map_err(|e| err(&e))?;
    Ok(f(&view))
}

/// Unmaps its buffer when dropped (after any view of it, which borrows it).
struct Unmap<'a>(&'a wgpu::Buffer);

impl Drop for Unmap<'_> {
    fn drop(&mut self) {
        self.0.unmap();
    }
}
