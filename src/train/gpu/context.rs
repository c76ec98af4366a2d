//! The wgpu device, kernels and buffers of the GPU trainer, and the recording of one training
//! iteration's passes.
//!
//! Projection, key emission, prefix scan, radix sort and tile ranges are the decoder's renderer
//! kernels (`gscodec_decoder::render::gpu`, same WGSL); the training kernels are in
//! `shaders/train_*.wgsl`.

use crate::{Error, Result};
use gscodec_decoder::render::gpu::{block_on, compute_pipeline, error_sink, map_wait, shader_module, GpuRenderer};
pub use gscodec_decoder::render::gpu::{dims, FrameUniform};
use std::sync::{Arc, Mutex};
use wgpu::util::DeviceExt;

use gscodec_decoder::shaders::{EMIT, PROJECT, RASTERIZE};
const TRAIN_RASTER: &str = include_str!("../../../shaders/train_raster.wgsl");
const TRAIN_PROJECT: &str = include_str!("../../../shaders/train_project.wgsl");
const TRAIN_LOSS: &str = include_str!("../../../shaders/train_loss.wgsl");
const TRAIN_ADAM: &str = include_str!("../../../shaders/train_adam.wgsl");
const TRAIN_RATE: &str = include_str!("../../../shaders/train_rate.wgsl");
const TRAIN_COUNT: &str = include_str!("../../../shaders/train_count.wgsl");

/// Floats per projected Gaussian (`Projected` in common.wgsl).
const PROJECTED_BYTES: u64 = 48;
/// Screen-space gradient components per Gaussian (train_raster.wgsl's G2).
pub const G2: usize = 9;

/// Floats per parameter record for SH degree `degree`: `[pos3, log_scale3, rot4, opacity, dc3, rest]`.
pub fn stride_for(degree: u8) -> usize {
    14 + 3 * gscodec_decoder::math::sh_rest_coeffs(degree)
}

/// Adam hyper-parameters of one step (train_adam.wgsl's `AdamStep`).
#[repr(C)]
#[derive(Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct AdamUniform {
    /// `lr / (1 - β1^t)` per group: position, scale, rotation, opacity, dc, rest.
    pub step_size: [f32; 6],
    pub sqrt_bc2: f32,
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
    /// Opacity reset: logits are capped at this (`reset_opacity`).
    pub cap: f32,
    pub _p0: f32,
    /// Gaussians × stride.
    pub total: u32,
    pub stride: u32,
    pub n: u32,
    pub _p1: u32,
}

/// Device, adapter facts and compiled kernels.
pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    pub subgroups: bool,
    /// Timestamp queries per compute pass (None when the adapter has none).
    pub timestamps: bool,
    pub max_binding: u64,
    pub renderer: GpuRenderer,
    errors: Arc<Mutex<Option<String>>>,
    /// Read-backs so far (every wait for data from the GPU: [`Gpu::map_wait`]).
    readbacks: std::sync::atomic::AtomicUsize,
    pub project: wgpu::ComputePipeline,
    pub emit: wgpu::ComputePipeline,
    pub tile_ranges: wgpu::ComputePipeline,
    pub raster_forward: wgpu::ComputePipeline,
    pub raster_backward: wgpu::ComputePipeline,
    pub project_backward: wgpu::ComputePipeline,
    pub ssim_h: wgpu::ComputePipeline,
    pub ssim_v: wgpu::ComputePipeline,
    pub ssim_bh: wgpu::ComputePipeline,
    pub ssim_bv: wgpu::ComputePipeline,
    pub adam: wgpu::ComputePipeline,
    pub reset_opacity: wgpu::ComputePipeline,
    pub count_pairs: wgpu::ComputePipeline,
    pub rate_quantise: wgpu::ComputePipeline,
    pub rate_reduce: wgpu::ComputePipeline,
    pub rate_grads: wgpu::ComputePipeline,
    pub rate_update: wgpu::ComputePipeline,
}

fn adapter() -> Option<wgpu::Adapter> {
    gscodec_decoder::render::gpu::default_adapter().ok()
}

/// Whether a hardware (not CPU/software, e.g. lavapipe) GPU adapter is available.
pub fn hardware_adapter_available() -> bool {
    adapter().is_some_and(|a| a.get_info().device_type != wgpu::DeviceType::Cpu)
}

/// The SSIM window's taps as a WGSL constant (from [`crate::loss::ssim::gaussian_taps`]).
fn taps_wgsl() -> String {
    let t = crate::loss::ssim::gaussian_taps();
    let list: Vec<String> = t.iter().map(|v| format!("{:e}", *v as f32)).collect();
    format!("var<private> TAPS: array<f32, 11> = array<f32, 11>({});\n", list.join(", "))
}

impl Gpu {
    /// Opens the default adapter. `Ok(None)` when there is none at all.
    pub fn new() -> Result<Option<Gpu>> {
        let Some(adapter) = adapter() else { return Ok(None) };
        Gpu::with_adapter(&adapter).map(Some)
    }

