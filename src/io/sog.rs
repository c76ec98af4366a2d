//! PlayCanvas SOG v2 ("Spatially Ordered Gaussians"): read and write, bundled (`.sog`, a zip
//! archive) or unbundled (a folder holding `meta.json` and the WebP images it names).
//!
//! Layout, per PlayCanvas's format page and splat-transform's reader/writer (facts, not code):
//!
//! * Every per-Gaussian image is `W × H` RGBA, Gaussian `i` at pixel `(i % W, i / W)`, row-major;
//!   `W = ⌈√n / 4⌉·4`, `H = ⌈n / W / 4⌉·4`, `count ≤ W·H` (trailing pixels ignored). Gaussians are
//!   written in Morton order of their positions. Images are lossless WebP.
//! * `means_l` / `means_u`: the low / high byte of a 16-bit value per axis, a lerp between
//!   `means.mins` and `means.maxs` of the log-transformed positions `sign(x)·ln(|x|+1)`.
//! * `quats`: smallest three of the normalised `(w, x, y, z)`: the largest component is made
//!   positive, the other three (in `w, x, y, z` order) are multiplied by √2 and stored as
//!   `255·(v/2 + ½)`; alpha is `252 + index of the largest`.
//! * `scales` (log-scales) and `sh0` (DC coefficients) index one 256-entry codebook each, shared by
//!   the three channels; `sh0`'s alpha is `255·sigmoid(opacity)`.
//! * `shN` (SH degree ≥ 1): `shN_labels` holds a 16-bit palette index (R low byte, G high byte);
//!   `shN_centroids` is `64·K` texels wide, centroid `c` at row `c / 64`, columns
//!   `(c % 64)·K + k` for coefficient `k`, RGB = channel indices into `shN.codebook`. A label
//!   `≥ shN.count` means "no view-dependent colour".
//!
//! Coordinates are the `.ply`'s, unchanged (splat-transform stores SOG in "PLY space" too).
//!
//! Precision of our writer: positions to 1/65535 of the log-transformed extent per axis,
//! quaternion components to `1/(255·√2)`, opacity to 1/255; scales, DC colour and SH to the
//! nearest of 256 codebook values (1-D k-means over the scene's values); SH vectors are
//! additionally clustered into a palette of at most `min(64, 2^⌊log2(n/1024)⌋)·1024` entries
//! (the reference writer's size rule), which is the format's main loss.

use crate::io::atomic::{write_bytes_atomic, write_dir_atomic};
use crate::io::spz::alpha_to_logit;
use crate::{Error, Result};
use gscodec_decoder::bitstream::positions::morton_encode;
use gscodec_decoder::math::{normalize_quat, sh_rest_coeffs, sigmoid};
use gscodec_decoder::Splats;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::io::{Read, Write};
use std::path::{Component, Path};

/// Entries of the scale / colour / SH codebooks (one byte indexes them).
pub const CODEBOOK_SIZE: usize = 256;
/// Palette centroids per row of `shN_centroids.webp`.
const CENTROIDS_PER_ROW: usize = 64;
/// Largest side of a WebP image.
const MAX_WEBP_SIDE: usize = 16383;
/// Largest zip entry we inflate (a guard against zip bombs).
const MAX_ENTRY_BYTES: u64 = 1 << 30;
/// Lloyd iterations refining the SH palette are skipped when one would cost more than this many
/// multiply-adds (large scenes keep the variance-split palette).
const PALETTE_REFINE_BUDGET: f64 = 4e9;

#[derive(Debug, Serialize, Deserialize)]
struct Meta {
    version: u32,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    asset: Option<serde_json::Value>,
    count: usize,
    means: Means,
    scales: Codebooked,
    quats: Files,
    sh0: Codebooked,
    #[serde(rename = "shN", default, skip_serializing_if = "Option::is_none")]
    sh_n: Option<ShN>,
}

#[derive(Debug, Serialize, Deserialize)]
struct Means {
    mins: Vec<f64>,
    maxs: Vec<f64>,
    files: Vec<String>,
}

#[derive(Debug, Serialize, Deserialize)]
struct Codebooked {
    codebook: Vec<f32>,
    files: Vec<String>,
}

#[derive(Debug, Serialize, Deserialize)]
struct Files {
    files: Vec<String>,
}

#[derive(Debug, Serialize, Deserialize)]
struct ShN {
    count: usize,
    bands: u8,
    codebook: Vec<f32>,
    files: Vec<String>,
}

