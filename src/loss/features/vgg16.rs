//! `vgg16=PATH`: the paper's feature space, as in the WD reference (`codex`,
//! `pretrained_features.py`): the ImageNet-normalised image, then relu1_2, relu2_2, relu3_3,
//! relu4_3 and relu5_3 of VGG-16 (2×2 average pooling instead of max-pooling) at 3 image scales,
//! the normalised image low-passed and subsampled by 2 between scales: 1 + 3·5 = 16 arrays.
//!
//! Weights are frozen and read from a safetensors file with torchvision's key names
//! (`features.N.weight` `[out, in, 3, 3]`, `features.N.bias` `[out]`, f32), which
//! `scripts/export_vgg16.py` writes. Any channel widths are accepted as long as the 13 layers
//! chain (the tests use narrow random networks); the real file has 64…512 channels.
//!
//! Convolutions are im2col + GEMM (`matrixmultiply`) over column blocks in parallel (rayon).
//! Pooling floors odd sizes like the reference; an array whose side would reach 0 on a tiny
//! image is left out (for the reference and the rendered image alike).

use std::path::Path;
use std::sync::Arc;

use rayon::prelude::*;

use super::{normalize, normalize_adjoint, Backward, Extracted, FeatureSpace};
use crate::loss::tensor::{Real, Tensor};
use crate::{Error, Result};

/// torchvision `features.N` indices of the 13 convolutions.
pub const CONV_INDICES: [usize; 13] = [0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28];
/// Convolutions per block; each block's last ReLU is a feature tap (relu1_2 … relu5_3).
pub const BLOCKS: [usize; 5] = [2, 2, 3, 3, 3];
/// Output channels of the real VGG-16 per convolution.
pub const VGG16_CHANNELS: [usize; 13] = [64, 64, 128, 128, 256, 256, 256, 512, 512, 512, 512, 512, 512];
/// Image scales the network runs on.
pub const SCALES: usize = 3;
/// Pixels per GEMM column block.
const BLOCK_COLS: usize = 1024;

/// A 3×3 convolution (padding 1) followed by ReLU.
#[derive(Clone, Debug)]
struct Conv<T> {
    cin: usize,
    cout: usize,
    /// `[cout, cin·9]`, row-major.
    weight: Vec<T>,
    bias: Vec<T>,
}

/// Frozen VGG-16 convolution stack.
#[derive(Clone, Debug)]
pub struct Vgg16<T> {
    /// Shared so a backward tape can hold the network without borrowing it.
    convs: Arc<Vec<Conv<T>>>,
}