    /// The process's training device: opened by the first call ([`Gpu::new`]) and kept, so every
    /// training in the process (a sweep's concurrent points included) shares one device and its
    /// compiled kernels, and no device is destroyed while another trains. `Ok(None)` when there is
    /// no adapter. Sharing means an uncaptured validation error is reported by whichever training
    /// checks first, and [`Gpu::readbacks`] counts every training's read-backs.
    pub fn shared() -> Result<Option<Arc<Gpu>>> {
        static SHARED: Mutex<Option<Arc<Gpu>>> = Mutex::new(None);
        let mut slot = SHARED.lock().unwrap_or_else(|p| p.into_inner());
        if slot.is_none() {
            *slot = Gpu::new()?.map(Arc::new);
        }
        Ok(slot.clone())
    }

    pub fn with_adapter(adapter: &wgpu::Adapter) -> Result<Gpu> {
        let limits = adapter.limits();
        let mut required = wgpu::Limits::downlevel_defaults();
        required.max_storage_buffer_binding_size = limits.max_storage_buffer_binding_size;
        required.max_buffer_size = limits.max_buffer_size;
        required.max_storage_buffers_per_shader_stage = 8.min(limits.max_storage_buffers_per_shader_stage);
        required.max_compute_workgroup_storage_size = limits.max_compute_workgroup_storage_size.min(16384);
        required.max_compute_workgroups_per_dimension = limits.max_compute_workgroups_per_dimension.min(65535);
        let have = adapter.features();
        let mut features = wgpu::Features::empty();
        let subgroups = have.contains(wgpu::Features::SUBGROUP) && std::env::var_os("GSCODEC_GPU_NO_SUBGROUPS").is_none();
        if subgroups {
            features |= wgpu::Features::SUBGROUP;
        }
        let timestamps = have.contains(wgpu::Features::TIMESTAMP_QUERY);
        if timestamps {
            features |= wgpu::Features::TIMESTAMP_QUERY;
        }
        let (device, queue) = block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("gscodec-train"),
            required_limits: required.clone(),
            required_features: features,
            ..Default::default()
        }))
        .map_err(|e| Error::Failure(format!("cannot create a GPU device: {e}")))?;
        let info = adapter.get_info();
        let max_binding = required.max_storage_buffer_binding_size;
        let renderer = GpuRenderer::from_device(device.clone(), queue.clone(), info.clone(), max_binding)
            .map_err(|e| Error::Failure(e.to_string()))?;
        // The renderer installed its error sink; ours replaces it and the renderer's check() is unused.
        let errors = error_sink(&device);
        let module = |name: &str, src: &str| shader_module(&device, name, src);
        let pipeline = |m: &wgpu::ShaderModule, entry: &str| compute_pipeline(&device, m, entry);
        let raster_src = if subgroups {
            TRAIN_RASTER.replace("SUBGROUP_ARGS", ", @builtin(subgroup_invocation_id) sg_lane: u32").replace(
                "ACCUMULATE",
                "if (subgroupAny(hit)) {\n\
                 let s0 = subgroupAdd(g_mean.x); let s1 = subgroupAdd(g_mean.y);\n\
                 let s2 = subgroupAdd(g_conic.x); let s3 = subgroupAdd(g_conic.y); let s4 = subgroupAdd(g_conic.z);\n\
                 let s5 = subgroupAdd(g_op);\n\
                 let s6 = subgroupAdd(g_col.x); let s7 = subgroupAdd(g_col.y); let s8 = subgroupAdd(g_col.z);\n\
                 if (sg_lane == 0u) { let o = j * G2;\n\
                 wg_add(o, s0); wg_add(o + 1u, s1); wg_add(o + 2u, s2); wg_add(o + 3u, s3); wg_add(o + 4u, s4);\n\
                 wg_add(o + 5u, s5); wg_add(o + 6u, s6); wg_add(o + 7u, s7); wg_add(o + 8u, s8); } }",
            )
        } else {
            TRAIN_RASTER.replace("SUBGROUP_ARGS", "").replace(
                "ACCUMULATE",
                "if (hit) { let o = j * G2;\n\
                 wg_add(o, g_mean.x); wg_add(o + 1u, g_mean.y); wg_add(o + 2u, g_conic.x); wg_add(o + 3u, g_conic.y);\n\
                 wg_add(o + 4u, g_conic.z); wg_add(o + 5u, g_op); wg_add(o + 6u, g_col.x); wg_add(o + 7u, g_col.y);\n\
                 wg_add(o + 8u, g_col.z); }",
            )
        };
        let project_m = module("project", PROJECT);
        let emit_m = module("emit", EMIT);
        let rasterize_m = module("rasterize", RASTERIZE);
        let train_raster_m = module("train_raster", &raster_src);
        let train_project_m = module("train_project", TRAIN_PROJECT);
        let train_loss_m = module("train_loss", &format!("{}{TRAIN_LOSS}", taps_wgsl()));
        let train_adam_m = module("train_adam", TRAIN_ADAM);
        let train_rate_m = module("train_rate", TRAIN_RATE);
        let train_count_m = module("train_count", TRAIN_COUNT);
        let gpu = Gpu {
            project: pipeline(&project_m, "project"),
            emit: pipeline(&emit_m, "emit"),
            tile_ranges: pipeline(&rasterize_m, "tile_ranges"),
            raster_forward: pipeline(&train_raster_m, "forward"),
            raster_backward: pipeline(&train_raster_m, "backward"),
            project_backward: pipeline(&train_project_m, "project_backward"),
            ssim_h: pipeline(&train_loss_m, "ssim_h"),
            ssim_v: pipeline(&train_loss_m, "ssim_v"),
            ssim_bh: pipeline(&train_loss_m, "ssim_bh"),
            ssim_bv: pipeline(&train_loss_m, "ssim_bv"),
            adam: pipeline(&train_adam_m, "adam"),
            reset_opacity: pipeline(&train_adam_m, "reset_opacity"),
            count_pairs: pipeline(&train_count_m, "count_pairs"),
            rate_quantise: pipeline(&train_rate_m, "quantise"),
            rate_reduce: pipeline(&train_rate_m, "rate_reduce"),
            rate_grads: pipeline(&train_rate_m, "rate_grads"),
            rate_update: pipeline(&train_rate_m, "rate_update"),
            device,
            queue,
            info,
            subgroups,
            timestamps,
            max_binding,
            renderer,
            errors,
            readbacks: Default::default(),
        };
        gpu.check()?;
        Ok(gpu)
    }

    /// `"name (backend, device type)"` of the adapter.
    pub fn adapter_name(&self) -> String {
        format!("{} ({:?}, {:?})", self.info.name, self.info.backend, self.info.device_type)
    }

    /// The first wgpu error since the last check, as a failure.
    pub fn check(&self) -> Result<()> {
        match self.errors.lock().unwrap_or_else(|p| p.into_inner()).take() {
            Some(e) => Err(Error::Failure(format!("GPU error: {e}"))),
            None => Ok(()),
        }
    }

    pub fn fits(&self, what: &str, bytes: u64) -> Result<()> {
        if bytes > self.max_binding {
            return Err(Error::Input(format!(
                "GPU training: {what} needs {bytes} bytes, more than this adapter binds at once ({})",
                self.max_binding
            )));
        }
        Ok(())
    }

    pub fn storage(&self, label: &str, bytes: u64) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: bytes.max(16).next_multiple_of(4),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    pub fn storage_init(&self, label: &str, data: &[u8]) -> wgpu::Buffer {
        if data.is_empty() {
            return self.storage(label, 16);
        }
        self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: data,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
        })
    }

    pub fn uniform_buffer(&self, bytes: u64) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("uniform"),
            size: bytes,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    pub fn uniform<T: bytemuck::Pod>(&self, value: &T) -> wgpu::Buffer {
        self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: None,
            contents: bytemuck::bytes_of(value),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        })
    }

    pub fn bind(&self, pipeline: &wgpu::ComputePipeline, buffers: &[(u32, &wgpu::Buffer)]) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> =
            buffers.iter().map(|&(binding, b)| wgpu::BindGroupEntry { binding, resource: b.as_entire_binding() }).collect();
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &pipeline.get_bind_group_layout(0),
            entries: &entries,
        })
    }

    /// Reads `bytes` bytes of `src` from `offset` back to the host (waits for the queue).
    pub fn read_back(&self, src: &wgpu::Buffer, offset: u64, bytes: u64) -> Result<Vec<u8>> {
        if bytes == 0 {
            return Ok(Vec::new());
        }
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = self.device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(src, offset, &staging, 0, bytes);
        self.queue.submit([enc.finish()]);
        self.map_wait(&staging)
    }

    /// Read-backs so far (each one a wait for the GPU).
    pub fn readbacks(&self) -> usize {
        self.readbacks.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Maps a MAP_READ buffer (after its copy was submitted) and returns its bytes.
    pub fn map_wait(&self, staging: &wgpu::Buffer) -> Result<Vec<u8>> {
        self.readbacks.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let mapped = map_wait(&self.device, staging);
        self.check()?;
        mapped.map_err(|e| Error::Failure(format!("GPU {e}")))?;
        let bytes = staging.slice(..).get_mapped_range().map_err(|e| Error::Failure(format!("GPU error: {e}")))?.to_vec();
        staging.unmap();
        Ok(bytes)
    }

    pub fn read_f32(&self, src: &wgpu::Buffer, n: usize) -> Result<Vec<f32>> {
        Ok(bytemuck::pod_collect_to_vec(&self.read_back(src, 0, n as u64 * 4)?))
    }
}

/// Bytes of the projected-Gaussian array for `n` Gaussians.
pub fn projected_bytes(n: usize) -> u64 {
    n as u64 * PROJECTED_BYTES
}
