//! WD and WD-R on the GPU (built-in `pyramid` and `pyramid-colour` features): the feature bank,
//! the WD statistics and level weights, their backward down to the image, and the `wd` / `wdr`
//! combination with γ (fixed, or measured after the warm-up as [`crate::loss::wdr::WdrLoss`]
//! does), formula by formula as `crate::loss::{wd, wdr, features::pyramid}`, the CPU oracle
//! (`shaders/train_wd.wgsl`).
//!
//! Layout: per image size, one f32 arena holds the level weights (from [`Plan`], uploaded once),
//! the rendered image's feature arrays, their local moments and every gradient; a fixed list of
//! elementwise ops (one uniform each, made once) is recorded into one compute pass per iteration.
//! Each training view's reference statistics (level-0 features, means and standard deviations
//! of the weighted levels) are computed on the GPU the first time the view is drawn and kept in a
//! buffer of their own while the cache budget allows; views over the budget are recomputed into
//! a scratch buffer every time. γ lives on the GPU: its measurement reads nothing back.

use super::context::{dims, Gpu};
use super::session::{Session, WD_TIMESTAMPS};
use crate::loss::features::{pyramid, IMAGENET_MEAN, IMAGENET_STD};
use crate::loss::tensor::{half, same_offset};
use crate::loss::wd::{Plan, Sigma, DEFAULT_SIGMA, NUM_LEVELS};
use crate::loss::wdr::{self, BETA, DEFAULT_GAMMA_WD, DEFAULT_GAMMA_WDR, NORMALISE_VIEWS};
use crate::loss::{FeatureSpec, LossKind};
use crate::{Error, Result};

const SHADER: &str = include_str!("../../../shaders/train_wd.wgsl");

/// Words of the scalar buffer `acc` that the kernels read (d_WD, the two gradient norms, γ, γ's
/// running sums and views measured: `train_wd.wgsl`'s header).
const ACC_WORDS: usize = 8;
/// The first words of `acc` that are sums over workgroups (d_WD and the two norms).
const ACC_SUMS: usize = 3;
/// Each sum is accumulated in this many slots after [`ACC_WORDS`], a workgroup adding into the
/// slot of its index modulo this: every workgroup adding into one word (a compare-exchange loop
/// on its bit pattern) serialises them, which at 1280×960 is tens of thousands of workgroups per
/// level. `scalars` folds the slots in order.
const ACC_STRIPES: usize = 256;
/// Default budget of the per-view reference cache (the CPU's [`wdr::DEFAULT_CACHE_BYTES`]).
pub const DEFAULT_CACHE_BYTES: u64 = wdr::DEFAULT_CACHE_BYTES as u64;

// Flags of train_wd.wgsl.
const SQ: u32 = 1;
const WEIGHTED: u32 = 2;
const NEXT: u32 = 4;
const UP: u32 = 8;
const HAS0: u32 = 16;
const WDR: u32 = 32;
const NORMALISE: u32 = 64;

/// One op's uniform (`Op` in train_wd.wgsl); offsets in floats.
#[repr(C)]
#[derive(Clone, Copy, Default, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct OpU {
    c: u32,
    h: u32,
    w: u32,
    oh: u32,
    ow: u32,
    src: u32,
    src2: u32,
    dst: u32,
    dst2: u32,
    aux: u32,
    aux2: u32,
    aux3: u32,
    aux4: u32,
    aux5: u32,
    flags: u32,
    fscale: f32,
    oy: u32,
    ox: u32,
    count: u32,
    pad: u32,
}

/// The kernels of train_wd.wgsl, in the order of [`KERNELS`].
#[derive(Clone, Copy, Debug)]
enum K {
    FeatInput,
    Lowpass2,
    BasisH,
    BasisV,
    Moments,
    ExportStats,
    ExportCopy,
    LevelGrad,
    BlurPair,
    BlurSubAdjPair,
    ArrayGrad,
    RectifyAdj,
    BasisAdjH,
    BasisAdjV,
    InputAdj,
    FeatSignal,
    Lowpass2Adj,
    InputAdjSignal,
    Norms,
    Scalars,
    Combine,
}