impl<T: Real> Vgg16<T> {
    /// Reads the weights from a safetensors file.
    ///
    /// # Errors
    /// [`Error::input`] naming `path` when it cannot be read, is not safetensors, or lacks a
    /// layer / has inconsistent shapes.
    pub fn load(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|e| Error::input(path, format!("cannot read VGG-16 weights: {e}")))?;
        Self::from_safetensors(&bytes).map_err(|msg| Error::input(path, msg))
    }

    /// Parses safetensors bytes (see the module docs for the expected keys).
    pub fn from_safetensors(bytes: &[u8]) -> std::result::Result<Self, String> {
        let st = safetensors::SafeTensors::deserialize(bytes).map_err(|e| format!("not a safetensors file: {e}"))?;
        let read = |name: &str, shape_len: usize| -> std::result::Result<(Vec<usize>, Vec<T>), String> {
            let t = st.tensor(name).map_err(|_| format!("missing tensor `{name}` (expected torchvision VGG-16 keys)"))?;
            if t.dtype() != safetensors::Dtype::F32 {
                return Err(format!("tensor `{name}` is {:?}, expected F32", t.dtype()));
            }
            if t.shape().len() != shape_len {
                return Err(format!("tensor `{name}` has shape {:?}", t.shape()));
            }
            let vals = t.data().chunks_exact(4).map(|b| T::c(f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64)).collect::<Vec<T>>();
            if vals.iter().any(|v| !v.is_finite()) {
                return Err(format!("tensor `{name}` holds NaN or infinite values"));
            }
            Ok((t.shape().to_vec(), vals))
        };
        let mut convs = Vec::with_capacity(13);
        let mut cin = 3;
        for idx in CONV_INDICES {
            let (ws, weight) = read(&format!("features.{idx}.weight"), 4)?;
            let (bs, bias) = read(&format!("features.{idx}.bias"), 1)?;
            if ws[1] != cin || ws[2] != 3 || ws[3] != 3 || bs[0] != ws[0] || ws[0] == 0 {
                return Err(format!(
                    "layer features.{idx}: weight {ws:?} / bias {bs:?} do not continue a {cin}-channel input with 3x3 kernels"
                ));
            }
            convs.push(Conv { cin, cout: ws[0], weight, bias });
            cin = ws[0];
        }
        Ok(Vgg16 { convs: Arc::new(convs) })
    }

    /// A network of VGG-16 topology with the given output widths and He-initialised random
    /// weights (deterministic in `seed`): for tests and benchmarks, never for real use.
    pub fn random(widths: &[usize; 13], seed: u64) -> Self {
        let mut rng = crate::rng::Rng::new(seed);
        let mut uniform = move || 2.0 * rng.uniform_f64() - 1.0;
        let mut cin = 3;
        let convs = widths
            .iter()
            .map(|&cout| {
                // uniform on [−a, a] with variance 2 / fan-in
                let a = (6.0 / (cin * 9) as f64).sqrt();
                let weight = (0..cout * cin * 9).map(|_| T::c(a * uniform())).collect();
                let bias = (0..cout).map(|_| T::c(0.05 * uniform())).collect();
                let c = Conv { cin, cout, weight, bias };
                cin = cout;
                c
            })
            .collect();
        Vgg16 { convs: Arc::new(convs) }
    }

    /// Whether the channel widths are those of the real VGG-16.
    pub fn is_full_size(&self) -> bool {
        self.convs.iter().map(|c| c.cout).eq(VGG16_CHANNELS)
    }
}

/// im2col of rows-major pixel block `[p0, p1)` of a `c × h × w` input: `[c·9, p1 − p0]`.
fn im2col<T: Real>(x: &Tensor<T>, p0: usize, p1: usize, cols: &mut [T]) {
    let (h, w, n) = (x.h as isize, x.w as isize, p1 - p0);
    for c in 0..x.c {
        let plane = x.plane(c);
        for k in 0..9 {
            let (dy, dx) = ((k / 3) as isize - 1, (k % 3) as isize - 1);
            let row = &mut cols[(c * 9 + k) * n..(c * 9 + k + 1) * n];
            for (j, p) in (p0..p1).enumerate() {
                let (y, xx) = ((p as isize / w) + dy, (p as isize % w) + dx);
                row[j] = if y >= 0 && y < h && xx >= 0 && xx < w { plane[(y * w + xx) as usize] } else { T::zero() };
            }
        }
    }
}

/// Convolution + bias + ReLU.
fn conv_forward<T: Real>(conv: &Conv<T>, x: &Tensor<T>) -> Tensor<T> {
    let (h, w) = (x.h, x.w);
    let np = h * w;
    let mut out = Tensor::zeros(conv.cout, h, w);
    let k = conv.cin * 9;
    let blocks: Vec<(usize, usize)> = (0..np).step_by(BLOCK_COLS).map(|p| (p, (p + BLOCK_COLS).min(np))).collect();
    let results: Vec<Vec<T>> = blocks
        .par_iter()
        .map(|&(p0, p1)| {
            let n = p1 - p0;
            let mut cols = vec![T::zero(); k * n];
            im2col(x, p0, p1, &mut cols);
            let mut o = vec![T::zero(); conv.cout * n];
            // SAFETY: all three matrices are dense row-major views of the vectors above.
            unsafe {
                T::gemm(
                    conv.cout,
                    k,
                    n,
                    conv.weight.as_ptr(),
                    (k as isize, 1),
                    cols.as_ptr(),
                    (n as isize, 1),
                    false,
                    o.as_mut_ptr(),
                    (n as isize, 1),
                );
            }
            o
        })
        .collect();
    for (&(p0, p1), o) in blocks.iter().zip(results) {
        let n = p1 - p0;
        for co in 0..conv.cout {
            let b = conv.bias[co];
            let dst = &mut out.data[co * np + p0..co * np + p1];
            for (d, &v) in dst.iter_mut().zip(&o[co * n..(co + 1) * n]) {
                *d = (v + b).max(T::zero());
            }
        }
    }
    out
}

