//! The GPU-resident training state (parameters, gradients, Adam moments, densification statistics,
//! per-view images) and the recording of one iteration.

use super::context::{dims, projected_bytes, stride_for, AdamUniform, FrameUniform, Gpu, G2};
use super::rate::{GpuRate, Pass};
use crate::rate::group::{self, Group};
use crate::rate::term::RateTerm;
use crate::{Error, Result};
use gscodec_decoder::math::TILE;
use gscodec_decoder::{Camera, Image, Splats};

/// Parameter records of a scene: `[pos3, log_scale3, rot4, opacity, dc3, rest 3K]` per Gaussian.
pub fn to_records(s: &Splats) -> Vec<f32> {
    let stride = stride_for(s.sh_degree);
    let mut r = Vec::with_capacity(s.len() * stride);
    for i in 0..s.len() {
        r.extend_from_slice(&s.positions[i]);
        r.extend_from_slice(&s.log_scales[i]);
        r.extend_from_slice(&s.rotations[i]);
        r.push(s.opacity_logits[i]);
        r.extend_from_slice(&s.sh_dc[i]);
        r.extend_from_slice(s.rest_of(i));
    }
    r
}

/// Offset in a parameter record (SH degree `degree`) of value `c` of group `g`.
pub fn record_offset(g: Group, degree: u8, c: usize) -> usize {
    let field = match g {
        Group::Position => 0,
        Group::Scale => 3,
        Group::Rotation => 6,
        Group::Opacity => 10,
        Group::ShDc => 11,
        Group::Sh1 | Group::Sh2 | Group::Sh3 => 14,
    };
    field + group::layout(g, degree).1.start + c
}

/// Inverse of [`to_records`].
pub fn from_records(r: &[f32], degree: u8) -> Splats {
    let stride = stride_for(degree);
    let mut s = Splats::new(degree);
    for rec in r.chunks_exact(stride) {
        s.push(
            [rec[0], rec[1], rec[2]],
            [rec[3], rec[4], rec[5]],
            [rec[6], rec[7], rec[8], rec[9]],
            rec[10],
            [rec[11], rec[12], rec[13]],
            &rec[14..],
        );
    }
    s
}

/// Buffers sized by the scene.
pub struct SceneBufs {
    pub n: usize,
    pub degree: u8,
    pub stride: usize,
    pub params: wgpu::Buffer,
    pub grads: wgpu::Buffer,
    pub m: wgpu::Buffer,
    pub v: wgpu::Buffer,
    pub projected: wgpu::Buffer,
    pub counts: wgpu::Buffer,
    pub grad2d: wgpu::Buffer,
    pub stats: wgpu::Buffer,
}

/// Buffers sized by the image.
pub struct ImageBufs {
    pub width: u32,
    pub height: u32,
    pub image: wgpu::Buffer,
    pub final_t: wgpu::Buffer,
    pub last: wgpu::Buffer,
    pub dl: wgpu::Buffer,
    pub planes: wgpu::Buffer,
    pub gplanes: wgpu::Buffer,
    pub gblur: wgpu::Buffer,
    pub ranges: wgpu::Buffer,
}

/// Iterations whose scalars the GPU keeps (a ring of slots); the host reads them at least this
/// often ([`Session::read_scalars`]).
pub const RING: u64 = 64;
/// Bytes per slot: the 12 stage timestamps (u64) at 0, then the words below (the slot size is the
/// query-resolve alignment).
const SLOT: u64 = 256;
const SLOT_WORDS: u32 = (SLOT / 4) as u32;
/// f32: the iteration's loss (image loss, plus `w·R` with the rate term).
const LOSS_WORD: u32 = 24;
/// u32: the iteration's (tile, Gaussian) pairs, before clamping to the key capacity.
const PAIRS_WORD: u32 = 25;
/// f32: the rate term's `R` in bits (0 when it is off).
const BITS_WORD: u32 = 26;
const TIMESTAMPS: u32 = 12;