const KERNELS: [&str; 21] = [
    "feat_input",
    "lowpass2",
    "basis_h",
    "basis_v",
    "moments",
    "export_stats",
    "export_copy",
    "level_grad",
    "blur_pair",
    "blur_sub_adj_pair",
    "array_grad",
    "rectify_adj",
    "basis_adj_h",
    "basis_adj_v",
    "input_adj",
    "feat_signal",
    "lowpass2_adj",
    "input_adj_signal",
    "norms",
    "scalars",
    "combine",
];

/// The WD loss of a GPU run: which one, and γ.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WdConfig {
    /// `Wd` or `Wdr`.
    pub kind: LossKind,
    /// A fixed γ; None: `wd`'s default, or `wdr`'s measured γ.
    pub gamma: Option<f64>,
    /// Uniform pooling scale σ (`--wd-sigma`; the level weights come from the CPU's [`Plan`]).
    pub sigma: f64,
    /// Iterations (1-based numbers up to this) trained with `L_orig` alone.
    pub warmup: usize,
    /// Budget of the reference cache in bytes.
    pub cache_bytes: u64,
    /// The `pyramid-colour` bank (opponent colour signals besides the luminance), else `pyramid`.
    pub colour: bool,
}

impl WdConfig {
    /// The config of a `kind` run of `iters` iterations (the warm-up of [`wdr::warmup_iters`]
    /// with the share `warmup`, None: [`wdr::WARMUP_FRACTION`]); `sigma` None is
    /// [`DEFAULT_SIGMA`]; in the default features ([`FeatureSpec::default`]).
    pub fn new(kind: LossKind, gamma: Option<f64>, sigma: Option<f64>, warmup: Option<f64>, iters: usize) -> Self {
        let sigma = sigma.unwrap_or(DEFAULT_SIGMA);
        let warmup = wdr::warmup_iters(iters, warmup.unwrap_or(wdr::WARMUP_FRACTION));
        WdConfig { kind, gamma, sigma, warmup, cache_bytes: DEFAULT_CACHE_BYTES, colour: FeatureSpec::default().colour() }
    }

    fn normalise(&self) -> bool {
        self.kind == LossKind::Wdr && self.gamma.is_none()
    }

    fn initial_gamma(&self) -> f64 {
        match (self.kind, self.gamma) {
            (_, Some(g)) => g,
            (LossKind::Wd, None) => DEFAULT_GAMMA_WD,
            _ => DEFAULT_GAMMA_WDR,
        }
    }
}

/// Compiled kernels and their shared layouts.
struct Kernels {
    layout0: wgpu::BindGroupLayout,
    layout1: wgpu::BindGroupLayout,
    pipes: Vec<wgpu::ComputePipeline>,
}

fn wgsl_array(name: &str, ty: &str, v: &[String]) -> String {
    format!("var<private> {name}: array<{ty}, {}> = array<{ty}, {}>({});\n", v.len(), v.len(), v.join(", "))
}

/// The CPU feature bank's constants as WGSL.
fn constants_wgsl() -> String {
    let f = |x: f64| format!("{:e}", x as f32);
    let (g, d1, d2) = pyramid::taps();
    let st = pyramid::steering();
    let mut s = String::new();
    s += &wgsl_array("TG", "f32", &g.map(f));
    s += &wgsl_array("TD1", "f32", &d1.map(f));
    s += &wgsl_array("TD2", "f32", &d2.map(f));
    s += &wgsl_array("ODD", "vec2<f32>", &st.iter().map(|(o, _)| format!("vec2<f32>({}, {})", f(o[0]), f(o[1]))).collect::<Vec<_>>());
    s += &wgsl_array(
        "EVEN",
        "vec3<f32>",
        &st.iter().map(|(_, e)| format!("vec3<f32>({}, {}, {})", f(e[0]), f(e[1]), f(e[2]))).collect::<Vec<_>>(),
    );
    s += &wgsl_array(
        "SIG",
        "vec3<f32>",
        &pyramid::SIGNALS.map(|g| format!("vec3<f32>({}, {}, {})", f(g.coef[0]), f(g.coef[1]), f(g.coef[2]))),
    );
    s += &wgsl_array("MEAN", "f32", &IMAGENET_MEAN.map(f));
    s += &wgsl_array("STD", "f32", &IMAGENET_STD.map(f));
    s += &format!("const GAIN: f32 = {};\nconst NORMALISE_VIEWS: u32 = {}u;\n", f(pyramid::GAIN), NORMALISE_VIEWS);
    s += &format!("const SUMS_AT: u32 = {ACC_WORDS}u;\nconst SUMS: u32 = {ACC_SUMS}u;\nconst STRIPES: u32 = {ACC_STRIPES}u;\n");
    s
}

