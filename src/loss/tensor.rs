//! A small channel-major tensor (C × H × W) and the fixed low-pass operators WD and the feature
//! spaces share, each with its adjoint for the backward pass.
//!
//! Everything is generic over [`Real`] so the same code runs in `f32` (training) and `f64`
//! (finite-difference gradient checks).

use gscodec_decoder::Image;
use rayon::prelude::*;

/// Floating-point scalar the WD code runs in (`f32` or `f64`).
pub trait Real: num_traits::Float + num_traits::FromPrimitive + Default + Send + Sync + std::fmt::Debug + std::iter::Sum + 'static {
    /// Converts an `f64` constant.
    fn c(x: f64) -> Self;
    /// Converts to `f64`.
    fn f64(self) -> f64;
    /// `C[m×n] = A[m×k] · B[k×n]` (+ `C` when `accumulate`), all given as strided views
    /// (`(row stride, column stride)` per matrix).
    ///
    /// # Safety
    /// The strided views must lie inside the slices they point into.
    #[allow(clippy::too_many_arguments)]
    unsafe fn gemm(
        m: usize,
        k: usize,
        n: usize,
        a: *const Self,
        sa: (isize, isize),
        b: *const Self,
        sb: (isize, isize),
        accumulate: bool,
        c: *mut Self,
        sc: (isize, isize),
    );
}

impl Real for f32 {
    fn c(x: f64) -> Self {
        x as f32
    }
    fn f64(self) -> f64 {
        self as f64
    }
    unsafe fn gemm(
        m: usize,
        k: usize,
        n: usize,
        a: *const f32,
        (rsa, csa): (isize, isize),
        b: *const f32,
        (rsb, csb): (isize, isize),
        accumulate: bool,
        c: *mut f32,
        (rsc, csc): (isize, isize),
    ) {
        let beta = if accumulate { 1.0 } else { 0.0 };
        matrixmultiply::sgemm(m, k, n, 1.0, a, rsa, csa, b, rsb, csb, beta, c, rsc, csc);
    }
}

impl Real for f64 {
    fn c(x: f64) -> Self {
        x
    }
    fn f64(self) -> f64 {
        self
    }
    unsafe fn gemm(
        m: usize,
        k: usize,
        n: usize,
        a: *const f64,
        (rsa, csa): (isize, isize),
        b: *const f64,
        (rsb, csb): (isize, isize),
        accumulate: bool,
        c: *mut f64,
        (rsc, csc): (isize, isize),
    ) {
        let beta = if accumulate { 1.0 } else { 0.0 };
        matrixmultiply::dgemm(m, k, n, 1.0, a, rsa, csa, b, rsb, csb, beta, c, rsc, csc);
    }
}

/// A channel-major array: `data[(c * h + y) * w + x]`.
#[derive(Clone, Debug, PartialEq)]
pub struct Tensor<T> {
    pub c: usize,
    pub h: usize,
    pub w: usize,
    pub data: Vec<T>,
}

impl<T: Real> Tensor<T> {
    pub fn zeros(c: usize, h: usize, w: usize) -> Self {
        Tensor { c, h, w, data: vec![T::zero(); c * h * w] }
    }

    pub fn from_vec(c: usize, h: usize, w: usize, data: Vec<T>) -> Self {
        assert_eq!(data.len(), c * h * w, "tensor data length does not match its shape");
        Tensor { c, h, w, data }
    }

    /// The image's RGB channels as a 3 × H × W tensor.
    pub fn from_image(img: &Image) -> Self {
        let (w, h) = (img.width as usize, img.height as usize);
        let mut data = vec![T::zero(); 3 * h * w];
        for (i, px) in img.data.chunks_exact(3).enumerate() {
            for c in 0..3 {
                data[c * h * w + i] = T::c(px[c] as f64);
            }
        }
        Tensor { c: 3, h, w, data }
    }

    /// Interleaved RGB `f32` values of a 3-channel tensor (the image-gradient layout).
    pub fn to_interleaved_f32(&self) -> Vec<f32> {
        assert_eq!(self.c, 3);
        let n = self.h * self.w;
        let mut out = vec![0.0f32; 3 * n];
        for i in 0..n {
            for c in 0..3 {
                out[3 * i + c] = self.data[c * n + i].f64() as f32;
            }
        }
        out
    }