/// Where a SOG scene's files come from: a name in `meta.json` to the file's bytes.
type Loader<'a> = dyn FnMut(&str) -> Result<Vec<u8>, String> + 'a;

/// True when `path` names an unbundled SOG scene (a file called `meta.json`).
pub fn is_sog_meta(path: &Path) -> bool {
    path.file_name().is_some_and(|n| n.to_string_lossy().eq_ignore_ascii_case("meta.json"))
}

/// Reads a `.sog` bundle or an unbundled scene's `meta.json`.
pub fn read_sog(path: &Path) -> Result<Splats> {
    let bad = |m: String| Error::input(path, format!("not a valid SOG scene: {m}"));
    if is_sog_meta(path) {
        let dir = path.parent().unwrap_or(Path::new("."));
        let mut load = |name: &str| -> Result<Vec<u8>, String> {
            let rel = Path::new(name);
            if name == "meta.json" {
                return std::fs::read(path).map_err(|e| format!("cannot read: {e}"));
            }
            if !rel.components().all(|c| matches!(c, Component::Normal(_))) {
                return Err(format!("meta.json names `{name}`, which is not a file beside it"));
            }
            std::fs::read(dir.join(rel)).map_err(|e| format!("{name}: {e}"))
        };
        decode_sog(&mut load).map_err(bad)
    } else {
        let bytes = std::fs::read(path).map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
        decode_sog_bundle(&bytes).map_err(bad)
    }
}

/// Decodes a `.sog` bundle (a zip archive with `meta.json` and the images at its root).
pub fn decode_sog_bundle(bytes: &[u8]) -> Result<Splats, String> {
    let mut zip = zip::ZipArchive::new(std::io::Cursor::new(bytes)).map_err(|e| format!("not a zip archive: {e}"))?;
    let mut load = |name: &str| -> Result<Vec<u8>, String> {
        let mut f = zip.by_name(name).map_err(|e| format!("{name}: {e}"))?;
        if f.size() > MAX_ENTRY_BYTES {
            return Err(format!("{name}: {} bytes uncompressed is too large", f.size()));
        }
        // The declared size only bounds the reservation: the data itself decides the length.
        let mut out = Vec::with_capacity(f.size().min(1 << 24) as usize);
        f.by_ref().take(MAX_ENTRY_BYTES).read_to_end(&mut out).map_err(|e| format!("{name}: {e}"))?;
        Ok(out)
    };
    decode_sog(&mut load)
}

/// An RGBA8 image.
struct Rgba {
    width: usize,
    height: usize,
    data: Vec<u8>,
}

impl Rgba {
    fn texel(&self, i: usize) -> [u8; 4] {
        self.data[4 * i..4 * i + 4].try_into().unwrap()
    }
}

fn decode_webp(bytes: &[u8], name: &str) -> Result<Rgba, String> {
    let img = image::load_from_memory_with_format(bytes, image::ImageFormat::WebP).map_err(|e| format!("{name}: {e}"))?;
    let img = img.to_rgba8();
    Ok(Rgba { width: img.width() as usize, height: img.height() as usize, data: img.into_raw() })
}

fn encode_webp(img: &Rgba) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    image::codecs::webp::WebPEncoder::new_lossless(&mut out)
        .encode(&img.data, img.width as u32, img.height as u32, image::ExtendedColorType::Rgba8)
        .map_err(|e| format!("WebP encoding: {e}"))?;
    Ok(out)
}

fn parse_meta(bytes: &[u8]) -> Result<Meta, String> {
    let v: serde_json::Value = serde_json::from_slice(bytes).map_err(|e| format!("meta.json: {e}"))?;
    match v.get("version") {
        None => return Err("meta.json has no `version`: SOG v1 is not supported (v2 is)".into()),
        Some(ver) if ver.as_u64() != Some(2) => return Err(format!("meta.json: SOG version {ver} is not supported (2 is)")),
        _ => {}
    }
    let meta: Meta = serde_json::from_value(v).map_err(|e| format!("meta.json: {e}"))?;
    if meta.means.mins.len() != 3 || meta.means.maxs.len() != 3 {
        return Err("meta.json: means.mins and means.maxs need 3 values each".into());
    }
    if meta.means.mins.iter().chain(&meta.means.maxs).any(|v| !v.is_finite()) {
        return Err("meta.json: means.mins / means.maxs are not finite".into());
    }
    Ok(meta)
}

