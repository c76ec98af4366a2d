//! wgpu compute renderer with the semantics of the CPU renderer ([`super::render`]).
//!
//! Pipeline (WGSL kernels in `decoder/shaders/`, sources in [`crate::shaders`]):
//! 1. `project` — per Gaussian: camera transform, 3D → 2D covariance (EWA), conic and 3σ radius,
//!    SH colour, opacity, and the number of 16×16 tiles its rectangle touches. The scene is
//!    uploaded once ([`GpuRenderer::upload`]) in chunks so that no storage binding exceeds the
//!    device limit (at most 1 GiB).
//! 2. `scan` — exclusive prefix sum of the tile counts (workgroup-shared Hillis–Steele scans,
//!    recursive over blocks); the total number of (tile, Gaussian) pairs is read back once.
//! 3. `emit` — one `(tile, depth, id)` key per overlap, in Gaussian order.
//! 4. `radix_sort` — stable LSD radix sort, 4 bits per pass: 8 passes over the depth bits, then as
//!    many as the tile index needs. Stability keeps equal depths in index order (like the CPU).
//! 5. `tile_ranges` + `rasterize` — each tile's slice of the sorted list; one 16×16 workgroup per
//!    tile composites front to back, staging Gaussians through workgroup memory.
//!
//! No subgroup operations or optional features are used, so any WebGPU-capable adapter works
//! (including Mesa's lavapipe software Vulkan). [`GpuRenderer::render_frame`] leaves the RGB f32
//! image in a GPU buffer ([`GpuFrame`]); [`GpuRenderer::render`] uploads, renders and reads back.

use super::{Image, RenderOptions};
use crate::camera::Camera;
use crate::math::{sh_rest_coeffs, TILE};
use crate::shaders::{COMMON, EMIT, PROJECT, RADIX_SORT, RASTERIZE, SCAN};
use crate::splats::Splats;
use std::future::Future;
use std::sync::{Arc, Mutex};
use wgpu::util::DeviceExt;

/// Why the GPU renderer could not run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GpuError {
    /// No GPU adapter (not even a software one) is available.
    #[error("no GPU adapter available: {0}")]
    NoAdapter(String),
    /// The adapter refused to create a device.
    #[error("cannot create a GPU device: {0}")]
    Device(String),
    /// The frame needs a buffer larger than the device allows.
    #[error("scene too large for the GPU renderer: {0}")]
    TooLarge(String),
    /// A wgpu validation or out-of-memory error, or a failed readback.
    #[error("GPU error: {0}")]
    Backend(String),
}

/// Installs on `device` a sink for its uncaptured errors: the slot holds the first error since
/// it was last emptied. (The GPU trainer installs its own on the device it shares.)
#[doc(hidden)]
pub fn error_sink(device: &wgpu::Device) -> Arc<Mutex<Option<String>>> {
    let errors: Arc<Mutex<Option<String>>> = Arc::new(Mutex::new(None));
    let sink = errors.clone();
    device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
        let mut slot = sink.lock().unwrap_or_else(|p| p.into_inner());
        slot.get_or_insert_with(|| e.to_string());
    }));
    errors
}

/// A WGSL module of `src` after the shared definitions ([`crate::shaders::COMMON`]).
#[doc(hidden)]
pub fn shader_module(device: &wgpu::Device, name: &str, src: &str) -> wgpu::ShaderModule {
    device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(name),
        source: wgpu::ShaderSource::Wgsl(format!("{COMMON}\n{src}").into()),
    })
}

/// The compute pipeline of entry point `entry` of `module`, its layout derived from the shader.
#[doc(hidden)]
pub fn compute_pipeline(device: &wgpu::Device, module: &wgpu::ShaderModule, entry: &str) -> wgpu::ComputePipeline {
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(entry),
        layout: None,
        module,
        entry_point: Some(entry),
        compilation_options: Default::default(),
        cache: None,
    })
}

/// Kernels and device of the wgpu renderer. Create once, render many frames.
pub struct GpuRenderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    max_binding: u64,
    errors: Arc<Mutex<Option<String>>>,
    /// Five stage-boundary timestamps and their resolve buffer, when the adapter has them.
    timestamps: Option<(wgpu::QuerySet, wgpu::Buffer)>,
    project: wgpu::ComputePipeline,
    emit: wgpu::ComputePipeline,
    scan_blocks: wgpu::ComputePipeline,
    scan_add: wgpu::ComputePipeline,
    radix_count: wgpu::ComputePipeline,
    radix_scatter: wgpu::ComputePipeline,
    tile_ranges: wgpu::ComputePipeline,
    rasterize: wgpu::ComputePipeline,
}

