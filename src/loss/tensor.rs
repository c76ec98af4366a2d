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
    let mut tmp = vec![T::zero(); h * w];
    for (row, t) in x.chunks_exact(w.max(1)).zip(tmp.chunks_exact_mut(w.max(1))) {
        blur_row(row, t);
    }
    blur_columns(&tmp, h, w, out);
}

/// The horizontal [¼,½,¼] pass of one row (zero padding): `t[i] = ½·row[i] + ¼·(row[i−1] +
/// row[i+1])`, the missing neighbour of an edge sample read as 0.
fn blur_row<T: Real>(row: &[T], t: &mut [T]) {
    let (q, hf) = (T::c(0.25), T::c(0.5));
    let w = row.len();
    if w == 0 {
        return;
    }
    if w == 1 {
        t[0] = hf * row[0] + q * (T::zero() + T::zero());
        return;
    }
    t[0] = hf * row[0] + q * (T::zero() + row[1]);
    // Interior: no branches, so the loop vectorises.
    for ((o, c), (l, r)) in t[1..w - 1].iter_mut().zip(&row[1..w - 1]).zip(row[..w - 2].iter().zip(&row[2..])) {
        *o = hf * *c + q * (*l + *r);
    }
    t[w - 1] = hf * row[w - 1] + q * (row[w - 2] + T::zero());
}

/// The vertical [¼,½,¼] pass over whole rows (zero padding), `tmp` → `out` (both `h × w`).
fn blur_columns<T: Real>(tmp: &[T], h: usize, w: usize, out: &mut [T]) {
    let row = |y: usize| &tmp[y * w..(y + 1) * w];
    for (y, o) in out.chunks_exact_mut(w.max(1)).take(h).enumerate() {
        blend_rows(o, row(y), (y > 0).then(|| row(y - 1)), (y + 1 < h).then(|| row(y + 1)));
    }
}

/// `o = ½·mid + ¼·(up + dn)` element by element, a missing neighbour row read as zeros (the
/// vertical tap of the [¼,½,¼] blur, written so that each case's loop vectorises).
fn blend_rows<T: Real>(o: &mut [T], mid: &[T], up: Option<&[T]>, dn: Option<&[T]>) {
    let (q, hf, zero) = (T::c(0.25), T::c(0.5), T::zero());
    match (up, dn) {
        (Some(up), Some(dn)) => {
            for (((o, m), u), d) in o.iter_mut().zip(mid).zip(up).zip(dn) {
                *o = hf * *m + q * (*u + *d);
            }
        }
        (None, Some(dn)) => {
            for ((o, m), d) in o.iter_mut().zip(mid).zip(dn) {
                *o = hf * *m + q * (zero + *d);
            }
        }
        (Some(up), None) => {
            for ((o, m), u) in o.iter_mut().zip(mid).zip(up) {
                *o = hf * *m + q * (*u + zero);
            }
        }
        (None, None) => {
            for (o, m) in o.iter_mut().zip(mid) {
                *o = hf * *m + q * (zero + zero);
            }
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

pub fn subsample_adjoint_into<T: Real>(g: &[T], w2: usize, oy: usize, ox: usize, w: usize, out: &mut [T]) {
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
pub fn blur_subsample_into<T: Real>(x: &[T], h: usize, w: usize, out: &mut [T]) {
    let (h2, w2) = (half(h), half(w));
    let (q, hf, zero) = (T::c(0.25), T::c(0.5), T::zero());
    // horizontal pass at even columns for every row, then vertical at even rows
    let mut tmp = vec![T::zero(); h * w2];
    for (row, t) in x.chunks_exact(w.max(1)).zip(tmp.chunks_exact_mut(w2.max(1))).take(h) {
        for (i, o) in t.iter_mut().enumerate() {
            let c = 2 * i;
            let l = if c > 0 { row[c - 1] } else { zero };
            let r = if c + 1 < w { row[c + 1] } else { zero };
            *o = hf * row[c] + q * (l + r);
        }
    }
    let row = |y: usize| &tmp[y * w2..(y + 1) * w2];
    for (j, o) in out.chunks_exact_mut(w2.max(1)).take(h2).enumerate() {
        let y = 2 * j;
        blend_rows(o, row(y), (y > 0).then(|| row(y - 1)), (y + 1 < h).then(|| row(y + 1)));
    }
}

/// Adjoint of [`blur_subsample_into`]: fine sample y gets ½·g[y/2] when even, else
/// ¼·(g[(y−1)/2] + g[(y+1)/2]) (the second read as 0 past the end), separably in both directions.
pub fn blur_subsample_adjoint_into<T: Real>(g: &[T], h2: usize, w2: usize, h: usize, w: usize, out: &mut [T]) {
    let (q, hf, zero) = (T::c(0.25), T::c(0.5), T::zero());
    let mut tmp = vec![T::zero(); h * w2];
    let coarse = |j: usize| &g[j * w2..(j + 1) * w2];
    for (y, t) in tmp.chunks_exact_mut(w2.max(1)).take(h).enumerate() {
        if y % 2 == 0 {
            for (t, a) in t.iter_mut().zip(coarse(y / 2)) {
                *t = hf * *a;
            }
        } else if y.div_ceil(2) < h2 {
            for ((t, a), b) in t.iter_mut().zip(coarse((y - 1) / 2)).zip(coarse(y.div_ceil(2))) {
                *t = q * (*a + *b);
            }
        } else {
            for (t, a) in t.iter_mut().zip(coarse((y - 1) / 2)) {
                *t = q * (*a + zero);
            }
        }
    }
    for (row, o) in tmp.chunks_exact(w2.max(1)).zip(out.chunks_exact_mut(w.max(1))).take(h) {
        for (x, o) in o.iter_mut().enumerate() {
            *o = if x % 2 == 0 {
                hf * row[x / 2]
            } else {
                let b = if x.div_ceil(2) < w2 { row[x.div_ceil(2)] } else { zero };
                q * (row[(x - 1) / 2] + b)
            };
        }
    }
}