/// The `i`-th name of a `files` list.
fn file<'a>(files: &'a [String], i: usize, key: &str) -> Result<&'a str, String> {
    files.get(i).map(String::as_str).ok_or_else(|| format!("meta.json: `{key}.files` needs at least {} names", i + 1))
}

/// Decodes a SOG scene whose files `load` provides (`meta.json` first).
fn decode_sog(load: &mut Loader) -> Result<Splats, String> {
    let meta = parse_meta(&load("meta.json")?)?;
    let n = meta.count;
    let mut texture = |name: &str| -> Result<Rgba, String> {
        let img = decode_webp(&load(name)?, name)?;
        Ok(img)
    };
    let per_gaussian = |img: Rgba, name: &str| -> Result<Rgba, String> {
        if img.width * img.height < n {
            return Err(format!("{name}: {}×{} image holds fewer than count = {n} Gaussians", img.width, img.height));
        }
        Ok(img)
    };
    let lo_name = file(&meta.means.files, 0, "means")?;
    let hi_name = file(&meta.means.files, 1, "means")?;
    let lo = per_gaussian(texture(lo_name)?, lo_name)?;
    let hi = per_gaussian(texture(hi_name)?, hi_name)?;
    let q_name = file(&meta.quats.files, 0, "quats")?;
    let quats = per_gaussian(texture(q_name)?, q_name)?;
    let s_name = file(&meta.scales.files, 0, "scales")?;
    let scales = per_gaussian(texture(s_name)?, s_name)?;
    let c_name = file(&meta.sh0.files, 0, "sh0")?;
    let sh0 = per_gaussian(texture(c_name)?, c_name)?;
    check_indices(&scales, n, 3, meta.scales.codebook.len(), s_name)?;
    check_indices(&sh0, n, 3, meta.sh0.codebook.len(), c_name)?;

    // SH palette.
    let (degree, palette) = match &meta.sh_n {
        None => (0, None),
        Some(sh) => {
            if sh.bands > 3 {
                return Err(format!("meta.json: shN.bands = {} (0 to 3 allowed)", sh.bands));
            }
            let k = sh_rest_coeffs(sh.bands);
            if k == 0 {
                (0, None)
            } else {
                let cen_name = file(&sh.files, 0, "shN")?;
                let lab_name = file(&sh.files, 1, "shN")?;
                let centroids = texture(cen_name)?;
                if centroids.width != CENTROIDS_PER_ROW * k {
                    return Err(format!(
                        "{cen_name}: {} texels wide, {} expected for {} bands",
                        centroids.width,
                        CENTROIDS_PER_ROW * k,
                        sh.bands
                    ));
                }
                // Only the palette's `count` centroids are ever looked up (padding texels may hold anything).
                let used = sh.count.min(CENTROIDS_PER_ROW * centroids.height);
                let max = (0..used)
                    .flat_map(|c| {
                        let base = (c / CENTROIDS_PER_ROW) * centroids.width + (c % CENTROIDS_PER_ROW) * k;
                        (base..base + k).flat_map(|t| centroids.texel(t)[..3].to_vec())
                    })
                    .max();
                if let Some(m) = max.filter(|&m| m as usize >= sh.codebook.len()) {
                    return Err(format!("{cen_name}: index {m} is beyond the {}-entry codebook", sh.codebook.len()));
                }
                let labels = per_gaussian(texture(lab_name)?, lab_name)?;
                (sh.bands, Some((centroids, labels, sh)))
            }
        }
    };

    let (mins, maxs) = (&meta.means.mins, &meta.means.maxs);
    let mut s = Splats::new(degree);
    let k = sh_rest_coeffs(degree);
    let mut rest = vec![0.0f32; 3 * k];
    for i in 0..n {
        let (l, h) = (lo.texel(i), hi.texel(i));
        let pos: [f32; 3] = std::array::from_fn(|a| {
            let q = f64::from(u16::from(l[a]) | u16::from(h[a]) << 8);
            let range = if maxs[a] - mins[a] != 0.0 { maxs[a] - mins[a] } else { 1.0 };
            inv_log_transform(mins[a] + range * q / 65535.0) as f32
        });
        rest.fill(0.0);
        if let Some((centroids, labels, sh)) = &palette {
            let t = labels.texel(i);
            let label = usize::from(t[0]) | usize::from(t[1]) << 8;
            let row = label / CENTROIDS_PER_ROW;
            if label < sh.count && row < centroids.height {
                let base = row * centroids.width + (label % CENTROIDS_PER_ROW) * k;
                for (kk, coeff) in rest.chunks_exact_mut(3).enumerate() {
                    let texel = centroids.texel(base + kk);
                    for (ch, v) in coeff.iter_mut().enumerate() {
                        *v = sh.codebook[texel[ch] as usize];
                    }
                }
            }
        }
        let sc = scales.texel(i);
        let c = sh0.texel(i);
        let cb = &meta.sh0.codebook;
        s.push(
            pos,
            [0, 1, 2].map(|a| meta.scales.codebook[sc[a] as usize]),
            unpack_quat(quats.texel(i)),
            alpha_to_logit(c[3]),
            [cb[c[0] as usize], cb[c[1] as usize], cb[c[2] as usize]],
            &rest,
        );
    }
    s.validate().map_err(|e| format!("invalid scene: {e}"))?;
    Ok(s)
}