/// How long [`map_wait`] waits for a read-back's map callback once the device is idle before it
/// gives up ("did not complete"). The callback normally runs inside the first wait; it can be
/// late when another thread that polls the same device took it and has not run it yet. (The
/// earlier bound, 1000 polls, ran out once in a lego-200 sweep of ten trainings sharing one
/// H200 and its 16 cores; the cause was not reproduced.)
pub const MAP_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(60);

/// Floats per input record before the SH rest coefficients.
const RECORD_BASE: usize = 14;
const PROJECTED_BYTES: u64 = 48;
const SCAN_BLOCK: u32 = 1024;
const SORT_BLOCK: u32 = 1024;
const MAX_GROUPS: u32 = 65535;
/// Device features for the per-stage GPU timestamps (requested when the adapter has them).
const TIMESTAMP_FEATURES: wgpu::Features = wgpu::Features::TIMESTAMP_QUERY.union(wgpu::Features::TIMESTAMP_QUERY_INSIDE_ENCODERS);

/// Minimal executor for wgpu's futures (they complete after `Device::poll` on native backends).
#[doc(hidden)]
pub fn block_on<F: Future>(fut: F) -> F::Output {
    use std::task::{Context, Poll, Wake, Waker};
    struct Unpark(std::thread::Thread);
    impl Wake for Unpark {
        fn wake(self: Arc<Self>) {
            self.0.unpark();
        }
    }
    let waker = Waker::from(Arc::new(Unpark(std::thread::current())));
    let mut cx = Context::from_waker(&waker);
    let mut fut = std::pin::pin!(fut);
    loop {
        match fut.as_mut().poll(&mut cx) {
            Poll::Ready(v) => return v,
            Poll::Pending => std::thread::park(),
        }
    }
}

/// Maps `staging` (a `MAP_READ` buffer whose copy has been submitted) for reading and waits until
/// it is mapped: polls the device until idle, then sleeps on the map callback (another thread
/// polling the same device may be the one to run it), for at most [`MAP_TIMEOUT`] past the
/// polls. The error is a message for the caller's error type.
pub fn map_wait(device: &wgpu::Device, staging: &wgpu::Buffer) -> Result<(), String> {
    use std::sync::Condvar;
    let done = Arc::new((Mutex::new(None), Condvar::new()));
    let slot = done.clone();
    staging.slice(..).map_async(wgpu::MapMode::Read, move |r| {
        *slot.0.lock().unwrap_or_else(|p| p.into_inner()) = Some(r);
        slot.1.notify_all();
    });
    let deadline = std::time::Instant::now() + MAP_TIMEOUT;
    let outcome = loop {
        device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| format!("poll failed: {e}"))?;
        let (lock, ready) = &*done;
        let guard = lock.lock().unwrap_or_else(|p| p.into_inner());
        let wait = std::time::Duration::from_millis(10);
        let (mut guard, _) = ready.wait_timeout_while(guard, wait, |o| o.is_none()).unwrap_or_else(|p| p.into_inner());
        if let Some(outcome) = guard.take() {
            break outcome;
        }
        if std::time::Instant::now() > deadline {
            return Err("readback did not complete".into());
        }
    };
    outcome.map_err(|e| format!("readback failed: {e}"))
}

/// The per-frame uniform of common.wgsl (`Frame`), shared with the GPU trainer.
#[doc(hidden)]
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct FrameUniform {
    rot: [[f32; 4]; 3],
    trans: [f32; 4],
    center: [f32; 4],
    focal: [f32; 4],
    background: [f32; 4],
    znear: f32,
    width: u32,
    height: u32,
    tiles_x: u32,
    tiles_y: u32,
    degree: u32,
    stride: u32,
    n: u32,
}