impl Kernels {
    fn new(gpu: &Gpu) -> Kernels {
        let device = &gpu.device;
        let storage = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only: false },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let layout0 = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("wd buffers"),
            entries: &(0..6).map(storage).collect::<Vec<_>>(),
        });
        let layout1 = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("wd op"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::Buffer { ty: wgpu::BufferBindingType::Uniform, has_dynamic_offset: false, min_binding_size: None },
                count: None,
            }],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("wd"),
            bind_group_layouts: &[Some(&layout0), Some(&layout1)],
            immediate_size: 0,
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("train_wd"),
            source: wgpu::ShaderSource::Wgsl(format!("{}{SHADER}", constants_wgsl()).into()),
        });
        let pipes = KERNELS
            .iter()
            .map(|entry| {
                device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(entry),
                    layout: Some(&layout),
                    module: &module,
                    entry_point: Some(entry),
                    compilation_options: Default::default(),
                    cache: None,
                })
            })
            .collect();
        Kernels { layout0, layout1, pipes }
    }
}

/// One recorded op: kernel, uniform bind group, workgroups.
#[derive(Clone)]
struct Op {
    k: K,
    bind: wgpu::BindGroup,
    groups: (u32, u32),
}

/// Float offsets handed out in order.
#[derive(Default)]
struct Alloc(u64);

impl Alloc {
    fn take(&mut self, floats: usize) -> u32 {
        let at = self.0;
        self.0 += floats as u64;
        at as u32
    }
}

/// One weighted-or-not level k (1..=top) of one feature array.
#[derive(Default, Clone, Copy)]
struct Level {
    /// Resolution of the level's input x_{k-1} (where its maps live).
    h: usize,
    w: usize,
    weighted: bool,
    /// Weight map (h × w) when weighted.
    wmap: u32,
    /// m_k, p_k (c × h × w) when weighted.
    m: u32,
    p: u32,
    /// Next level's inputs x_k, q_k (c × ⌈h/2⌉ × ⌈w/2⌉) when k < top.
    xn: u32,
    qn: u32,
    /// dL/dm, dL/dp when weighted.
    gm: u32,
    gp: u32,
    /// dL/dx_{k-1}, dL/dq_{k-1}.
    gx: u32,
    gq: u32,
    /// Reference mean and sd (in the view's buffer) when weighted.
    ref_m: u32,
    ref_s: u32,
}

/// One feature array: the normalised image (c = 3) or a stage of 16 oriented channels.
struct Array {
    c: usize,
    h: usize,
    w: usize,
    feat: u32,
    grad: u32,
    top: usize,
    /// Level-0 weight map and reference features, when level 0 counts.
    level0: Option<(u32, u32)>,
    /// levels[k - 1] is level k.
    levels: Vec<Level>,
}

/// A view's reference statistics.
struct RefBuf {
    buf: wgpu::Buffer,
    filled: bool,
}

/// One signal of the bank ([`pyramid::SIGNALS`]): its index there, its first stage with
/// oriented responses, its feature arrays' first index, and its values and gradient per stage.
struct SignalLayout {
    index: usize,
    first: usize,
    array: usize,
    values: Vec<u32>,
    grads: Vec<u32>,
}