/// Every index in the first `channels` channels of the first `count` texels is below `len`.
fn check_indices(img: &Rgba, count: usize, channels: usize, len: usize, name: &str) -> Result<(), String> {
    let max = img.data.chunks_exact(4).take(count).flat_map(|t| t[..channels].iter().copied()).max();
    match max {
        Some(m) if m as usize >= len => Err(format!("{name}: index {m} is beyond the {len}-entry codebook")),
        _ => Ok(()),
    }
}

/// `sign(x)·ln(|x| + 1)`: the transform positions are quantised in.
fn log_transform(x: f64) -> f64 {
    x.signum() * x.abs().ln_1p()
}

fn inv_log_transform(v: f64) -> f64 {
    v.signum() * v.abs().exp_m1()
}

/// `quats.webp` texel to `(w, x, y, z)`; an alpha outside 252..=255 decodes as the identity
/// (as the reference reader does).
fn unpack_quat(t: [u8; 4]) -> [f32; 4] {
    if !(252..=255).contains(&t[3]) {
        return [1.0, 0.0, 0.0, 0.0];
    }
    let largest = (t[3] - 252) as usize;
    let mut q = [0.0f32; 4];
    let mut sum = 0.0;
    let mut j = 0;
    for (i, v) in q.iter_mut().enumerate() {
        if i != largest {
            *v = (t[j] as f32 / 255.0 * 2.0 - 1.0) / std::f32::consts::SQRT_2;
            sum += *v * *v;
            j += 1;
        }
    }
    q[largest] = (1.0 - sum).max(0.0).sqrt();
    q
}

/// `(w, x, y, z)` to a `quats.webp` texel (rounding to the nearest byte).
fn pack_quat(rot: [f32; 4]) -> [u8; 4] {
    let q = normalize_quat(rot);
    let largest = (1..4).fold(0, |m, i| if q[i].abs() > q[m].abs() { i } else { m });
    let s = if q[largest] < 0.0 { -std::f32::consts::SQRT_2 } else { std::f32::consts::SQRT_2 };
    let mut out = [0u8, 0, 0, 252 + largest as u8];
    let mut j = 0;
    for (i, &v) in q.iter().enumerate() {
        if i != largest {
            out[j] = to_u8(255.0 * (v * s * 0.5 + 0.5));
            j += 1;
        }
    }
    out
}

fn to_u8(x: f32) -> u8 {
    x.round().clamp(0.0, 255.0) as u8
}

/// Gaussians in Morton (Z-curve) order of their positions on a 1024³ grid over the bounding box,
/// ties in input order: the order SOG and compressed PLY writers store Gaussians in.
pub fn morton_order(positions: &[[f32; 3]]) -> Vec<usize> {
    let Some((lo, hi)) = positions.iter().try_fold(([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]), |(lo, hi), p| {
        Some((std::array::from_fn(|a| lo[a].min(p[a])), std::array::from_fn(|a| hi[a].max(p[a]))))
    }) else {
        return Vec::new();
    };
    let mut keyed: Vec<(u64, usize)> = positions
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let q = std::array::from_fn(|a| {
                let range = hi[a] - lo[a];
                if range > 0.0 {
                    (((p[a] - lo[a]) / range) * 1023.0).round().clamp(0.0, 1023.0) as u32
                } else {
                    0
                }
            });
            (morton_encode(q, 10), i)
        })
        .collect();
    keyed.sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}