impl FrameUniform {
    /// The frame of `cam`: `n` Gaussians of `stride` f32 records, SH up to `degree`.
    pub fn new(cam: &Camera, background: [f32; 3], degree: u8, stride: usize, n: usize) -> Self {
        let r = cam.rotation;
        FrameUniform {
            rot: [r.x_axis.extend(0.0).to_array(), r.y_axis.extend(0.0).to_array(), r.z_axis.extend(0.0).to_array()],
            trans: cam.translation.extend(0.0).to_array(),
            center: cam.center().extend(0.0).to_array(),
            focal: [cam.fx, cam.fy, cam.cx, cam.cy],
            background: [background[0], background[1], background[2], 0.0],
            znear: cam.znear,
            width: cam.width,
            height: cam.height,
            tiles_x: cam.width.div_ceil(TILE),
            tiles_y: cam.height.div_ceil(TILE),
            degree: u32::from(degree),
            stride: stride as u32,
            n: n as u32,
        }
    }
}

/// Workgroup counts `(x, y)` covering `groups` with `x ≤ 65535`.
#[doc(hidden)]
pub fn dims(groups: u32) -> (u32, u32) {
    if groups <= MAX_GROUPS {
        (groups.max(1), 1)
    } else {
        (MAX_GROUPS, groups.div_ceil(MAX_GROUPS))
    }
}

/// The default adapter (any backend wgpu was built with, high-performance preferred), from the
/// process's one wgpu instance.
///
/// The instance is created on first use and kept until the process exits, so the Vulkan loader
/// and driver stay loaded: on an NVIDIA H100 (driver 580) a GPU sweep whose trainings each made
/// and dropped their own instance and device crashed in a jump to unmapped code, which is what
/// running code of an unloaded library looks like (docs/train.md).
pub fn default_adapter() -> Result<wgpu::Adapter, GpuError> {
    static INSTANCE: std::sync::OnceLock<wgpu::Instance> = std::sync::OnceLock::new();
    let instance = INSTANCE.get_or_init(|| wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env()));
    block_on(
        instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            ..Default::default()
        }),
    )
    .map_err(|e| GpuError::NoAdapter(e.to_string()))
}

impl GpuRenderer {
    /// Picks the default adapter ([`default_adapter`]) and compiles the kernels.
    pub fn new() -> Result<Self, GpuError> {
        Self::with_adapter(&default_adapter()?)
    }

