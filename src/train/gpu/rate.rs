//! The rate term on the GPU: straight-through quantised render records, `w·R` and its gradient
//! from the learned per-channel densities, the soft "kept" factor, and the learned log steps
//! (LSQ estimator plus ∂R/∂ln s, one Adam step per iteration) — [`RateTerm`]'s maths, run by
//! `shaders/train_rate.wgsl` with every value (steps, their Adam moments, the densities) kept on
//! the GPU. The host fits the starting densities once ([`RateTerm::fit_models`], one read-back
//! of the parameters when the term starts) and reads the steps and the bit estimate back when
//! the trainer reads its scalars.

use super::context::{dims, Gpu};
use super::session::record_offset;
use crate::rate::group::{Group, GroupMap};
use crate::rate::term::{RateTerm, FIXED_BITS_PER_GAUSSIAN, LEARNED_GROUPS, STEP_LR, STEP_RANGE};
use crate::rate::Steps;
use crate::Result;
use gscodec_decoder::Splats;

/// f32 slots of the state buffer before the per-channel densities (train_rate.wgsl's STATE_MODELS).
const STATE_MODELS: usize = 40;
const STATE_D_LOG_STEP: usize = 24;
const STATE_BITS: usize = 32;
const SUMS: usize = 5;

/// A compute pass to record: pipeline, bind group, workgroups.
pub type Pass<'g> = (&'g wgpu::ComputePipeline, wgpu::BindGroup, (u32, u32));

/// train_rate.wgsl's `RateParams`.
#[repr(C)]
#[derive(Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct RateUniform {
    n: u32,
    stride: u32,
    channels: u32,
    learn: u32,
    weight: f32,
    logit_min: f32,
    step_size: f32,
    sqrt_bc2: f32,
    loss_word: u32,
    total: u32,
    learned: u32,
    fixed_bits: f32,
    bits_word: u32,
    rest_deadzone: f32,
    _pad: [u32; 2],
    start: [f32; 8],
    adam: [f32; 4],
}

/// What the GPU rate term holds after an update, read back.
#[derive(Debug, Clone, PartialEq)]
pub struct RateState {
    pub steps: Steps,
    /// ∂(D + w·R)/∂ln s per group of the last update.
    pub d_log_step: GroupMap<f64>,
    /// R (bits) of the last update.
    pub bits: f64,
}

/// The rate term's GPU buffers and its description.
pub struct GpuRate {
    /// λ, starting steps, pruning opacity, whether steps are learned, start iteration; its
    /// `steps` and `last_bits` are updated from the GPU by [`GpuRate::read`].
    pub term: RateTerm,
    channels: u32,
    uniform: wgpu::Buffer,
    pub(super) state: wgpu::Buffer,
    chan: wgpu::Buffer,
    qgroup: wgpu::Buffer,
    sums: wgpu::Buffer,
    /// Quantised render records (grown with the scene).
    pub(super) render: wgpu::Buffer,
    render_floats: usize,
    /// Adam steps taken on the log steps.
    adam_step: u64,
    /// Whether the densities were fitted (the term has started).
    pub started: bool,
}

impl GpuRate {
    /// Buffers for `term` on a scene of SH degree `degree` and record stride `stride`.
    pub fn new(gpu: &Gpu, term: RateTerm, degree: u8, stride: usize) -> GpuRate {
        let channels = RateTerm::channels(degree);
        let chan: Vec<[u32; 2]> = channels.iter().map(|&(g, c)| [record_offset(g, degree, c) as u32, g as u32]).collect();
        let mut qgroup = vec![u32::MAX; stride];
        for &[o, g] in &chan {
            qgroup[o as usize] = g;
        }
        let mut state = vec![0.0f32; STATE_MODELS + 2 * channels.len()];
        for g in Group::ALL {
            state[g as usize] = term.steps.of(g);
        }
        GpuRate {
            channels: channels.len() as u32,
            uniform: gpu.uniform_buffer(std::mem::size_of::<RateUniform>() as u64),
            state: gpu.storage_init("rate state", bytemuck::cast_slice(&state)),
            chan: gpu.storage_init("rate channels", bytemuck::cast_slice(&chan)),
            qgroup: gpu.storage_init("rate groups", bytemuck::cast_slice(&qgroup)),
            sums: gpu.storage("rate sums", ((channels.len() + 1) * SUMS * 4) as u64),
            render: gpu.storage("render records", 16),
            render_floats: 0,
            adam_step: 0,
            started: false,
            term,
        }
    }

    /// Whether the term is on at iteration `it`.
    pub fn on_at(&self, it: usize) -> bool {
        it >= self.term.start_iter
    }

    /// Starts the term: fits each channel's density to `params` (as the CPU term does on its
    /// first call) and uploads it.
    pub fn start(&mut self, gpu: &Gpu, params: &Splats) {
        let models: Vec<f32> = RateTerm::fit_models(params).iter().flat_map(|m| [m.mu as f32, m.log_b as f32]).collect();
        gpu.queue.write_buffer(&self.state, (STATE_MODELS * 4) as u64, bytemuck::cast_slice(&models));
        self.started = true;
    }