/// A codebook of at most 256 values for `values` and each value's index in it: exact when there
/// are at most 256 distinct values, otherwise 1-D k-means (Lloyd's algorithm on the sorted values,
/// seeded at quantiles). Each value gets its nearest entry.
pub fn quantize_1d(values: &[f32]) -> (Vec<f32>, Vec<u8>) {
    let mut sorted: Vec<f32> = values.to_vec();
    sorted.sort_unstable_by(f32::total_cmp);
    let mut distinct = sorted.clone();
    distinct.dedup();
    let codebook: Vec<f32> = if distinct.len() <= CODEBOOK_SIZE {
        if distinct.is_empty() {
            vec![0.0]
        } else {
            distinct
        }
    } else {
        let n = sorted.len();
        let mut c: Vec<f64> = (0..CODEBOOK_SIZE).map(|i| f64::from(sorted[((2 * i + 1) * n / (2 * CODEBOOK_SIZE)).min(n - 1)])).collect();
        c.dedup();
        for _ in 0..30 {
            let (mut sum, mut cnt) = (vec![0.0f64; c.len()], vec![0usize; c.len()]);
            let mut j = 0;
            for &v in &sorted {
                let v = f64::from(v);
                while j + 1 < c.len() && v > 0.5 * (c[j] + c[j + 1]) {
                    j += 1;
                }
                sum[j] += v;
                cnt[j] += 1;
            }
            let next: Vec<f64> = c.iter().enumerate().map(|(i, &old)| if cnt[i] > 0 { sum[i] / cnt[i] as f64 } else { old }).collect();
            if next == c {
                break;
            }
            c = next;
        }
        let mut cb: Vec<f32> = c.iter().map(|&v| v as f32).collect();
        cb.dedup();
        cb
    };
    let labels = values.iter().map(|&v| nearest(&codebook, v) as u8).collect();
    (codebook, labels)
}

/// Index of the entry of the ascending `codebook` nearest to `v` (lower one on ties).
fn nearest(codebook: &[f32], v: f32) -> usize {
    let i = codebook.partition_point(|&c| c < v);
    if i == 0 {
        0
    } else if i == codebook.len() || (v - codebook[i - 1]) <= (codebook[i] - v) {
        i - 1
    } else {
        i
    }
}