    pub fn plane_len(&self) -> usize {
        self.h * self.w
    }

    pub fn plane(&self, c: usize) -> &[T] {
        let n = self.plane_len();
        &self.data[c * n..(c + 1) * n]
    }

    pub fn same_shape(&self, other: &Self) -> bool {
        (self.c, self.h, self.w) == (other.c, other.h, other.w)
    }

    /// Applies `f` plane by plane (in parallel), producing a tensor of planes `oh × ow`.
    pub fn map_planes(&self, oh: usize, ow: usize, f: impl Fn(&[T], &mut [T]) + Sync) -> Self {
        let mut out = Tensor::zeros(self.c, oh, ow);
        let n = self.plane_len();
        if oh * ow > 0 && n > 0 {
            out.data.par_chunks_mut(oh * ow).zip(self.data.par_chunks(n)).for_each(|(o, x)| f(x, o));
        }
        out
    }

    /// 3×3 binomial low-pass, stride 1, zero padding (self-adjoint).
    pub fn blur(&self) -> Self {
        self.map_planes(self.h, self.w, |x, o| blur_into(x, self.h, self.w, o))
    }

    /// Every second sample from `(oy, ox)` on (see [`subsample_into`]).
    pub fn subsample(&self, oy: usize, ox: usize) -> Self {
        let (h2, w2) = (half(self.h), half(self.w));
        self.map_planes(h2, w2, |x, o| subsample_into(x, self.h, self.w, oy, ox, o))
    }

    /// Adjoint of [`Tensor::subsample`]: scatter into an `h × w` grid of zeros.
    pub fn subsample_adjoint(&self, h: usize, w: usize, oy: usize, ox: usize) -> Self {
        self.map_planes(h, w, |g, o| subsample_adjoint_into(g, self.w, oy, ox, w, o))
    }

    /// `blur().subsample(0, 0)` computed only at the kept samples (¼ of the work).
    pub fn blur_subsample(&self) -> Self {
        let (h2, w2) = (half(self.h), half(self.w));
        self.map_planes(h2, w2, |x, o| blur_subsample_into(x, self.h, self.w, o))
    }

    /// Adjoint of [`Tensor::blur_subsample`] back to an `h × w` grid.
    pub fn blur_subsample_adjoint(&self, h: usize, w: usize) -> Self {
        self.map_planes(h, w, |g, o| blur_subsample_adjoint_into(g, self.h, self.w, h, w, o))
    }

    /// Stride-2 low-pass with XLA "SAME" padding, as the reference's `lowpass(x, stride=2)`:
    /// output size ⌈n/2⌉, centred on odd samples when n is even and on even ones when n is odd.
    pub fn lowpass2(&self) -> Self {
        self.blur().subsample(same_offset(self.h), same_offset(self.w))
    }

    /// Adjoint of [`Tensor::lowpass2`] back to an `h × w` grid.
    pub fn lowpass2_adjoint(&self, h: usize, w: usize) -> Self {
        self.subsample_adjoint(h, w, same_offset(h), same_offset(w)).blur()
    }

    pub fn add_assign(&mut self, other: &Self) {
        assert!(self.same_shape(other), "adding tensors of different shapes");
        self.data.iter_mut().zip(&other.data).for_each(|(a, b)| *a = *a + *b);
    }
}

/// ⌈n/2⌉.
pub fn half(n: usize) -> usize {
    n.div_ceil(2)
}

/// First sampled index of a stride-2 "SAME" convolution over `n` samples with a 3-tap kernel.
pub fn same_offset(n: usize) -> usize {
    if n % 2 == 0 {
        1
    } else {
        0
    }
}