    /// Uses a given adapter.
    pub fn with_adapter(adapter: &wgpu::Adapter) -> Result<Self, GpuError> {
        let limits = adapter.limits();
        let mut required = wgpu::Limits::downlevel_defaults();
        // Ask for as much as the adapter offers, but never bind more than 1 GiB at once.
        required.max_storage_buffer_binding_size = limits.max_storage_buffer_binding_size.min(1 << 30);
        required.max_buffer_size = limits.max_buffer_size.min(1 << 31);
        required.max_storage_buffers_per_shader_stage = 8.min(limits.max_storage_buffers_per_shader_stage);
        required.max_compute_workgroup_storage_size = limits.max_compute_workgroup_storage_size.min(16384);
        let (device, queue) = block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("gscodec"),
            required_limits: required.clone(),
            required_features: adapter.features() & TIMESTAMP_FEATURES,
            ..Default::default()
        }))
        .map_err(|e| GpuError::Device(e.to_string()))?;
        Self::from_device(device, queue, adapter.get_info(), required.max_storage_buffer_binding_size)
    }

    /// Compiles the kernels on an existing device (the GPU trainer shares its device).
    #[doc(hidden)]
    pub fn from_device(device: wgpu::Device, queue: wgpu::Queue, info: wgpu::AdapterInfo, max_binding: u64) -> Result<Self, GpuError> {
        let errors = error_sink(&device);
        let module = |name: &str, src: &str| shader_module(&device, name, src);
        let pipeline = |m: &wgpu::ShaderModule, entry: &str| compute_pipeline(&device, m, entry);
        let project_m = module("project", PROJECT);
        let emit_m = module("emit", EMIT);
        let scan_m = module("scan", SCAN);
        let sort_m = module("radix_sort", RADIX_SORT);
        let raster_m = module("rasterize", RASTERIZE);
        let timestamps = device.features().contains(TIMESTAMP_FEATURES).then(|| {
            let qs = device.create_query_set(&wgpu::QuerySetDescriptor { label: Some("stages"), ty: wgpu::QueryType::Timestamp, count: 5 });
            let resolve = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamps"),
                size: 5 * 8,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            });
            (qs, resolve)
        });
        let r = GpuRenderer {
            timestamps,
            project: pipeline(&project_m, "project"),
            emit: pipeline(&emit_m, "emit"),
            scan_blocks: pipeline(&scan_m, "scan_blocks"),
            scan_add: pipeline(&scan_m, "scan_add"),
            radix_count: pipeline(&sort_m, "radix_count"),
            radix_scatter: pipeline(&sort_m, "radix_scatter"),
            tile_ranges: pipeline(&raster_m, "tile_ranges"),
            rasterize: pipeline(&raster_m, "rasterize"),
            info,
            max_binding,
            device,
            queue,
            errors,
        };
        r.check()?;
        Ok(r)
    }

    /// Name and backend of the adapter in use, e.g. `"llvmpipe (LLVM 15.0.6, 256 bits) (Vulkan)"`.
    pub fn adapter_name(&self) -> String {
        format!("{} ({:?})", self.info.name, self.info.backend)
    }

    /// Whether the adapter is a CPU (software) implementation such as lavapipe.
    pub fn is_software(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    fn check(&self) -> Result<(), GpuError> {
        match self.errors.lock().unwrap_or_else(|p| p.into_inner()).take() {
            Some(e) => Err(GpuError::Backend(e)),
            None => Ok(()),
        }
    }

    fn storage(&self, label: &str, bytes: u64) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: bytes.max(16),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    fn uniform<T: bytemuck::Pod>(&self, value: &T) -> wgpu::Buffer {
        self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: None,
            contents: bytemuck::bytes_of(value),
            usage: wgpu::BufferUsages::UNIFORM,
        })
    }

    fn bind(&self, pipeline: &wgpu::ComputePipeline, buffers: &[(u32, &wgpu::Buffer)]) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> =
            buffers.iter().map(|&(binding, b)| wgpu::BindGroupEntry { binding, resource: b.as_entire_binding() }).collect();
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &pipeline.get_bind_group_layout(0),
            entries: &entries,
        })
    }

    fn dispatch(enc: &mut wgpu::CommandEncoder, pipeline: &wgpu::ComputePipeline, bg: &wgpu::BindGroup, groups: (u32, u32)) {
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: None, timestamp_writes: None });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, bg, &[]);
        pass.dispatch_workgroups(groups.0, groups.1, 1);
    }

    /// Records an in-place exclusive scan of the first `n` u32 of `data`.
    #[doc(hidden)]
    pub fn record_scan(&self, enc: &mut wgpu::CommandEncoder, data: &wgpu::Buffer, n: u32) {
        let blocks = n.div_ceil(SCAN_BLOCK);
        let sums = self.storage("scan sums", blocks as u64 * 4);
        let params = self.uniform(&[n, 0u32, 0, 0]);
        let bg_blocks = self.bind(&self.scan_blocks, &[(0, &params), (1, data), (2, &sums)]);
        Self::dispatch(enc, &self.scan_blocks, &bg_blocks, dims(blocks));
        if blocks > 1 {
            self.record_scan(enc, &sums, blocks);
            let bg_add = self.bind(&self.scan_add, &[(0, &params), (1, data), (2, &sums)]);
            Self::dispatch(enc, &self.scan_add, &bg_add, dims(blocks));
        }
    }

    /// Records a stable sort of (tile, depth, id) triples in `a` by (tile, depth), using `b` as
    /// scratch; the result ends up in `a`. The buffers hold `cap` keys; the number sorted is
    /// `min(cap, count)` where `count` is the u32 at byte `count.1` of buffer `count.0` on the
    /// GPU. With `indirect`, the sort's workgroup counts come from that buffer (bytes 0..12: the
    /// 1024-key blocks as `(x, y, 1)`, written on the GPU) instead of covering `cap`.
    #[doc(hidden)]
    #[allow(clippy::too_many_arguments)]
    pub fn record_radix_sort(
        &self,
        enc: &mut wgpu::CommandEncoder,
        a: &mut [wgpu::Buffer; 3],
        b: &mut [wgpu::Buffer; 3],
        cap: u32,
        tile_bits: u32,
        count: (&wgpu::Buffer, u64),
        indirect: Option<&wgpu::Buffer>,
    ) {
        let blocks = cap.div_ceil(SORT_BLOCK);
        let hist_bytes = blocks as u64 * 16 * 4;
        // The histograms, then the key count (radix_sort.wgsl reads it at counts[16 · blocks]).
        let hist = self.storage("radix counts", hist_bytes + 4);
        enc.copy_buffer_to_buffer(count.0, count.1, &hist, hist_bytes, 4);
        let passes = (0..8).map(|p| (0u32, 4 * p)).chain((0..tile_bits.div_ceil(4)).map(|p| (1u32, 4 * p)));
        for (word, shift) in passes {
            let params = self.uniform(&[cap, shift, word, blocks]);
            let count_bg = self.bind(&self.radix_count, &[(0, &params), (1, &a[0]), (2, &a[1]), (4, &hist)]);
            let scatter_bg = self.bind(
                &self.radix_scatter,
                &[(0, &params), (1, &a[0]), (2, &a[1]), (3, &a[2]), (4, &hist), (5, &b[0]), (6, &b[1]), (7, &b[2])],
            );
            match indirect {
                Some(args) => {
                    // Blocks past the count are not run: their histogram entries must read 0.
                    enc.clear_buffer(&hist, 0, Some(hist_bytes));
                    Self::dispatch_indirect(enc, &self.radix_count, &count_bg, args);
                    self.record_scan(enc, &hist, blocks * 16);
                    Self::dispatch_indirect(enc, &self.radix_scatter, &scatter_bg, args);
                }
                None => {
                    Self::dispatch(enc, &self.radix_count, &count_bg, dims(blocks));
                    self.record_scan(enc, &hist, blocks * 16);
                    Self::dispatch(enc, &self.radix_scatter, &scatter_bg, dims(blocks));
                }
            }
            std::mem::swap(a, b);
        }
    }

    fn dispatch_indirect(enc: &mut wgpu::CommandEncoder, pipeline: &wgpu::ComputePipeline, bg: &wgpu::BindGroup, args: &wgpu::Buffer) {
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: None, timestamp_writes: None });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, bg, &[]);
        pass.dispatch_workgroups_indirect(args, 0);
    }

    fn upload_u32(&self, data: &[u32]) -> wgpu::Buffer {
        let buf = self.storage("upload", data.len() as u64 * 4);
        self.queue.write_buffer(&buf, 0, bytemuck::cast_slice(data));
        buf
    }

    fn download_u32(&self, buf: &wgpu::Buffer, n: usize) -> Result<Vec<u32>, GpuError> {
        Ok(bytemuck::pod_collect_to_vec(&self.read_back(buf, 0, n as u64 * 4)?))
    }

    /// Exclusive prefix sum on the GPU (exposed for tests of the scan kernel).
    #[doc(hidden)]
    pub fn debug_scan(&self, data: &[u32]) -> Result<Vec<u32>, GpuError> {
        let buf = self.upload_u32(data);
        let mut enc = self.device.create_command_encoder(&Default::default());
        self.record_scan(&mut enc, &buf, data.len() as u32);
        self.queue.submit([enc.finish()]);
        self.download_u32(&buf, data.len())
    }

    /// Stable sort of `(tile, depth)` keys on the GPU; returns the permutation (exposed for tests).
    #[doc(hidden)]
    pub fn debug_sort(&self, tiles: &[u32], depths: &[u32], tile_bits: u32) -> Result<Vec<u32>, GpuError> {
        let n = tiles.len();
        let ids: Vec<u32> = (0..n as u32).collect();
        let mut a = [self.upload_u32(tiles), self.upload_u32(depths), self.upload_u32(&ids)];
        let mut b = [self.storage("b0", n as u64 * 4), self.storage("b1", n as u64 * 4), self.storage("b2", n as u64 * 4)];
        let count = self.upload_u32(&[n as u32]);
        let mut enc = self.device.create_command_encoder(&Default::default());
        self.record_radix_sort(&mut enc, &mut a, &mut b, n as u32, tile_bits, (&count, 0), None);
        self.queue.submit([enc.finish()]);
        self.download_u32(&a[2], n)
    }

    fn read_back(&self, src: &wgpu::Buffer, offset: u64, bytes: u64) -> Result<Vec<u8>, GpuError> {
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = self.device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(src, offset, &staging, 0, bytes);
        self.queue.submit([enc.finish()]);
        let mapped = map_wait(&self.device, &staging);
        self.check()?;
        mapped.map_err(GpuError::Backend)?;
        let bytes = staging.slice(..).get_mapped_range().map_err(|e| GpuError::Backend(e.to_string()))?.to_vec();
        staging.unmap();
        Ok(bytes)
    }

    fn fits(&self, what: &str, bytes: u64) -> Result<(), GpuError> {
        if bytes > self.max_binding {
            return Err(GpuError::TooLarge(format!("{what} needs {bytes} bytes, the per-binding limit is {}", self.max_binding)));
        }
        Ok(())
    }

    /// Renders `splats` from `cam`: the same image as [`super::render`] up to float rounding.
    /// Uploads the scene, renders one frame and reads it back; for many frames of one scene use
    /// [`Self::upload`], [`Self::render_frame`] and [`Self::read_image`].
    pub fn render(&self, splats: &Splats, cam: &Camera, opts: &RenderOptions) -> Result<Image, GpuError> {
        let scene = self.upload(splats, opts.max_sh_degree)?;
        let frame = self.render_frame(&scene, cam, opts)?;
        self.read_image(&frame)
    }

    /// Uploads `splats` (SH bands up to `max_sh_degree`) once, to render many frames from.
    pub fn upload(&self, splats: &Splats, max_sh_degree: u8) -> Result<GpuScene, GpuError> {
        let n = splats.len();
        let n32 = u32::try_from(n).map_err(|_| GpuError::TooLarge(format!("{n} Gaussians")))?;
        let degree = max_sh_degree.min(splats.sh_degree);
        let k_used = sh_rest_coeffs(degree);
        let k_all = splats.rest_coeffs();
        let stride = RECORD_BASE + 3 * k_used;
        self.fits("the projected Gaussians", n as u64 * PROJECTED_BYTES)?;
        // each chunk's records stay under the binding limit
        let per_chunk = ((self.max_binding / (stride as u64 * 4)) as usize).clamp(1, 1 << 22);
        let mut record = Vec::with_capacity(per_chunk.min(n) * stride);
        let mut chunks = Vec::new();
        for base in (0..n).step_by(per_chunk) {
            let end = (base + per_chunk).min(n);
            record.clear();
            for i in base..end {
                record.extend_from_slice(&splats.positions[i]);
                record.extend_from_slice(&splats.log_scales[i]);
                record.extend_from_slice(&splats.rotations[i]);
                record.push(splats.opacity_logits[i]);
                record.extend_from_slice(&splats.sh_dc[i]);
                record.extend_from_slice(&splats.sh_rest[i * k_all * 3..(i * k_all + k_used) * 3]);
            }
            let records = self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("records"),
                contents: bytemuck::cast_slice(&record),
                usage: wgpu::BufferUsages::STORAGE,
            });
            chunks.push((records, self.uniform(&[base as u32, (end - base) as u32, 0, 0]), (end - base) as u32));
        }
        self.check()?;
        Ok(GpuScene { chunks, n: n32, degree, stride: stride as u32 })
    }

    /// Renders an uploaded scene from `cam` into a GPU-resident RGB f32 image (no readback of
    /// the image; the tile-pair count is read back once, mid-frame).
    pub fn render_frame(&self, scene: &GpuScene, cam: &Camera, opts: &RenderOptions) -> Result<GpuFrame, GpuError> {
        self.frame(scene, cam, opts, None)
    }

    /// As [`Self::render_frame`], waiting for the GPU after the frame and returning the time of
    /// each stage: from GPU timestamps when the adapter has `TIMESTAMP_QUERY` and
    /// `TIMESTAMP_QUERY_INSIDE_ENCODERS`, else host time around stage-by-stage submissions.
    pub fn render_frame_timed(&self, scene: &GpuScene, cam: &Camera, opts: &RenderOptions) -> Result<(GpuFrame, StageTimes), GpuError> {
        let mut times = StageTimes::default();
        let frame = self.frame(scene, cam, opts, Some(&mut times))?;
        Ok((frame, times))
    }

    /// Whether [`Self::render_frame_timed`] uses GPU timestamps (else host time per stage).
    pub fn has_timestamps(&self) -> bool {
        self.timestamps.is_some()
    }

    /// Waits until the GPU has finished all submitted work (e.g. a [`Self::render_frame`]).
    pub fn sync(&self) -> Result<(), GpuError> {
        self.wait()
    }

    /// Reads a frame back to the host.
    pub fn read_image(&self, frame: &GpuFrame) -> Result<Image, GpuError> {
        let bytes = self.read_back(&frame.image, 0, frame.width as u64 * frame.height as u64 * 12)?;
        Ok(Image { width: frame.width, height: frame.height, data: bytemuck::pod_collect_to_vec(&bytes) })
    }

    fn filled_frame(&self, w: u32, h: u32, rgb: [f32; 3]) -> GpuFrame {
        let image = self.storage("image", w as u64 * h as u64 * 12);
        if w > 0 && h > 0 {
            self.queue.write_buffer(&image, 0, bytemuck::cast_slice(&Image::filled(w, h, rgb).data));
        }
        GpuFrame { image, width: w, height: h }
    }

    fn wait(&self) -> Result<(), GpuError> {
        self.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| GpuError::Backend(e.to_string()))?;
        self.check()
    }

    /// Marks a stage boundary: a GPU timestamp `index` when available, else (when timing) a host
    /// clock reading after submitting `enc` and waiting for the GPU.
    fn mark(
        &self,
        enc: &mut wgpu::CommandEncoder,
        timing: &mut Option<&mut StageTimes>,
        host: &mut [Option<std::time::Instant>; 5],
        index: usize,
    ) -> Result<(), GpuError> {
        if timing.is_none() {
            return Ok(());
        }
        if let Some((qs, _)) = &self.timestamps {
            enc.write_timestamp(qs, index as u32);
        } else {
            let done = std::mem::replace(enc, self.device.create_command_encoder(&Default::default()));
            self.queue.submit([done.finish()]);
            self.wait()?;
            host[index] = Some(std::time::Instant::now());
        }
        Ok(())
    }

    fn frame(
        &self,
        scene: &GpuScene,
        cam: &Camera,
        opts: &RenderOptions,
        mut timing: Option<&mut StageTimes>,
    ) -> Result<GpuFrame, GpuError> {
        let (w, h) = (cam.width, cam.height);
        let n = scene.n;
        if n == 0 || w == 0 || h == 0 {
            return Ok(self.filled_frame(w, h, opts.background));
        }
        let degree = opts.max_sh_degree.min(scene.degree);
        let (tiles_x, tiles_y) = (w.div_ceil(TILE), h.div_ceil(TILE));
        self.fits("the image", w as u64 * h as u64 * 12)?;
        self.fits("the tile table", tiles_x as u64 * tiles_y as u64 * 8)?;
        let mut host = [None; 5];

        let frame = FrameUniform::new(cam, opts.background, degree, scene.stride as usize, n as usize);
        let frame_buf = self.uniform(&frame);
        let projected = self.storage("projected", n as u64 * PROJECTED_BYTES);
        let counts = self.storage("tile counts", (n as u64 + 1) * 4);

        // 1. project, chunk by chunk
        let mut enc = self.device.create_command_encoder(&Default::default());
        self.mark(&mut enc, &mut timing, &mut host, 0)?;
        enc.clear_buffer(&counts, 0, None);
        for (records, chunk, len) in &scene.chunks {
            let bg = self.bind(&self.project, &[(0, &frame_buf), (1, chunk), (2, records), (3, &projected), (4, &counts)]);
            Self::dispatch(&mut enc, &self.project, &bg, dims(len.div_ceil(256)));
        }
        // 2. offsets = exclusive scan of the counts; counts[n] (zero) becomes the total
        self.record_scan(&mut enc, &counts, n + 1);
        self.mark(&mut enc, &mut timing, &mut host, 1)?;
        self.queue.submit([enc.finish()]);
        let total = self.read_back(&counts, n as u64 * 4, 4)?;
        let pairs = u32::from_le_bytes(total[..4].try_into().unwrap());
        if pairs == 0 {
            if let Some(t) = timing {
                *t = self.stage_times(&host, false)?;
            }
            return Ok(self.filled_frame(w, h, opts.background));
        }
        self.fits("the sort keys", pairs as u64 * 4)?;

        // 3. keys
        let mut enc = self.device.create_command_encoder(&Default::default());
        self.mark(&mut enc, &mut timing, &mut host, 2)?;
        let key = |name| self.storage(name, pairs as u64 * 4);
        let mut a = [key("tile A"), key("depth A"), key("id A")];
        let mut b = [key("tile B"), key("depth B"), key("id B")];
        let bg = self.bind(&self.emit, &[(0, &frame_buf), (1, &projected), (2, &counts), (3, &a[0]), (4, &a[1]), (5, &a[2])]);
        Self::dispatch(&mut enc, &self.emit, &bg, dims(n.div_ceil(256)));

        // 4. stable radix sort: depth word first, then the tile word
        let tile_bits = 32 - (tiles_x * tiles_y - 1).leading_zeros();
        self.record_radix_sort(&mut enc, &mut a, &mut b, pairs, tile_bits, (&counts, n as u64 * 4), None);
        self.mark(&mut enc, &mut timing, &mut host, 3)?;

        // 5. tile ranges and rasterization
        let ranges = self.storage("tile ranges", tiles_x as u64 * tiles_y as u64 * 8);
        let image = self.storage("image", w as u64 * h as u64 * 12);
        enc.clear_buffer(&ranges, 0, None);
        let rp = self.uniform(&[pairs, n, 0, 0]);
        let bg = self.bind(&self.tile_ranges, &[(1, &rp), (2, &a[0]), (4, &ranges), (7, &counts)]);
        Self::dispatch(&mut enc, &self.tile_ranges, &bg, dims(pairs.div_ceil(256)));
        let bg = self.bind(&self.rasterize, &[(0, &frame_buf), (3, &a[2]), (4, &ranges), (5, &projected), (6, &image)]);
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: None, timestamp_writes: None });
            pass.set_pipeline(&self.rasterize);
            pass.set_bind_group(0, &bg, &[]);
            pass.dispatch_workgroups(tiles_x, tiles_y, 1);
        }
        self.mark(&mut enc, &mut timing, &mut host, 4)?;
        if let (Some(_), Some((qs, resolve))) = (&timing, &self.timestamps) {
            enc.resolve_query_set(qs, 0..5, resolve, 0);
        }
        self.queue.submit([enc.finish()]);
        if let Some(t) = timing {
            self.wait()?;
            *t = self.stage_times(&host, true)?;
        }
        self.check()?;
        Ok(GpuFrame { image, width: w, height: h })
    }

    /// Stage durations from the five boundary marks (timestamps or host instants).
    fn stage_times(&self, host: &[Option<std::time::Instant>; 5], complete: bool) -> Result<StageTimes, GpuError> {
        let t: Vec<f64> = if let Some((_, resolve)) = &self.timestamps {
            if !complete {
                return Ok(StageTimes::default());
            }
            let period = self.queue.get_timestamp_period() as f64 * 1e-9;
            let ticks: Vec<u64> = bytemuck::pod_collect_to_vec(&self.read_back(resolve, 0, 40)?);
            ticks.iter().map(|&v| v.wrapping_sub(ticks[0]) as f64 * period).collect()
        } else {
            let t0 = host[0].expect("timing mark 0");
            host.iter().map(|m| m.map_or(0.0, |m| (m - t0).as_secs_f64())).collect()
        };
        let span = |a: usize, b: usize| (t[b] - t[a]).max(0.0);
        Ok(StageTimes { project: span(0, 1), sort: span(2, 3), rasterize: span(3, 4), gpu_timestamps: self.timestamps.is_some() })
    }
}