    /// Makes the render-record buffer hold `floats` values.
    fn ensure_render(&mut self, gpu: &Gpu, floats: usize) {
        if self.render_floats < floats {
            self.render = gpu.storage("render records", (floats * 4) as u64);
            self.render_floats = floats;
        }
    }

    /// Writes this iteration's uniform (`loss_word`: where the loss kernel sums this iteration's
    /// loss, `bits_word`: where `R` goes); counts the Adam step of the log steps when they are
    /// learned.
    pub fn prepare(&mut self, gpu: &Gpu, n: usize, stride: usize, loss_word: u32, bits_word: u32) {
        self.ensure_render(gpu, n * stride);
        let rule = crate::optim::AdamRule { step: self.adam_step, ..Default::default() };
        let (mut step_size, mut sqrt_bc2) = (0.0, 1.0);
        if self.term.learn_steps {
            self.adam_step += 1;
            let bc1 = 1.0 - f64::from(rule.beta1).powf(self.adam_step as f64);
            let bc2 = 1.0 - f64::from(rule.beta2).powf(self.adam_step as f64);
            step_size = (f64::from(STEP_LR) / bc1) as f32;
            sqrt_bc2 = bc2.sqrt() as f32;
        }
        let start = self.term.start_steps();
        let min_opacity = self.term.min_opacity;
        let u = RateUniform {
            n: n as u32,
            stride: stride as u32,
            channels: self.channels,
            learn: self.term.learn_steps as u32,
            weight: self.term.lambda.training_weight_per_bit() as f32,
            logit_min: (min_opacity / (1.0 - min_opacity).max(1e-6)).max(1e-9).ln(),
            step_size,
            sqrt_bc2,
            loss_word,
            total: (n * stride) as u32,
            learned: LEARNED_GROUPS.iter().fold(0, |m, &g| m | 1 << g as u32),
            fixed_bits: FIXED_BITS_PER_GAUSSIAN as f32,
            bits_word,
            rest_deadzone: self.term.deadzone(Group::Sh1),
            _pad: [0; 2],
            start: std::array::from_fn(|g| if g < 8 { start.of(Group::ALL[g]) } else { 1.0 }),
            adam: [rule.beta1, rule.beta2, rule.eps, STEP_RANGE.ln()],
        };
        gpu.queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&u));
    }

    /// The pass quantising `params` (`total` floats) into the render records.
    pub fn quantise<'g>(&self, gpu: &'g Gpu, params: &wgpu::Buffer, total: usize) -> Pass<'g> {
        let bg = gpu.bind(&gpu.rate_quantise, &[(0, &self.uniform), (1, params), (3, &self.state), (6, &self.render), (8, &self.qgroup)]);
        (&gpu.rate_quantise, bg, dims((total as u32).div_ceil(256)))
    }

    /// The passes summing over the Gaussians and adding the rate gradient into `grads` (after the
    /// image backward wrote it).
    pub fn grads<'g>(&self, gpu: &'g Gpu, params: &wgpu::Buffer, grads: &wgpu::Buffer, n: usize) -> [Pass<'g>; 2] {
        let reduce =
            gpu.bind(&gpu.rate_reduce, &[(0, &self.uniform), (1, params), (2, grads), (3, &self.state), (4, &self.chan), (5, &self.sums)]);
        let add = gpu.bind(&gpu.rate_grads, &[(0, &self.uniform), (1, params), (2, grads), (3, &self.state), (4, &self.chan)]);
        [(&gpu.rate_reduce, reduce, dims(self.channels + 1)), (&gpu.rate_grads, add, dims((n as u32).div_ceil(256)))]
    }

    /// The pass updating the densities and the steps and adding `w·R` to the loss word.
    pub fn update<'g>(&self, gpu: &'g Gpu, loss: &wgpu::Buffer) -> Pass<'g> {
        let bg = gpu.bind(&gpu.rate_update, &[(0, &self.uniform), (3, &self.state), (4, &self.chan), (5, &self.sums), (7, loss)]);
        (&gpu.rate_update, bg, (1, 1))
    }

    /// Reads the steps, the last step gradient and bit estimate back, and records them in
    /// [`Self::term`] (for the report's [`crate::train::RateOutcome`]).
    pub fn read(&mut self, gpu: &Gpu) -> Result<RateState> {
        let s = gpu.read_f32(&self.state, STATE_MODELS)?;
        let mut steps = self.term.steps;
        for g in LEARNED_GROUPS {
            *steps.of_mut(g) = s[g as usize];
        }
        let d_log_step = GroupMap::from_fn(|g| f64::from(s[STATE_D_LOG_STEP + g as usize]));
        let bits = f64::from(s[STATE_BITS]);
        self.term.steps = steps;
        self.term.last_bits = bits;
        Ok(RateState { steps, d_log_step, bits })
    }
}