/// Clusters the `n = data.len() / d` rows of `data` into at most `k` centroids: repeatedly splits
/// the cluster with the largest squared error at the mean of its highest-variance coordinate,
/// then refines with Lloyd iterations while they are cheap. Returns the centroids (row-major) and
/// each row's label. With `n ≤ k` every row is its own centroid.
pub fn palette(data: &[f32], d: usize, k: usize) -> (Vec<f32>, Vec<u32>) {
    let n = data.len().checked_div(d).unwrap_or(0);
    if n <= k {
        return (data.to_vec(), (0..n as u32).collect());
    }
    let row = |i: u32| &data[i as usize * d..(i as usize + 1) * d];
    // (sse, members) per cluster.
    let stats = |m: &[u32]| -> (f64, Vec<f64>, Vec<f64>) {
        let mut mean = vec![0.0f64; d];
        let mut sq = vec![0.0f64; d];
        for &i in m {
            for (j, &v) in row(i).iter().enumerate() {
                mean[j] += f64::from(v);
                sq[j] += f64::from(v) * f64::from(v);
            }
        }
        let len = m.len().max(1) as f64;
        let var: Vec<f64> = (0..d).map(|j| (sq[j] / len - (mean[j] / len).powi(2)).max(0.0)).collect();
        mean.iter_mut().for_each(|v| *v /= len);
        (var.iter().sum::<f64>() * len, mean, var)
    };
    #[derive(PartialEq)]
    struct Item(f64, usize);
    impl Eq for Item {}
    impl PartialOrd for Item {
        fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
            Some(self.cmp(o))
        }
    }
    impl Ord for Item {
        fn cmp(&self, o: &Self) -> std::cmp::Ordering {
            self.0.total_cmp(&o.0).then(o.1.cmp(&self.1))
        }
    }
    let mut clusters: Vec<Vec<u32>> = vec![(0..n as u32).collect()];
    let mut heap = std::collections::BinaryHeap::new();
    heap.push(Item(stats(&clusters[0]).0, 0));
    while clusters.len() < k {
        let Some(Item(sse, c)) = heap.pop() else { break };
        if sse <= 0.0 {
            break;
        }
        let (_, mean, var) = stats(&clusters[c]);
        let dim = (0..d).fold(0, |b, j| if var[j] > var[b] { j } else { b });
        let (a, b): (Vec<u32>, Vec<u32>) = clusters[c].iter().partition(|&&i| f64::from(row(i)[dim]) <= mean[dim]);
        if a.is_empty() || b.is_empty() {
            continue; // identical along every coordinate to float precision: leave it whole
        }
        heap.push(Item(stats(&a).0, c));
        heap.push(Item(stats(&b).0, clusters.len()));
        clusters[c] = a;
        clusters.push(b);
    }
    let mut labels = vec![0u32; n];
    for (c, m) in clusters.iter().enumerate() {
        m.iter().for_each(|&i| labels[i as usize] = c as u32);
    }
    let kk = clusters.len();
    let means = |labels: &[u32], old: Option<&[f32]>| -> Vec<f32> {
        let mut sum = vec![0.0f64; kk * d];
        let mut cnt = vec![0usize; kk];
        for (i, &l) in labels.iter().enumerate() {
            cnt[l as usize] += 1;
            for (j, &v) in row(i as u32).iter().enumerate() {
                sum[l as usize * d + j] += f64::from(v);
            }
        }
        (0..kk * d).map(|x| if cnt[x / d] > 0 { (sum[x] / cnt[x / d] as f64) as f32 } else { old.map_or(0.0, |o| o[x]) }).collect()
    };
    let mut centroids = means(&labels, None);
    if (n * kk * d) as f64 <= PALETTE_REFINE_BUDGET {
        for _ in 0..5 {
            let next: Vec<u32> = (0..n as u32)
                .into_par_iter()
                .map(|i| {
                    let r = row(i);
                    let dist = |c: usize| -> f32 { centroids[c * d..(c + 1) * d].iter().zip(r).map(|(a, b)| (a - b) * (a - b)).sum() };
                    let mut best = labels[i as usize] as usize;
                    let mut bd = dist(best);
                    for c in 0..kk {
                        let dc = dist(c);
                        if dc < bd {
                            (best, bd) = (c, dc);
                        }
                    }
                    best as u32
                })
                .collect();
            if next == labels {
                break;
            }
            labels = next;
            centroids = means(&labels, Some(&centroids));
        }
    }
    (centroids, labels)
}

/// The reference writer's SH palette size for `n` Gaussians: `min(64, 2^⌊log2(n/1024)⌋)·1024`.
pub fn palette_size(n: usize) -> usize {
    if n == 0 {
        return 1;
    }
    let e = ((n as f64) / 1024.0).log2().floor();
    ((2f64.powf(e).min(64.0)) * 1024.0).round().max(1.0) as usize
}