/// Where everything of one image size lives: arena and reference offsets (floats).
struct Layout {
    /// (height, width) of each stage.
    stages: Vec<(usize, usize)>,
    arrays: Vec<Array>,
    signals: Vec<SignalLayout>,
    /// Scratch: 3 and 5 planes at full resolution.
    t3: u32,
    gb5: u32,
    /// dd_WD/dimage, interleaved.
    gw: u32,
    /// Level weight maps to upload: (offset, values).
    weights: Vec<(u32, Vec<f32>)>,
    arena_floats: u64,
    ref_floats: u64,
}

impl Layout {
    /// A uniform `sigma` and the `pyramid` (or `pyramid-colour`) arrays of a `width × height`
    /// image.
    fn new(width: u32, height: u32, sigma: f64, colour: bool) -> Layout {
        let (ww, hh) = (width as usize, height as usize);
        let sigma = Sigma::Constant(sigma);
        let mut a = Alloc::default();
        let mut r = Alloc::default();
        let mut weights: Vec<(u32, Vec<f32>)> = Vec::new();

        // Feature arrays: the normalised image, then per signal its stages of 16 channels.
        let mut stages = vec![(hh, ww)];
        for s in 1..pyramid::STAGES {
            stages.push((half(stages[s - 1].0), half(stages[s - 1].1)));
        }
        let mut shapes = vec![(3, hh, ww)];
        let mut signal_at = Vec::new();
        for (index, g) in (pyramid::Pyramid { colour }).signals().iter().enumerate() {
            signal_at.push((index, g.first, shapes.len()));
            shapes.extend(stages[g.first..].iter().map(|&(h, w)| (pyramid::STAGE_CHANNELS, h, w)));
        }
        let mut arrays: Vec<Array> = Vec::new();
        for &(c, h, w) in &shapes {
            let plan = Plan::<f32>::new(&sigma, hh, ww, h, w);
            let top = plan.max_level();
            let feat = a.take(c * h * w);
            let grad = a.take(c * h * w);
            let mut put_weights = |a: &mut Alloc, t: &crate::loss::tensor::Tensor<f32>| {
                let off = a.take(t.data.len());
                weights.push((off, t.data.clone()));
                off
            };
            let level0 = plan.weights[0].as_ref().map(|t| (put_weights(&mut a, t), r.take(c * h * w)));
            let mut levels = Vec::new();
            let (mut lh, mut lw) = (h, w);
            for k in 1..=top {
                let mut l = Level { h: lh, w: lw, ..Default::default() };
                let n = c * lh * lw;
                if let Some(t) = &plan.weights[k] {
                    l.weighted = true;
                    l.wmap = put_weights(&mut a, t);
                    (l.m, l.p, l.gm, l.gp) = (a.take(n), a.take(n), a.take(n), a.take(n));
                    (l.ref_m, l.ref_s) = (r.take(n), r.take(n));
                }
                (l.gx, l.gq) = (a.take(n), a.take(n));
                (lh, lw) = (half(lh), half(lw));
                if k < top {
                    let n2 = c * lh * lw;
                    (l.xn, l.qn) = (a.take(n2), a.take(n2));
                }
                levels.push(l);
            }
            debug_assert!(levels.len() <= NUM_LEVELS);
            arrays.push(Array { c, h, w, feat, grad, top, level0, levels });
        }
        let n0 = hh * ww;
        let signals = signal_at
            .into_iter()
            .map(|(index, first, array)| SignalLayout {
                index,
                first,
                array,
                values: stages.iter().map(|&(h, w)| a.take(h * w)).collect(),
                grads: stages.iter().map(|&(h, w)| a.take(h * w)).collect(),
            })
            .collect();
        let (t3, gb5, gw) = (a.take(3 * n0), a.take(5 * n0), a.take(3 * n0));
        Layout { stages, arrays, signals, t3, gb5, gw, weights, arena_floats: a.0, ref_floats: r.0 }
    }
}