/// Gradient w.r.t. a convolution's input, given its ReLU output `y` and `dL/dy`.
fn conv_backward<T: Real>(conv: &Conv<T>, y: &Tensor<T>, gy: &Tensor<T>) -> Tensor<T> {
    let (h, w) = (y.h, y.w);
    let np = h * w;
    let k = conv.cin * 9;
    // dL/d(pre-activation), channel-major.
    let gpre: Vec<T> = gy.data.iter().zip(&y.data).map(|(&g, &v)| if v > T::zero() { g } else { T::zero() }).collect();
    let blocks: Vec<(usize, usize)> = (0..np).step_by(BLOCK_COLS).map(|p| (p, (p + BLOCK_COLS).min(np))).collect();
    let parts: Vec<Vec<T>> = blocks
        .par_iter()
        .map(|&(p0, p1)| {
            let n = p1 - p0;
            let mut gcols = vec![T::zero(); k * n];
            // gcols[k×n] = Wᵀ[k×cout] · gpre[cout × (p0..p1)] (row stride np).
            unsafe {
                T::gemm(
                    k,
                    conv.cout,
                    n,
                    conv.weight.as_ptr(),
                    (1, k as isize),
                    gpre.as_ptr().add(p0),
                    (np as isize, 1),
                    false,
                    gcols.as_mut_ptr(),
                    (n as isize, 1),
                );
            }
            gcols
        })
        .collect();
    // col2im: scatter every column block back onto the input planes (channels in parallel).
    let mut gx = Tensor::zeros(conv.cin, h, w);
    gx.data.par_chunks_mut(np.max(1)).enumerate().for_each(|(c, plane)| {
        for (&(p0, p1), gcols) in blocks.iter().zip(&parts) {
            let n = p1 - p0;
            for kk in 0..9 {
                let (dy, dx) = ((kk / 3) as isize - 1, (kk % 3) as isize - 1);
                let row = &gcols[(c * 9 + kk) * n..(c * 9 + kk + 1) * n];
                for (j, p) in (p0..p1).enumerate() {
                    let (yy, xx) = ((p / w) as isize + dy, (p % w) as isize + dx);
                    if yy >= 0 && yy < h as isize && xx >= 0 && xx < w as isize {
                        let q = yy as usize * w + xx as usize;
                        plane[q] = plane[q] + row[j];
                    }
                }
            }
        }
    });
    gx
}

fn avg_pool<T: Real>(x: &Tensor<T>) -> Tensor<T> {
    let (h2, w2) = (x.h / 2, x.w / 2);
    let q = T::c(0.25);
    x.map_planes(h2, w2, |p, o| {
        for y in 0..h2 {
            for i in 0..w2 {
                let a = |yy: usize, xx: usize| p[yy * x.w + xx];
                o[y * w2 + i] = q * (a(2 * y, 2 * i) + a(2 * y, 2 * i + 1) + a(2 * y + 1, 2 * i) + a(2 * y + 1, 2 * i + 1));
            }
        }
    })
}

fn avg_pool_adjoint<T: Real>(g: &Tensor<T>, h: usize, w: usize) -> Tensor<T> {
    let q = T::c(0.25);
    g.map_planes(h, w, |gp, o| {
        for y in 0..g.h {
            for i in 0..g.w {
                let v = q * gp[y * g.w + i];
                for (dy, dx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                    o[(2 * y + dy) * w + 2 * i + dx] = v;
                }
            }
        }
    })
}