/// What one iteration left in its slot.
#[derive(Debug, Clone, Copy)]
pub struct IterScalars {
    pub loss: f32,
    pub pairs: u32,
    /// The rate term's bit estimate (None when it was off).
    pub bits: Option<f32>,
    /// GPU seconds per stage (project, sort, rasterize, loss, backward, optimiser), from
    /// timestamp queries when the adapter has them.
    pub stage_seconds: Option<[f64; 6]>,
}

/// The scalars of the iterations recorded since the last read.
#[derive(Debug, Clone)]
pub struct Scalars {
    /// One per iteration, oldest first.
    pub iters: Vec<IterScalars>,
    /// First non-finite gradient / value (flat record index; u32::MAX: none) so far.
    pub bad_grad: u32,
    pub bad_value: u32,
}

/// GPU training state.
pub struct Session<'g> {
    pub gpu: &'g Gpu,
    pub scene: SceneBufs,
    pub img: Option<ImageBufs>,
    frame: wgpu::Buffer,
    chunk: wgpu::Buffer,
    adam_u: wgpu::Buffer,
    keys_a: [wgpu::Buffer; 3],
    keys_b: [wgpu::Buffer; 3],
    /// Keys the key buffers hold (a multiple of the sort's 1024-key block).
    key_cap: u32,
    /// Pairs to sort (the count clamped to `key_cap`), written on the GPU.
    sort_n: wgpu::Buffer,
    /// Indirect dispatch sizes of the sort and of the tile ranges, written on the GPU.
    sort_args: wgpu::Buffer,
    count_u: wgpu::Buffer,
    ranges_u: wgpu::Buffer,
    /// The next projection reads its pair count back to size the key buffers (at the start and
    /// after the scene changed).
    need_count: bool,
    /// Per-iteration scalars, [`RING`] slots of [`SLOT`] bytes.
    pub ring: wgpu::Buffer,
    ring_staging: wgpu::Buffer,
    /// Iterations submitted ([`Session::submit`]); the current one writes slot `recorded % RING`.
    recorded: u64,
    /// The first iteration whose scalars were not read yet.
    unread: u64,
    /// Iterations whose pairs exceeded the key capacity (they rendered the pairs that fit).
    pub truncated: usize,
    /// First non-finite gradient / value index (u32::MAX = none).
    bad: wgpu::Buffer,
    query: Option<wgpu::QuerySet>,
    period_ns: f64,
    pub step: u64,
    /// The rate term, when training under `D + λ·R`.
    pub rate: Option<GpuRate>,
    /// Whether the rate term is on in the iteration being recorded (render from the quantised
    /// records, add `w·R`, update steps).
    rate_on: bool,
}