/// The files of a SOG scene: `(name, bytes)`, `meta.json` last.
pub fn encode_sog(splats: &Splats) -> Result<Vec<(String, Vec<u8>)>, String> {
    splats.validate().map_err(|e| e.to_string())?;
    let n = splats.len();
    let width = ((n as f64).sqrt() / 4.0).ceil() as usize * 4;
    let width = width.max(4);
    let height = ((n as f64 / width as f64 / 4.0).ceil() as usize * 4).max(4);
    if width > MAX_WEBP_SIDE || height > MAX_WEBP_SIDE {
        return Err(format!("{n} Gaussians do not fit SOG's {MAX_WEBP_SIDE}×{MAX_WEBP_SIDE} WebP images"));
    }
    let order = morton_order(&splats.positions);
    let image = || Rgba { width, height, data: vec![0u8; width * height * 4] };

    // Positions.
    let lt: Vec<[f64; 3]> = splats.positions.iter().map(|p| p.map(|v| log_transform(f64::from(v)))).collect();
    let mins: Vec<f64> =
        (0..3).map(|a| lt.iter().map(|p| p[a]).fold(f64::INFINITY, f64::min)).map(|v| if v.is_finite() { v } else { 0.0 }).collect();
    let maxs: Vec<f64> =
        (0..3).map(|a| lt.iter().map(|p| p[a]).fold(f64::NEG_INFINITY, f64::max)).map(|v| if v.is_finite() { v } else { 0.0 }).collect();
    let (mut means_l, mut means_u, mut quats) = (image(), image(), image());
    for (t, &g) in order.iter().enumerate() {
        for a in 0..3 {
            let range = maxs[a] - mins[a];
            let q = if range > 0.0 { (65535.0 * (lt[g][a] - mins[a]) / range).round().clamp(0.0, 65535.0) as u16 } else { 0 };
            means_l.data[4 * t + a] = q as u8;
            means_u.data[4 * t + a] = (q >> 8) as u8;
        }
        means_l.data[4 * t + 3] = 255;
        means_u.data[4 * t + 3] = 255;
        quats.data[4 * t..4 * t + 4].copy_from_slice(&pack_quat(splats.rotations[g]));
    }

    // Scales and colour: one codebook each, shared by the three channels.
    let flat = |v: &[[f32; 3]]| -> Vec<f32> { order.iter().flat_map(|&g| v[g]).collect() };
    let (scale_cb, scale_idx) = quantize_1d(&flat(&splats.log_scales));
    let (dc_cb, dc_idx) = quantize_1d(&flat(&splats.sh_dc));
    let (mut scales, mut sh0) = (image(), image());
    for (t, &g) in order.iter().enumerate() {
        scales.data[4 * t..4 * t + 3].copy_from_slice(&scale_idx[3 * t..3 * t + 3]);
        scales.data[4 * t + 3] = 255;
        sh0.data[4 * t..4 * t + 3].copy_from_slice(&dc_idx[3 * t..3 * t + 3]);
        sh0.data[4 * t + 3] = to_u8(sigmoid(splats.opacity_logits[g]) * 255.0);
    }

    let mut files = vec![
        ("means_l.webp".to_string(), encode_webp(&means_l)?),
        ("means_u.webp".to_string(), encode_webp(&means_u)?),
        ("quats.webp".to_string(), encode_webp(&quats)?),
        ("scales.webp".to_string(), encode_webp(&scales)?),
        ("sh0.webp".to_string(), encode_webp(&sh0)?),
    ];

    // View-dependent SH: a palette of coefficient vectors, its values through one codebook.
    let k = splats.rest_coeffs();
    let sh_n = if k > 0 {
        let d = 3 * k;
        let rows: Vec<f32> = order.iter().flat_map(|&g| splats.rest_of(g).iter().copied()).collect();
        let (centroids, labels) = palette(&rows, d, palette_size(n));
        let count = centroids.len() / d;
        let (sh_cb, sh_idx) = quantize_1d(&centroids);
        let cw = CENTROIDS_PER_ROW * k;
        let ch = count.div_ceil(CENTROIDS_PER_ROW).max(1);
        if ch > MAX_WEBP_SIDE {
            return Err(format!("an SH palette of {count} entries does not fit a WebP image"));
        }
        let mut cen = Rgba { width: cw, height: ch, data: vec![0u8; cw * ch * 4] };
        for c in 0..count {
            for kk in 0..k {
                let t = (c / CENTROIDS_PER_ROW) * cw + (c % CENTROIDS_PER_ROW) * k + kk;
                // Palette rows are coefficient-major `[k][channel]`, as `Splats::sh_rest`.
                cen.data[4 * t..4 * t + 3].copy_from_slice(&sh_idx[c * d + kk * 3..c * d + kk * 3 + 3]);
                cen.data[4 * t + 3] = 255;
            }
        }
        let mut lab = image();
        for (t, &l) in labels.iter().enumerate() {
            lab.data[4 * t..4 * t + 4].copy_from_slice(&[l as u8, (l >> 8) as u8, 0, 255]);
        }
        files.push(("shN_centroids.webp".into(), encode_webp(&cen)?));
        files.push(("shN_labels.webp".into(), encode_webp(&lab)?));
        Some(ShN { count, bands: splats.sh_degree, codebook: sh_cb, files: vec!["shN_centroids.webp".into(), "shN_labels.webp".into()] })
    } else {
        None
    };

    let meta = Meta {
        version: 2,
        asset: Some(serde_json::json!({ "generator": format!("gscodec {}", env!("CARGO_PKG_VERSION")) })),
        count: n,
        means: Means { mins, maxs, files: vec!["means_l.webp".into(), "means_u.webp".into()] },
        scales: Codebooked { codebook: scale_cb, files: vec!["scales.webp".into()] },
        quats: Files { files: vec!["quats.webp".into()] },
        sh0: Codebooked { codebook: dc_cb, files: vec!["sh0.webp".into()] },
        sh_n,
    };
    files.push(("meta.json".into(), serde_json::to_vec(&meta).map_err(|e| e.to_string())?));
    Ok(files)
}