/// A scene uploaded to the GPU by [`GpuRenderer::upload`] (input records, chunked so that no
/// binding exceeds the device limit).
pub struct GpuScene {
    /// (records, chunk uniform: first index and length, length)
    chunks: Vec<(wgpu::Buffer, wgpu::Buffer, u32)>,
    n: u32,
    degree: u8,
    stride: u32,
}

impl GpuScene {
    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.n as usize
    }

    /// Whether the scene has no Gaussians.
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }
}

/// A rendered frame resident on the GPU: `width × height` RGB f32, row-major (the layout of
/// [`Image::data`]); read it with [`GpuRenderer::read_image`] or bind [`Self::buffer`].
pub struct GpuFrame {
    image: wgpu::Buffer,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
}

impl GpuFrame {
    /// The storage buffer holding the image.
    pub fn buffer(&self) -> &wgpu::Buffer {
        &self.image
    }
}

/// Seconds spent in each stage of a frame ([`GpuRenderer::render_frame_timed`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StageTimes {
    /// Projection (with SH colour) and the scan of tile counts.
    pub project: f64,
    /// Key emission and the radix sort.
    pub sort: f64,
    /// Tile ranges and compositing.
    pub rasterize: f64,
    /// Whether these are GPU timestamps (else host time around stage-by-stage submissions).
    pub gpu_timestamps: bool,
}