impl<'g> Session<'g> {
    /// Uploads `splats` (parameters; zero moments).
    pub fn new(gpu: &'g Gpu, splats: &Splats) -> Result<Self> {
        let scene = scene_bufs(gpu, splats, None)?;
        let key = |name| gpu.storage(name, 1024 * 4);
        let query = gpu.timestamps.then(|| {
            gpu.device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("stages"),
                ty: wgpu::QueryType::Timestamp,
                count: TIMESTAMPS,
            })
        });
        let s = Session {
            scene,
            img: None,
            frame: gpu.uniform_buffer(std::mem::size_of::<FrameUniform>() as u64),
            chunk: gpu.uniform_buffer(16),
            adam_u: gpu.uniform_buffer(std::mem::size_of::<AdamUniform>() as u64),
            keys_a: [key("tile A"), key("depth A"), key("id A")],
            keys_b: [key("tile B"), key("depth B"), key("id B")],
            key_cap: 1024,
            sort_n: gpu.storage("sort count", 16),
            sort_args: gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("sort dispatch"),
                size: 32,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::INDIRECT,
                mapped_at_creation: false,
            }),
            count_u: gpu.uniform_buffer(16),
            ranges_u: gpu.uniform_buffer(16),
            need_count: true,
            ring: gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("scalars"),
                size: RING * SLOT,
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_SRC
                    | wgpu::BufferUsages::COPY_DST
                    | wgpu::BufferUsages::QUERY_RESOLVE,
                mapped_at_creation: false,
            }),
            ring_staging: gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("scalars read-back"),
                size: RING * SLOT + 16,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            recorded: 0,
            unread: 0,
            truncated: 0,
            bad: gpu.storage_init("bad", bytemuck::cast_slice(&[u32::MAX; 4])),
            query,
            period_ns: gpu.queue.get_timestamp_period() as f64,
            step: 0,
            rate: None,
            rate_on: false,
            gpu,
        };
        gpu.queue.write_buffer(&s.ranges_u, 0, bytemuck::cast_slice(&[s.key_cap, 0, 0, 0]));
        gpu.check()?;
        Ok(s)
    }

    /// The slot of the iteration being recorded, as a word index into [`Self::ring`].
    fn slot_word(&self) -> u32 {
        (self.recorded % RING) as u32 * SLOT_WORDS
    }

    /// Makes the key buffers hold at least `pairs` keys (with room to grow).
    fn ensure_keys(&mut self, pairs: u32) -> Result<()> {
        if pairs <= self.key_cap {
            return Ok(());
        }
        let g = self.gpu;
        let cap = pairs.saturating_add(pairs / 2).next_multiple_of(1024);
        g.fits("the sort keys", cap as u64 * 4)?;
        let key = |name| g.storage(name, cap as u64 * 4);
        self.keys_a = [key("tile A"), key("depth A"), key("id A")];
        self.keys_b = [key("tile B"), key("depth B"), key("id B")];
        self.key_cap = cap;
        g.queue.write_buffer(&self.ranges_u, 0, bytemuck::cast_slice(&[cap, 0, 0, 0]));
        Ok(())
    }

    /// Trains under `D + λ·R` with `term` from its start iteration on.
    pub fn set_rate(&mut self, term: RateTerm) {
        self.rate = Some(GpuRate::new(self.gpu, term, self.scene.degree, self.scene.stride));
    }

    /// Turns the rate term on for the iteration about to be recorded when `it` is at or after its
    /// start (the first time, its densities are fitted to the parameters: one read-back).
    pub fn begin_rate(&mut self, it: usize) -> Result<()> {
        self.rate_on = self.rate.as_ref().is_some_and(|r| r.on_at(it));
        if !self.rate_on {
            return Ok(());
        }
        if !self.rate.as_ref().unwrap().started {
            let p = self.download_params()?;
            self.rate.as_mut().unwrap().start(self.gpu, &p);
        }
        let (n, stride, word) = (self.scene.n, self.scene.stride, self.slot_word());
        self.rate.as_mut().unwrap().prepare(self.gpu, n, stride, word + LOSS_WORD, word + BITS_WORD);
        Ok(())
    }

    /// The records the iteration renders from: the quantised ones while the rate term is on.
    fn render_records(&self) -> &wgpu::Buffer {
        match (&self.rate, self.rate_on) {
            (Some(r), true) => &r.render,
            _ => &self.scene.params,
        }
    }

    /// Records the rate term's passes alone (quantised records; gradient into the gradient buffer
    /// as it is; the updates): for tests of the term.
    #[doc(hidden)]
    pub fn record_rate(&self, enc: &mut wgpu::CommandEncoder) {
        let (g, sc) = (self.gpu, &self.scene);
        if let (Some(r), true) = (&self.rate, self.rate_on) {
            self.run(enc, &r.quantise(g, &sc.params, sc.n * sc.stride), (None, None));
            for p in r.grads(g, &sc.params, &sc.grads, sc.n) {
                self.run(enc, &p, (None, None));
            }
            self.run(enc, &r.update(g, &self.ring), (None, None));
        }
    }

    fn run(&self, enc: &mut wgpu::CommandEncoder, p: &Pass, ts: (Option<u32>, Option<u32>)) {
        self.pass(enc, p.0, &p.1, p.2, ts);
    }

    /// Replaces the scene (after densification): parameters and moments given.
    pub fn replace_scene(&mut self, splats: &Splats, m: &Splats, v: &Splats) -> Result<()> {
        self.scene = scene_bufs(self.gpu, splats, Some((m, v)))?;
        self.need_count = true;
        Ok(())
    }

    /// Reads parameters and Adam moments back.
    pub fn download(&self) -> Result<(Splats, Splats, Splats)> {
        let sc = &self.scene;
        let total = sc.n * sc.stride;
        let p = from_records(&self.gpu.read_f32(&sc.params, total)?, sc.degree);
        let m = from_records(&self.gpu.read_f32(&sc.m, total)?, sc.degree);
        let v = from_records(&self.gpu.read_f32(&sc.v, total)?, sc.degree);
        Ok((p, m, v))
    }

    pub fn download_params(&self) -> Result<Splats> {
        let sc = &self.scene;
        Ok(from_records(&self.gpu.read_f32(&sc.params, sc.n * sc.stride)?, sc.degree))
    }

    /// Densification statistics `(Σ|dL/dmean2d|, count, max radius)` per Gaussian.
    pub fn download_stats(&self) -> Result<Vec<f32>> {
        self.gpu.read_f32(&self.scene.stats, self.scene.n * 3)
    }

    /// Sets the densification statistics (`(Σ|dL/dmean2d|, count, max radius)` per Gaussian).
    pub fn upload_stats(&self, stats: &[f32]) {
        self.gpu.queue.write_buffer(&self.scene.stats, 0, bytemuck::cast_slice(stats));
    }

    pub fn clear_stats(&self) {
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        enc.clear_buffer(&self.scene.stats, 0, None);
        self.gpu.queue.submit([enc.finish()]);
    }

    /// Sizes the image buffers for `w × h`.
    pub fn ensure_image(&mut self, w: u32, h: u32) -> Result<()> {
        if self.img.as_ref().is_some_and(|b| b.width == w && b.height == h) {
            return Ok(());
        }
        let g = self.gpu;
        let n = w as u64 * h as u64;
        g.fits("the SSIM planes", n * 15 * 4)?;
        let tiles = w.div_ceil(TILE) as u64 * h.div_ceil(TILE) as u64;
        self.img = Some(ImageBufs {
            width: w,
            height: h,
            image: g.storage("image", n * 12),
            final_t: g.storage("final T", n * 4),
            last: g.storage("last", n * 4),
            dl: g.storage("dL/dimage", n * 12),
            planes: g.storage("ssim planes", n * 15 * 4),
            gplanes: g.storage("ssim grad planes", n * 9 * 4),
            gblur: g.storage("ssim grad blur", n * 9 * 4),
            ranges: g.storage("tile ranges", tiles * 8),
        });
        Ok(())
    }

    fn pass<'a>(
        &self,
        enc: &mut wgpu::CommandEncoder,
        p: &wgpu::ComputePipeline,
        bg: &wgpu::BindGroup,
        groups: impl Into<Dispatch<'a>>,
        ts: (Option<u32>, Option<u32>),
    ) {
        let groups = groups.into();
        let timestamp_writes = match (&self.query, ts) {
            (Some(q), (b, e)) if b.is_some() || e.is_some() => {
                Some(wgpu::ComputePassTimestampWrites { query_set: q, beginning_of_pass_write_index: b, end_of_pass_write_index: e })
            }
            _ => None,
        };
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: None, timestamp_writes });
        pass.set_pipeline(p);
        pass.set_bind_group(0, bg, &[]);
        match groups {
            Dispatch::Direct(x, y) => pass.dispatch_workgroups(x, y, 1),
            Dispatch::Indirect(args, offset) => pass.dispatch_workgroups_indirect(args, offset),
        }
    }

    /// Step 1 of an iteration: (the rate term's quantised records,) projection + SH colour, the
    /// tile-count scan and the pair count for the sort, recorded into `enc`. Nothing is read back,
    /// except the pair count at the first frame and after the scene changed (to size the key
    /// buffers; `enc` is then submitted up to here).
    pub fn project(&mut self, enc: &mut wgpu::CommandEncoder, cam: &Camera, background: [f32; 3], degree: u8) -> Result<()> {
        let g = self.gpu;
        let sc = &self.scene;
        let frame = FrameUniform::new(cam, background, degree.min(sc.degree), sc.stride, sc.n);
        g.queue.write_buffer(&self.frame, 0, bytemuck::bytes_of(&frame));
        g.queue.write_buffer(&self.chunk, 0, bytemuck::cast_slice(&[0u32, sc.n as u32, 0, 0]));
        let word = self.slot_word();
        enc.clear_buffer(&sc.counts, 0, None);
        enc.clear_buffer(&self.ring, (word + LOSS_WORD) as u64 * 4, Some(16));
        let mut first = Some(0);
        if let (Some(r), true) = (&self.rate, self.rate_on) {
            self.run(enc, &r.quantise(g, &sc.params, sc.n * sc.stride), (first.take(), None));
        }
        let bg = g.bind(&g.project, &[(0, &self.frame), (1, &self.chunk), (2, self.render_records()), (3, &sc.projected), (4, &sc.counts)]);
        self.pass(enc, &g.project, &bg, dims((sc.n as u32).div_ceil(256)), (first, None));
        g.renderer.record_scan(enc, &sc.counts, sc.n as u32 + 1);
        self.record_count(enc);
        if self.need_count {
            let done = std::mem::replace(enc, g.device.create_command_encoder(&Default::default()));
            g.queue.submit([done.finish()]);
            let pairs = u32::from_le_bytes(g.read_back(&self.ring, (word + PAIRS_WORD) as u64 * 4, 4)?[..4].try_into().expect("4 bytes"));
            if pairs > self.key_cap {
                self.ensure_keys(pairs)?;
                self.record_count(enc);
            }
            self.need_count = false;
        }
        Ok(())
    }

    /// Records the pair count (clamped to the key capacity) and the sort's dispatch sizes.
    fn record_count(&self, enc: &mut wgpu::CommandEncoder) {
        let g = self.gpu;
        let u = [self.scene.n as u32, self.key_cap, self.slot_word() + PAIRS_WORD, 0];
        g.queue.write_buffer(&self.count_u, 0, bytemuck::cast_slice(&u));
        let bg = g
            .bind(&g.count_pairs, &[(0, &self.count_u), (1, &self.scene.counts), (2, &self.sort_n), (3, &self.sort_args), (4, &self.ring)]);
        self.pass(enc, &g.count_pairs, &bg, (1, 1), (None, Some(1)));
    }

    /// Step 2: keys, sort and tile ranges (sized on the GPU by the pair count), and the saving
    /// rasterizer (into the image buffers), recorded into `enc`.
    pub fn rasterize(&mut self, enc: &mut wgpu::CommandEncoder, cam: &Camera) -> Result<()> {
        let g = self.gpu;
        self.ensure_image(cam.width, cam.height)?;
        let sc = &self.scene;
        let img = self.img.as_ref().unwrap();
        let (tiles_x, tiles_y) = (cam.width.div_ceil(TILE), cam.height.div_ceil(TILE));
        enc.clear_buffer(&img.ranges, 0, None);
        let bg = g.bind(
            &g.emit,
            &[(0, &self.frame), (1, &sc.projected), (2, &sc.counts), (3, &self.keys_a[0]), (4, &self.keys_a[1]), (5, &self.keys_a[2])],
        );
        self.pass(enc, &g.emit, &bg, dims((sc.n as u32).div_ceil(256)), (Some(2), None));
        let tile_bits = 32 - (tiles_x * tiles_y - 1).leading_zeros();
        // (`self.keys_*` are swapped by the sort: take them out for the call.)
        let (mut a, mut b) = (self.keys_a.clone(), self.keys_b.clone());
        g.renderer.record_radix_sort(enc, &mut a, &mut b, self.key_cap, tile_bits, (&self.sort_n, 0), Some(&self.sort_args));
        (self.keys_a, self.keys_b) = (a, b);
        let sc = &self.scene;
        let img = self.img.as_ref().unwrap();
        let bg = g.bind(&g.tile_ranges, &[(1, &self.ranges_u), (2, &self.keys_a[0]), (4, &img.ranges), (7, &self.sort_n)]);
        self.pass(enc, &g.tile_ranges, &bg, Dispatch::Indirect(&self.sort_args, 12), (None, Some(3)));
        let bg = g.bind(
            &g.raster_forward,
            &[
                (0, &self.frame),
                (1, &img.ranges),
                (2, &self.keys_a[2]),
                (3, &sc.projected),
                (4, &img.image),
                (5, &img.final_t),
                (6, &img.last),
            ],
        );
        self.pass(enc, &g.raster_forward, &bg, (tiles_x, tiles_y), (Some(4), Some(5)));
        Ok(())
    }

    /// Step 3: the L1+SSIM loss of the rendered image against `target` (same size), its value
    /// into the iteration's slot, its gradient into the image-gradient buffer.
    pub fn loss(&self, enc: &mut wgpu::CommandEncoder, target: &wgpu::Buffer, ssim_weight: f32) {
        let g = self.gpu;
        let slot = self.slot_word() + LOSS_WORD;
        let img = self.img.as_ref().expect("rasterize before the loss");
        let n = img.width * img.height;
        let lp = g.uniform(&[img.width, img.height, ssim_weight.to_bits(), slot]);
        let groups = dims(n.div_ceil(256));
        enc.clear_buffer(&self.ring, slot as u64 * 4, Some(4));
        let bg = g.bind(&g.ssim_h, &[(0, &lp), (1, &img.image), (2, target), (3, &img.planes)]);
        self.pass(enc, &g.ssim_h, &bg, groups, (Some(6), None));
        let bg = g.bind(&g.ssim_v, &[(0, &lp), (1, &img.image), (2, target), (3, &img.planes), (4, &img.gplanes), (7, &self.ring)]);
        self.pass(enc, &g.ssim_v, &bg, groups, (None, None));
        let bg = g.bind(&g.ssim_bh, &[(0, &lp), (4, &img.gplanes), (5, &img.gblur)]);
        self.pass(enc, &g.ssim_bh, &bg, groups, (None, None));
        let bg = g.bind(&g.ssim_bv, &[(0, &lp), (1, &img.image), (2, target), (5, &img.gblur), (6, &img.dl)]);
        self.pass(enc, &g.ssim_bv, &bg, groups, (None, Some(7)));
    }

    /// Step 4: rasterizer backward (image gradient in the `dl` buffer) and projection backward
    /// into the parameter gradients; densification statistics when `stats`.
    pub fn backward(&self, enc: &mut wgpu::CommandEncoder, cam: &Camera, stats: bool) {
        let g = self.gpu;
        let sc = &self.scene;
        let img = self.img.as_ref().expect("rasterize before the backward pass");
        enc.clear_buffer(&sc.grad2d, 0, None);
        let bg = g.bind(
            &g.raster_backward,
            &[
                (0, &self.frame),
                (1, &img.ranges),
                (2, &self.keys_a[2]),
                (3, &sc.projected),
                (4, &img.dl),
                (5, &img.final_t),
                (6, &img.last),
                (7, &sc.grad2d),
            ],
        );
        self.pass(enc, &g.raster_backward, &bg, (cam.width.div_ceil(TILE), cam.height.div_ceil(TILE)), (Some(8), None));
        let r_scale = 800.0 / cam.width.max(cam.height) as f32;
        let bw = g.uniform(&[sc.n as u32, stats as u32, r_scale.to_bits(), 0]);
        let bg = g.bind(
            &g.project_backward,
            &[(0, &self.frame), (1, &bw), (2, self.render_records()), (3, &sc.projected), (4, &sc.grad2d), (5, &sc.grads), (6, &sc.stats)],
        );
        let rate = self.rate.as_ref().filter(|_| self.rate_on).map(|r| r.grads(g, &sc.params, &sc.grads, sc.n));
        self.pass(enc, &g.project_backward, &bg, dims((sc.n as u32).div_ceil(256)), (None, rate.is_none().then_some(9)));
        if let Some([reduce, add]) = rate {
            self.run(enc, &reduce, (None, None));
            self.run(enc, &add, (None, Some(9)));
        }
    }

    /// Step 5: one Adam step with per-group learning rates `lr` (position, scale, rotation,
    /// opacity, dc, rest), with [`crate::optim::AdamRule`]'s hyper-parameters and update.
    pub fn adam(&mut self, enc: &mut wgpu::CommandEncoder, lr: [f32; 6]) {
        let g = self.gpu;
        let sc = &self.scene;
        let mut first = Some(10);
        if let (Some(r), true) = (&self.rate, self.rate_on) {
            self.run(enc, &r.update(g, &self.ring), (first.take(), None));
        }
        self.step += 1;
        let crate::optim::AdamRule { beta1, beta2, eps, .. } = crate::optim::AdamRule::default();
        let bc1 = 1.0 - (beta1 as f64).powf(self.step as f64);
        let bc2 = 1.0 - (beta2 as f64).powf(self.step as f64);
        let total = (sc.n * sc.stride) as u32;
        let u = AdamUniform {
            step_size: lr.map(|l| (l as f64 / bc1) as f32),
            sqrt_bc2: bc2.sqrt() as f32,
            beta1,
            beta2,
            eps,
            total,
            stride: sc.stride as u32,
            n: sc.n as u32,
            ..Default::default()
        };
        g.queue.write_buffer(&self.adam_u, 0, bytemuck::bytes_of(&u));
        let bg = g.bind(&g.adam, &[(0, &self.adam_u), (1, &sc.params), (2, &sc.grads), (3, &sc.m), (4, &sc.v), (5, &self.bad)]);
        self.pass(enc, &g.adam, &bg, dims(total.div_ceil(256)), (first, Some(11)));
    }

    /// Ends an iteration's recording: resolves its timestamps into its slot and submits.
    pub fn submit(&mut self, mut enc: wgpu::CommandEncoder) {
        if let Some(q) = &self.query {
            enc.resolve_query_set(q, 0..TIMESTAMPS, &self.ring, (self.recorded % RING) * SLOT);
        }
        self.gpu.queue.submit([enc.finish()]);
        self.recorded += 1;
    }

    /// Reads the scalars of the iterations submitted since the last read (one read-back; at most
    /// [`RING`] iterations may pass between two reads) and grows the key buffers when a count
    /// came near their capacity.
    ///
    /// # Errors
    /// A GPU error, or more than [`RING`] iterations unread (a bug of the caller).
    pub fn read_scalars(&mut self) -> Result<Scalars> {
        let g = self.gpu;
        let k = self.recorded - self.unread;
        if k > RING {
            return Err(Error::Failure(format!("GPU trainer: {k} iterations unread, the ring holds {RING}")));
        }
        let mut enc = g.device.create_command_encoder(&Default::default());
        for (j, it) in (self.unread..self.recorded).enumerate() {
            enc.copy_buffer_to_buffer(&self.ring, (it % RING) * SLOT, &self.ring_staging, j as u64 * SLOT, SLOT);
        }
        enc.copy_buffer_to_buffer(&self.bad, 0, &self.ring_staging, RING * SLOT, 8);
        g.queue.submit([enc.finish()]);
        let bytes = g.map_wait(&self.ring_staging)?;
        let word = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().expect("4 bytes"));
        let iters: Vec<IterScalars> = (0..k as usize)
            .map(|j| {
                let o = j * SLOT as usize;
                let t = |i: usize| u64::from_le_bytes(bytes[o + 8 * i..o + 8 * i + 8].try_into().expect("8 bytes"));
                let bits = f32::from_bits(word(o + 4 * BITS_WORD as usize));
                IterScalars {
                    loss: f32::from_bits(word(o + 4 * LOSS_WORD as usize)),
                    pairs: word(o + 4 * PAIRS_WORD as usize),
                    bits: (bits != 0.0).then_some(bits),
                    stage_seconds: self
                        .query
                        .is_some()
                        .then(|| std::array::from_fn(|s| t(2 * s + 1).saturating_sub(t(2 * s)) as f64 * self.period_ns * 1e-9)),
                }
            })
            .collect();
        self.unread = self.recorded;
        let most = iters.iter().map(|s| s.pairs).max().unwrap_or(0);
        self.truncated += iters.iter().filter(|s| s.pairs > self.key_cap).count();
        if most as u64 * 5 > self.key_cap as u64 * 4 {
            self.ensure_keys(most.saturating_add(most / 4).max(self.key_cap + 1))?;
        }
        let r = RING as usize * SLOT as usize;
        Ok(Scalars { iters, bad_grad: word(r), bad_value: word(r + 4) })
    }

    /// Caps every opacity logit at `logit(max_opacity)` and zeroes its moments.
    pub fn reset_opacity(&self, max_opacity: f32) {
        let g = self.gpu;
        let sc = &self.scene;
        let u =
            AdamUniform { cap: (max_opacity / (1.0 - max_opacity)).ln(), stride: sc.stride as u32, n: sc.n as u32, ..Default::default() };
        let ub = g.uniform(&u);
        let mut enc = g.device.create_command_encoder(&Default::default());
        let bg = g.bind(&g.reset_opacity, &[(0, &ub), (1, &sc.params), (3, &sc.m), (4, &sc.v)]);
        self.pass(&mut enc, &g.reset_opacity, &bg, dims((sc.n as u32).div_ceil(256)), (None, None));
        g.queue.submit([enc.finish()]);
    }

    /// The saved forward state, for tests: image, final transmittance, list end per pixel.
    pub fn read_image(&self) -> Result<Image> {
        let img = self.img.as_ref().ok_or_else(|| Error::Failure("nothing rendered".into()))?;
        let n = (img.width * img.height) as usize;
        Ok(Image { width: img.width, height: img.height, data: self.gpu.read_f32(&img.image, n * 3)? })
    }

    pub fn read_dl(&self) -> Result<Vec<f32>> {
        let img = self.img.as_ref().ok_or_else(|| Error::Failure("nothing rendered".into()))?;
        self.gpu.read_f32(&img.dl, (img.width * img.height * 3) as usize)
    }

    pub fn write_dl(&self, dl: &[f32]) {
        self.gpu.queue.write_buffer(&self.img.as_ref().expect("rasterize first").dl, 0, bytemuck::cast_slice(dl));
    }

    pub fn read_grads(&self) -> Result<(Splats, Vec<f32>)> {
        let sc = &self.scene;
        let grads = from_records(&self.gpu.read_f32(&sc.grads, sc.n * sc.stride)?, sc.degree);
        let g2 = self.gpu.read_f32(&sc.grad2d, sc.n * G2)?;
        Ok((grads, g2))
    }

    /// The loss of the iteration being recorded (for tests of the loss kernels).
    pub fn read_loss(&self) -> Result<f32> {
        let b = self.gpu.read_back(&self.ring, (self.slot_word() + LOSS_WORD) as u64 * 4, 4)?;
        Ok(f32::from_le_bytes(b[..4].try_into().expect("4 bytes")))
    }
}