/// Encodes a scene as a `.sog` bundle: a zip archive of its files (images stored, `meta.json`
/// deflated).
pub fn encode_sog_bundle(splats: &Splats) -> Result<Vec<u8>, String> {
    let files = encode_sog(splats)?;
    let mut zip = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    for (name, bytes) in &files {
        let method = if name.ends_with(".json") { zip::CompressionMethod::Deflated } else { zip::CompressionMethod::Stored };
        let opts = zip::write::SimpleFileOptions::default().compression_method(method);
        zip.start_file(name.as_str(), opts).map_err(|e| e.to_string())?;
        zip.write_all(bytes).map_err(|e| e.to_string())?;
    }
    Ok(zip.finish().map_err(|e| e.to_string())?.into_inner())
}

/// Writes `splats` as SOG: a `.sog` bundle, or, when `path` is a `meta.json`, the unbundled files
/// beside it (all moved into place together once written).
pub fn write_sog(path: &Path, splats: &Splats) -> Result<()> {
    let cannot = |m: String| Error::input(path, format!("cannot encode as SOG: {m}"));
    if is_sog_meta(path) {
        let files = encode_sog(splats).map_err(cannot)?;
        let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
        write_dir_atomic(dir, |tmp| {
            files.iter().try_for_each(|(name, bytes)| {
                let name = if name == "meta.json" { path.file_name().unwrap().to_string_lossy().into_owned() } else { name.clone() };
                std::fs::write(tmp.join(&name), bytes).map_err(|e| Error::failure(&tmp.join(&name), format!("cannot write: {e}")))
            })
        })
    } else {
        write_bytes_atomic(path, &encode_sog_bundle(splats).map_err(cannot)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quaternion_packing_round_trips_within_a_byte() {
        for q in [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, -1.0], [0.3, -0.5, 0.7, 0.1], [-0.5, 0.5, -0.5, 0.5], [0.01, -0.9, 0.2, 0.3]] {
            let n = normalize_quat(q);
            let d = unpack_quat(pack_quat(q));
            let dot: f32 = (0..4).map(|i| n[i] * d[i]).sum();
            assert!(dot.abs() > 1.0 - 5e-5, "{q:?} -> {d:?} (dot {dot})");
        }
        assert_eq!(unpack_quat([9, 9, 9, 0]), [1.0, 0.0, 0.0, 0.0]);
    }

    #[test]
    fn codebook_is_exact_for_few_values_and_nearest_otherwise() {
        let few = [0.5f32, -1.0, 0.5, 3.0];
        let (cb, idx) = quantize_1d(&few);
        assert_eq!(cb, vec![-1.0, 0.5, 3.0]);
        assert_eq!(idx.iter().map(|&i| cb[i as usize]).collect::<Vec<_>>(), few);
        let many: Vec<f32> = (0..5000).map(|i| ((i * 7919) % 5000) as f32 / 100.0).collect();
        let (cb, idx) = quantize_1d(&many);
        assert!(cb.len() <= CODEBOOK_SIZE && cb.windows(2).all(|w| w[0] < w[1]));
        for (&v, &i) in many.iter().zip(&idx) {
            let best = cb.iter().map(|c| (c - v).abs()).fold(f32::INFINITY, f32::min);
            assert_eq!((cb[i as usize] - v).abs(), best);
            assert!(best <= 50.0 / 256.0, "uniform data on [0, 50): error {best}");
        }
    }

    #[test]
    fn palette_finds_repeated_vectors_exactly() {
        let d = 4;
        let protos: Vec<[f32; 4]> = (0..10).map(|i| [i as f32, (i * i) as f32 * 0.1, -(i as f32), 0.5]).collect();
        let data: Vec<f32> = (0..300).flat_map(|i| protos[(i * 7) % 10]).collect();
        let (c, l) = palette(&data, d, 16);
        for (i, &lab) in l.iter().enumerate() {
            assert_eq!(&c[lab as usize * d..lab as usize * d + d], &data[i * d..i * d + d]);
        }
        assert_eq!(palette_size(1000), 512);
        assert_eq!(palette_size(1024), 1024);
        assert_eq!(palette_size(10_000_000), 65536);
    }
}