/// `out = K * x` for one `h × w` plane, K = [¼,½,¼]⊗[¼,½,¼], zero padding.
pub fn blur_into<T: Real>(x: &[T], h: usize, w: usize, out: &mut [T]) {
    let (q, hf) = (T::c(0.25), T::c(0.5));
    let mut tmp = vec![T::zero(); h * w];
    for y in 0..h {
        let row = &x[y * w..(y + 1) * w];
        let t = &mut tmp[y * w..(y + 1) * w];
        for i in 0..w {
            let l = if i > 0 { row[i - 1] } else { T::zero() };
            let r = if i + 1 < w { row[i + 1] } else { T::zero() };
            t[i] = hf * row[i] + q * (l + r);
        }
    }
    for y in 0..h {
        let o = &mut out[y * w..(y + 1) * w];
        let mid = &tmp[y * w..(y + 1) * w];
        for i in 0..w {
            let up = if y > 0 { tmp[(y - 1) * w + i] } else { T::zero() };
            let dn = if y + 1 < h { tmp[(y + 1) * w + i] } else { T::zero() };
            o[i] = hf * mid[i] + q * (up + dn);
        }
    }
}

/// Samples `x[oy + 2j][ox + 2i]` into a `⌈h/2⌉ × ⌈w/2⌉` plane (indices past the edge read 0,
/// which only happens for an offset of 1 on an odd size, never used by the callers).
pub fn subsample_into<T: Real>(x: &[T], h: usize, w: usize, oy: usize, ox: usize, out: &mut [T]) {
    let (h2, w2) = (half(h), half(w));
    for j in 0..h2 {
        for i in 0..w2 {
            let (y, xx) = (oy + 2 * j, ox + 2 * i);
            out[j * w2 + i] = if y < h && xx < w { x[y * w + xx] } else { T::zero() };
        }
    }
}

fn subsample_adjoint_into<T: Real>(g: &[T], w2: usize, oy: usize, ox: usize, w: usize, out: &mut [T]) {
    let h = out.len() / w.max(1);
    for (j, row) in g.chunks_exact(w2.max(1)).enumerate() {
        for (i, v) in row.iter().enumerate() {
            let (y, xx) = (oy + 2 * j, ox + 2 * i);
            if y < h && xx < w {
                out[y * w + xx] = *v;
            }
        }
    }
}

/// `K * x` sampled at even rows and columns (zero padding).
fn blur_subsample_into<T: Real>(x: &[T], h: usize, w: usize, out: &mut [T]) {
    let (h2, w2) = (half(h), half(w));
    let (q, hf) = (T::c(0.25), T::c(0.5));
    // horizontal pass at even columns for every row, then vertical at even rows
    let mut tmp = vec![T::zero(); h * w2];
    for y in 0..h {
        let row = &x[y * w..(y + 1) * w];
        for i in 0..w2 {
            let c = 2 * i;
            let l = if c > 0 { row[c - 1] } else { T::zero() };
            let r = if c + 1 < w { row[c + 1] } else { T::zero() };
            tmp[y * w2 + i] = hf * row[c] + q * (l + r);
        }
    }
    for j in 0..h2 {
        let y = 2 * j;
        for i in 0..w2 {
            let up = if y > 0 { tmp[(y - 1) * w2 + i] } else { T::zero() };
            let dn = if y + 1 < h { tmp[(y + 1) * w2 + i] } else { T::zero() };
            out[j * w2 + i] = hf * tmp[y * w2 + i] + q * (up + dn);
        }
    }
}

/// Adjoint of [`blur_subsample_into`]: fine sample y gets ½·g[y/2] when even, else
/// ¼·(g[(y−1)/2] + g[(y+1)/2]), separably in both directions.
fn blur_subsample_adjoint_into<T: Real>(g: &[T], h2: usize, w2: usize, h: usize, w: usize, out: &mut [T]) {
    let (q, hf) = (T::c(0.25), T::c(0.5));
    let spread = |src: &dyn Fn(usize) -> T, n2: usize, y: usize| -> T {
        if y % 2 == 0 {
            hf * src(y / 2)
        } else {
            let a = src((y - 1) / 2);
            let b = if y.div_ceil(2) < n2 { src(y.div_ceil(2)) } else { T::zero() };
            q * (a + b)
        }
    };
    let mut tmp = vec![T::zero(); h * w2];
    for y in 0..h {
        for i in 0..w2 {
            tmp[y * w2 + i] = spread(&|j| g[j * w2 + i], h2, y);
        }
    }
    for y in 0..h {
        let row = &tmp[y * w2..(y + 1) * w2];
        for x in 0..w {
            out[y * w + x] = spread(&|i| row[i], w2, x);
        }
    }
}