/// How a pass's workgroup count is given.
pub enum Dispatch<'a> {
    Direct(u32, u32),
    /// `(x, y, z)` u32 at a byte offset of a buffer written on the GPU.
    Indirect(&'a wgpu::Buffer, u64),
}

impl From<(u32, u32)> for Dispatch<'_> {
    fn from((x, y): (u32, u32)) -> Self {
        Dispatch::Direct(x, y)
    }
}

fn scene_bufs(gpu: &Gpu, splats: &Splats, moments: Option<(&Splats, &Splats)>) -> Result<SceneBufs> {
    let n = splats.len();
    let degree = splats.sh_degree;
    let stride = stride_for(degree);
    let bytes = n as u64 * stride as u64 * 4;
    gpu.fits("the scene parameters", bytes)?;
    gpu.fits("the projected Gaussians", projected_bytes(n))?;
    u32::try_from(n * stride).map_err(|_| Error::Input(format!("GPU training: {n} Gaussians are too many")))?;
    let records = to_records(splats);
    let (m, v) = match moments {
        Some((m, v)) => (
            gpu.storage_init("adam m", bytemuck::cast_slice(&to_records(m))),
            gpu.storage_init("adam v", bytemuck::cast_slice(&to_records(v))),
        ),
        None => (gpu.storage("adam m", bytes), gpu.storage("adam v", bytes)),
    };
    Ok(SceneBufs {
        n,
        degree,
        stride,
        params: gpu.storage_init("params", bytemuck::cast_slice(&records)),
        grads: gpu.storage("grads", bytes),
        m,
        v,
        projected: gpu.storage("projected", projected_bytes(n)),
        counts: gpu.storage("tile counts", (n as u64 + 1) * 4),
        grad2d: gpu.storage("grad2d", n as u64 * G2 as u64 * 4),
        stats: gpu.storage("densify stats", n as u64 * 12),
    })
}