/// Saved activations of one network pass.
struct Pass<T> {
    input_shape: (usize, usize),
    /// ReLU outputs of every convolution that ran.
    acts: Vec<Tensor<T>>,
    /// Number of feature taps produced (≤ 5).
    taps: usize,
}

impl<T: Real> Vgg16<T> {
    fn run(&self, x: &Tensor<T>) -> (Vec<Tensor<T>>, Pass<T>) {
        let mut acts: Vec<Tensor<T>> = Vec::with_capacity(13);
        let mut taps = Vec::with_capacity(5);
        let mut cur = x.clone();
        let mut li = 0;
        for (b, &nconv) in BLOCKS.iter().enumerate() {
            if b > 0 {
                cur = avg_pool(&cur);
            }
            if cur.h == 0 || cur.w == 0 {
                break;
            }
            for _ in 0..nconv {
                cur = conv_forward(&self.convs[li], &cur);
                acts.push(cur.clone());
                li += 1;
            }
            taps.push(cur.clone());
        }
        let n = taps.len();
        (taps, Pass { input_shape: (x.h, x.w), acts, taps: n })
    }

    fn run_backward(&self, pass: &Pass<T>, grads: &[Tensor<T>]) -> Tensor<T> {
        let mut li = pass.acts.len();
        let mut g: Option<Tensor<T>> = None;
        for b in (0..pass.taps).rev() {
            let top = &pass.acts[li - 1];
            let mut gb = match g.take() {
                Some(gnext) => avg_pool_adjoint(&gnext, top.h, top.w),
                None => Tensor::zeros(top.c, top.h, top.w),
            };
            gb.add_assign(&grads[b]);
            for _ in 0..BLOCKS[b] {
                li -= 1;
                gb = conv_backward(&self.convs[li], &pass.acts[li], &gb);
            }
            g = Some(gb);
        }
        match g {
            Some(g) => g,
            None => Tensor::zeros(3, pass.input_shape.0, pass.input_shape.1),
        }
    }
}

struct Tape<T> {
    net: Vgg16<T>,
    scale_shapes: Vec<(usize, usize)>,
    passes: Vec<Pass<T>>,
}

impl<T: Real> Backward<T> for Tape<T> {
    fn backward(self: Box<Self>, grads: &[Tensor<T>]) -> Tensor<T> {
        let t = *self;
        // grads[0]: normalised image; then the taps of each scale in order.
        let mut offset = 1;
        let mut per_scale = Vec::with_capacity(t.passes.len());
        for p in &t.passes {
            per_scale.push(&grads[offset..offset + p.taps]);
            offset += p.taps;
        }
        let mut g: Option<Tensor<T>> = None;
        for s in (0..t.passes.len()).rev() {
            let (h, w) = t.scale_shapes[s];
            let mut gs = t.net.run_backward(&t.passes[s], per_scale[s]);
            if let Some(gnext) = g.take() {
                gs.add_assign(&gnext.lowpass2_adjoint(h, w));
            }
            g = Some(gs);
        }
        let mut grad = g.expect("at least one scale");
        grad.add_assign(&grads[0]);
        normalize_adjoint(&mut grad);
        grad
    }
}

impl<T: Real> FeatureSpace<T> for Vgg16<T> {
    fn name(&self) -> &'static str {
        "vgg16"
    }

    fn extract(&self, image: &Tensor<T>) -> Extracted<T> {
        let norm = normalize(image);
        let mut arrays = vec![norm.clone()];
        let mut cur = norm;
        let mut passes = Vec::with_capacity(SCALES);
        let mut scale_shapes = Vec::with_capacity(SCALES);
        for s in 0..SCALES {
            if s > 0 {
                cur = cur.lowpass2();
            }
            scale_shapes.push((cur.h, cur.w));
            let (taps, pass) = self.run(&cur);
            arrays.extend(taps);
            passes.push(pass);
        }
        Extracted { arrays, tape: Box::new(Tape { net: self.clone(), scale_shapes, passes }) }
    }
}