/// The WD stage of a GPU training session for one image size.
pub struct WdStage {
    pub config: WdConfig,
    pub width: u32,
    pub height: u32,
    kernels: Kernels,
    arena: wgpu::Buffer,
    acc: wgpu::Buffer,
    /// Ops computing a view's reference statistics (features, moments, export).
    reference: Vec<Op>,
    /// Features and moments of the rendered image, WD value and backward down to dL/dimage.
    forward_backward: Vec<Op>,
    norms: Op,
    /// The scalar op and its uniform (the loss word changes per iteration).
    scalars: Op,
    scalars_u: wgpu::Buffer,
    scalars_op: OpU,
    combine: Op,
    /// Floats of one view's reference statistics.
    ref_floats: u64,
    /// Arena floats.
    arena_floats: u64,
    cache: Vec<Option<RefBuf>>,
    scratch: Option<wgpu::Buffer>,
    cached_bytes: u64,
}

impl WdStage {
    /// Lays out the stage for `width × height` images (`config.sigma`, the `pyramid` features).
    ///
    /// # Errors
    /// An input error when the arena or one view's statistics exceed what the adapter binds.
    pub fn new(gpu: &Gpu, config: WdConfig, width: u32, height: u32) -> Result<WdStage> {
        let Layout { stages, arrays, signals, t3, gb5, gw, weights, arena_floats, ref_floats } =
            Layout::new(width, height, config.sigma, config.colour);
        let n0 = width as usize * height as usize;
        gpu.fits("the WD arena", arena_floats * 4)?;
        gpu.fits("one view's WD reference statistics", ref_floats * 4)?;
        if arena_floats > u32::MAX as u64 {
            return Err(Error::Input(format!("GPU training: {width}x{height} images are too large for the WD stage")));
        }

        let kernels = Kernels::new(gpu);
        let op = |k: K, u: OpU| -> Op {
            let buf = gpu.uniform(&u);
            let bind = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: None,
                layout: &kernels.layout1,
                entries: &[wgpu::BindGroupEntry { binding: 0, resource: buf.as_entire_binding() }],
            });
            Op { k, bind, groups: dims(u.count.div_ceil(256).max(1)) }
        };
        let u32_ = |v: usize| v as u32;

        // Features of the image bound as `image` and the moments of every array.
        let mut features = Vec::new();
        let stage =
            |s: usize| OpU { h: u32_(stages[s].0), w: u32_(stages[s].1), count: u32_(stages[s].0 * stages[s].1), ..Default::default() };
        for g in &signals {
            features.push(if g.index == 0 {
                op(K::FeatInput, OpU { dst: arrays[0].feat, dst2: g.values[0], count: u32_(n0), ..Default::default() })
            } else {
                op(K::FeatSignal, OpU { c: u32_(g.index), src: arrays[0].feat, dst: g.values[0], count: u32_(n0), ..Default::default() })
            });
            for s in 0..pyramid::STAGES {
                let (h, w) = stages[s];
                if s > 0 {
                    let (ph, pw) = stages[s - 1];
                    features.push(op(
                        K::Lowpass2,
                        OpU {
                            h: u32_(ph),
                            w: u32_(pw),
                            oh: u32_(h),
                            ow: u32_(w),
                            oy: u32_(same_offset(ph)),
                            ox: u32_(same_offset(pw)),
                            src: g.values[s - 1],
                            dst: g.values[s],
                            count: u32_(h * w),
                            ..Default::default()
                        },
                    ));
                }
                if s >= g.first {
                    features.push(op(K::BasisH, OpU { src: g.values[s], dst: t3, ..stage(s) }));
                    features.push(op(K::BasisV, OpU { src: t3, dst: arrays[g.array + s - g.first].feat, ..stage(s) }));
                }
            }
        }
        for ar in &arrays {
            for k in 1..=ar.top {
                let l = ar.levels[k - 1];
                let (x, q, flags) = if k == 1 { (ar.feat, 0, SQ) } else { (ar.levels[k - 2].xn, ar.levels[k - 2].qn, 0) };
                let next = if k < ar.top { NEXT } else { 0 };
                let (oh, ow) = (half(l.h), half(l.w));
                let count = if l.weighted { ar.c * l.h * l.w } else { ar.c * oh * ow };
                features.push(op(
                    K::Moments,
                    OpU {
                        c: u32_(ar.c),
                        h: u32_(l.h),
                        w: u32_(l.w),
                        oh: u32_(oh),
                        ow: u32_(ow),
                        src: x,
                        src2: q,
                        dst: l.m,
                        dst2: l.p,
                        aux: l.xn,
                        aux2: l.qn,
                        flags: flags | next | if l.weighted { WEIGHTED } else { 0 },
                        count: u32_(count),
                        ..Default::default()
                    },
                ));
            }
        }

        // Reference: features, moments, then the statistics into the view's buffer.
        let mut reference: Vec<Op> = features.clone();
        let mut fwd_bwd: Vec<Op> = Vec::new();
        for ar in &arrays {
            if let Some((_, rf)) = ar.level0 {
                reference.push(op(K::ExportCopy, OpU { src: ar.feat, dst: rf, count: u32_(ar.c * ar.h * ar.w), ..Default::default() }));
            }
            for l in ar.levels.iter().filter(|l| l.weighted) {
                reference.push(op(
                    K::ExportStats,
                    OpU { src: l.m, src2: l.p, dst: l.ref_m, dst2: l.ref_s, count: u32_(ar.c * l.h * l.w), ..Default::default() },
                ));
            }
        }
        fwd_bwd.extend(features);

        // Backward through the WD levels of each array, then the feature bank.
        for ar in &arrays {
            for k in (1..=ar.top).rev() {
                let l = ar.levels[k - 1];
                let (oh, ow) = (half(l.h), half(l.w));
                let up = (k < ar.top).then(|| ar.levels[k]);
                let n = ar.c * l.h * l.w;
                let dims_ =
                    OpU { c: u32_(ar.c), h: u32_(l.h), w: u32_(l.w), oh: u32_(oh), ow: u32_(ow), count: u32_(n), ..Default::default() };
                if l.weighted {
                    let (ux, uq) = up.map_or((0, 0), |u| (u.gx, u.gq));
                    fwd_bwd.push(op(
                        K::LevelGrad,
                        OpU {
                            src: l.m,
                            src2: l.p,
                            dst: l.gm,
                            dst2: l.gp,
                            aux: l.wmap,
                            aux2: ux,
                            aux3: uq,
                            aux4: l.ref_m,
                            aux5: l.ref_s,
                            flags: if up.is_some() { UP } else { 0 },
                            fscale: (1.0 / n as f64) as f32,
                            ..dims_
                        },
                    ));
                    fwd_bwd.push(op(K::BlurPair, OpU { src: l.gm, src2: l.gp, dst: l.gx, dst2: l.gq, ..dims_ }));
                } else {
                    let u = up.expect("the top level is weighted");
                    fwd_bwd.push(op(K::BlurSubAdjPair, OpU { src: u.gx, src2: u.gq, dst: l.gx, dst2: l.gq, ..dims_ }));
                }
            }
            let n = ar.c * ar.h * ar.w;
            let (gx, gq) = ar.levels.first().map_or((0, 0), |l| (l.gx, l.gq));
            let (w0, f0) = ar.level0.unwrap_or((0, 0));
            fwd_bwd.push(op(
                K::ArrayGrad,
                OpU {
                    c: u32_(ar.c),
                    h: u32_(ar.h),
                    w: u32_(ar.w),
                    src: ar.feat,
                    dst: ar.grad,
                    aux: gx,
                    aux2: gq,
                    aux3: w0,
                    aux4: f0,
                    flags: if ar.top > 0 { UP } else { 0 } | if ar.level0.is_some() { HAS0 } else { 0 },
                    fscale: (1.0 / n as f64) as f32,
                    count: u32_(n),
                    ..Default::default()
                },
            ));
        }
        for g in &signals {
            for s in (0..pyramid::STAGES).rev() {
                let (h, w) = stages[s];
                let up = if s + 1 < pyramid::STAGES {
                    let (ch, cw) = stages[s + 1];
                    let (oy, ox) = (u32_(same_offset(h)), u32_(same_offset(w)));
                    OpU { aux: g.grads[s + 1], oh: u32_(ch), ow: u32_(cw), oy, ox, flags: UP, ..stage(s) }
                } else {
                    stage(s)
                };
                if s < g.first {
                    fwd_bwd.push(op(K::Lowpass2Adj, OpU { dst: g.grads[s], ..up }));
                    continue;
                }
                let ar = &arrays[g.array + s - g.first];
                fwd_bwd.push(op(K::RectifyAdj, OpU { src: ar.feat, src2: ar.grad, dst: gb5, ..stage(s) }));
                fwd_bwd.push(op(K::BasisAdjH, OpU { src: gb5, dst: t3, ..stage(s) }));
                fwd_bwd.push(op(K::BasisAdjV, OpU { src: t3, dst: g.grads[s], ..up }));
            }
            fwd_bwd.push(if g.index == 0 {
                op(K::InputAdj, OpU { src: arrays[0].grad, src2: g.grads[0], dst: gw, count: u32_(n0), ..Default::default() })
            } else {
                op(K::InputAdjSignal, OpU { c: u32_(g.index), src2: g.grads[0], dst: gw, count: u32_(n0), ..Default::default() })
            });
        }

        let wdr = if config.kind == LossKind::Wdr { WDR } else { 0 };
        let beta = BETA as f32;
        let n3 = u32_(3 * n0);
        let norms = op(K::Norms, OpU { src: gw, fscale: beta, count: n3, ..Default::default() });
        let normalise = if config.normalise() { NORMALISE } else { 0 };
        let scalars_op = OpU { flags: wdr | normalise, fscale: beta, count: 1, ..Default::default() };
        let scalars_u = gpu.uniform(&scalars_op);
        let scalars = Op {
            k: K::Scalars,
            bind: gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: None,
                layout: &kernels.layout1,
                entries: &[wgpu::BindGroupEntry { binding: 0, resource: scalars_u.as_entire_binding() }],
            }),
            groups: (1, 1),
        };
        let combine = op(K::Combine, OpU { src: gw, flags: wdr, fscale: beta, count: n3, ..Default::default() });

        let arena = gpu.storage("wd arena", arena_floats * 4);
        for (off, data) in &weights {
            gpu.queue.write_buffer(&arena, *off as u64 * 4, bytemuck::cast_slice(data));
        }
        let g0 = config.initial_gamma() as f32;
        let mut words = vec![0.0f32; ACC_WORDS + ACC_SUMS * ACC_STRIPES];
        words[3] = g0;
        let acc = gpu.storage_init("wd scalars", bytemuck::cast_slice(&words));
        gpu.check()?;
        Ok(WdStage {
            config,
            width,
            height,
            kernels,
            arena,
            acc,
            reference,
            forward_backward: fwd_bwd,
            norms,
            scalars,
            scalars_u,
            scalars_op,
            combine,
            ref_floats,
            arena_floats,
            cache: Vec::new(),
            scratch: None,
            cached_bytes: 0,
        })
    }

    /// GPU memory of the stage for `width × height` images at a uniform `sigma`: (working
    /// memory of the stage, reference statistics of one cached view), in bytes.
    pub fn memory(width: u32, height: u32, sigma: f64, colour: bool) -> (u64, u64) {
        let l = Layout::new(width, height, sigma, colour);
        (l.arena_floats * 4, l.ref_floats * 4)
    }

    /// Bytes of one view's cached reference statistics.
    pub fn reference_bytes(&self) -> u64 {
        self.ref_floats * 4
    }

    /// Bytes of the per-size working memory (features, moments, gradients, weights).
    pub fn arena_bytes(&self) -> u64 {
        self.arena_floats * 4
    }

    /// Number of views whose statistics are cached.
    pub fn cached_views(&self) -> usize {
        self.cache.iter().filter(|c| c.is_some()).count()
    }

    /// The current γ (reads one scalar back).
    pub fn gamma(&self, gpu: &Gpu) -> Result<f64> {
        Ok(gpu.read_f32(&self.acc, 4)?[3] as f64)
    }

    /// The reference buffer of `view`: cached while the budget allows, else the scratch buffer.
    /// Returns (buffer, whether it must be (re)computed now).
    fn reference_for(&mut self, gpu: &Gpu, view: usize) -> (wgpu::Buffer, bool) {
        let bytes = self.reference_bytes();
        if self.cache.len() <= view {
            self.cache.resize_with(view + 1, || None);
        }
        if self.cache[view].is_none() && self.cached_bytes + bytes <= self.config.cache_bytes {
            self.cached_bytes += bytes;
            self.cache[view] = Some(RefBuf { buf: gpu.storage("wd reference", bytes), filled: false });
        }
        match &mut self.cache[view] {
            Some(r) => {
                let fill = !r.filled;
                r.filled = true;
                (r.buf.clone(), fill)
            }
            // Over the budget: recomputed into the scratch buffer every time.
            None => (self.scratch.get_or_insert_with(|| gpu.storage("wd reference (scratch)", bytes)).clone(), true),
        }
    }

    /// Records the WD stage of one iteration after the L1+SSIM loss (whose gradient and value are
    /// in the session's `dl` and loss word): replaces them by the `wd` / `wdr` loss when `active`
    /// (after the warm-up), else does nothing. `view` is the training view's index, `target` its
    /// image. At most one call per queue submission (the loss word is a uniform written now).
    pub fn record(&mut self, s: &Session, enc: &mut wgpu::CommandEncoder, view: usize, target: &wgpu::Buffer, active: bool) -> Result<()> {
        if !active {
            return Ok(());
        }
        let gpu = s.gpu;
        let img = s.img.as_ref().ok_or_else(|| Error::Failure("WD stage before rasterizing".into()))?;
        if (img.width, img.height) != (self.width, self.height) {
            return Err(Error::Failure("WD stage of another image size".into()));
        }
        let su = OpU { c: s.loss_word(), ..self.scalars_op };
        gpu.queue.write_buffer(&self.scalars_u, 0, bytemuck::bytes_of(&su));
        let (refs, fill) = self.reference_for(gpu, view);
        let bind0 = |image: &wgpu::Buffer| {
            gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: None,
                layout: &self.kernels.layout0,
                entries: &[&self.arena, &refs, image, &img.dl, &self.acc, &s.ring]
                    .iter()
                    .enumerate()
                    .map(|(i, b)| wgpu::BindGroupEntry { binding: i as u32, resource: b.as_entire_binding() })
                    .collect::<Vec<_>>(),
            })
        };
        let bg_ref = fill.then(|| bind0(target));
        let bg = bind0(&img.image);
        enc.clear_buffer(&self.acc, 4 * ACC_WORDS as u64, Some(4 * (ACC_SUMS * ACC_STRIPES) as u64));
        s.wd_timed.set(true);
        let mut pass = s.timed_pass(enc, (Some(WD_TIMESTAMPS.0), Some(WD_TIMESTAMPS.1)));
        let run = |pass: &mut wgpu::ComputePass, o: &Op| {
            pass.set_pipeline(&self.kernels.pipes[o.k as usize]);
            pass.set_bind_group(1, &o.bind, &[]);
            pass.dispatch_workgroups(o.groups.0, o.groups.1, 1);
        };
        if let Some(b) = &bg_ref {
            pass.set_bind_group(0, b, &[]);
            self.reference.iter().for_each(|o| run(&mut pass, o));
        }
        pass.set_bind_group(0, &bg, &[]);
        self.forward_backward.iter().for_each(|o| run(&mut pass, o));
        if self.config.normalise() {
            run(&mut pass, &self.norms);
        }
        run(&mut pass, &self.scalars);
        run(&mut pass, &self.combine);
        Ok(())
    }
}
