//! Empirical entropy of each quantised channel, plain and conditioned on candidate contexts (the
//! previous Gaussian's value in Morton order, the previous channel of the same Gaussian, both):
//! the measurement behind the context tables of format 3.0 (docs/codec.md). Table costs are not
//! counted, so these are lower bounds.
//!
//! Then, on the file `encode --lambda LAMBDA` writes (pruned, importance classes, SH codebooks;
//! bands with a codebook skipped), the cost of each channel under *adaptive* context models —
//! per context, counts seeded by the channel's stored histogram (64 pseudo-counts) and updated
//! after every value, so no table per context is stored — against what the file stores. This is
//! the measurement behind "adaptive contexts" in docs/codec.md (not built: too small a gain).
//!
//! `cargo run --release --example ctx_probe -- SCENE.ply LAMBDA`
use gscodec::io::ply::read_ply;
use gscodec::rate::{self, quantise, tables};
use gscodec_decoder::entropy::{symbol_of, ChannelTable, FreqTable};
use std::collections::HashMap;
use std::path::Path;

fn h(vals: &[(u32, i32)]) -> f64 {
    // sum over contexts of n_c * H(v | c)
    let mut by: HashMap<u32, HashMap<i32, usize>> = HashMap::new();
    for &(c, v) in vals {
        *by.entry(c).or_default().entry(v).or_default() += 1;
    }
    let mut bits = 0.0;
    for m in by.values() {
        let n: usize = m.values().sum();
        for &k in m.values() {
            bits -= k as f64 * (k as f64 / n as f64).log2();
        }
    }
    bits
}

fn class(v: i32) -> u32 {
    match v.unsigned_abs() {
        0 => 0,
        1 => 1,
        2..=3 => 2,
        _ => 3,
    }
}

/// Adaptive cost: per context counts = prior (static freqs scaled to `prior` pseudo-counts) + inc per symbol.
fn adaptive(vals: &[i32], ctx: &[usize], nctx: usize, lo: i32, freqs: &[f64], prior: f64, inc: f64) -> f64 {
    let m = freqs.len();
    let mut counts = vec![vec![0.0; m]; nctx];
    let mut tot = vec![0.0; nctx];
    for c in 0..nctx {
        for s in 0..m {
            counts[c][s] = freqs[s] * prior;
        }
        tot[c] = prior;
    }
    let n = m - 1;
    let mut bits = 0.0;
    for (i, &v) in vals.iter().enumerate() {
        let c = ctx[i];
        let s = symbol_of(lo, n, v);
        bits += -(counts[c][s] / tot[c]).log2() + if s == n { 32.0 } else { 0.0 };
        counts[c][s] += inc;
        tot[c] += inc;
        if tot[c] > 65536.0 {
            for x in counts[c].iter_mut() {
                *x *= 0.5;
            }
            tot[c] *= 0.5;
        }
    }
    bits
}

/// The decoder's version: integer counts seeded by the stored table's frequencies (sum 2^16),
/// `inc` per symbol, the coding table rebuilt (SPEC §4.2) when a context has seen 1, 2, 4, …,
/// `cap` symbols and every `cap` after.
fn adaptive_int(vals: &[i32], ctx: &[usize], nctx: usize, lo: i32, base: &FreqTable, inc: u32, cap: usize) -> f64 {
    let m = base.len();
    let n = m - 1;
    let init: Vec<u32> = (0..m).map(|s| base.freq(s)).collect();
    let mut counts = vec![init.clone(); nctx];
    let mut tables: Vec<FreqTable> = vec![base.clone(); nctx];
    let mut seen = vec![0usize; nctx];
    let mut bits = 0.0;
    for (i, &v) in vals.iter().enumerate() {
        let c = ctx[i];
        let s = symbol_of(lo, n, v);
        bits += tables[c].bits(s) + if s == n { 32.0 } else { 0.0 };
        counts[c][s] += inc;
        seen[c] += 1;
        let k = seen[c];
        if (k <= cap && k.is_power_of_two()) || k % cap == 0 {
            tables[c] = FreqTable::from_weights(&counts[c]);
        }
    }
    bits
}

/// Per context a two-sided geometric window `r^|s − μ|` (μ the context's median symbol, r the
/// best of 64 ratios), alone or times the channel's stored frequencies: the cost of the values
/// plus `head` bits per used context for (μ, r).
fn parametric(vals: &[i32], ctx: &[usize], nctx: usize, lo: i32, base: &FreqTable, with_base: bool, head: f64) -> f64 {
    let m = base.len();
    let n = m - 1;
    let mut by: Vec<Vec<usize>> = vec![vec![]; nctx];
    for (i, &v) in vals.iter().enumerate() {
        by[ctx[i]].push(symbol_of(lo, n, v));
    }
    let mut bits = 0.0;
    for syms in by.iter().filter(|s| !s.is_empty()) {
        let mut sorted: Vec<usize> = syms.iter().copied().filter(|&s| s < n).collect();
        sorted.sort_unstable();
        let mu = if sorted.is_empty() { 0 } else { sorted[sorted.len() / 2] } as i64;
        let mut best = f64::INFINITY;
        for k in 0..64 {
            let r = 1.0 - (k as f64 + 0.5) / 64.0 * 0.999;
            let r = r.powf(1.5);
            let w: Vec<f64> = (0..m)
                .map(|s| {
                    let g = if s == n { 1e-4 } else { r.powi((s as i64 - mu).unsigned_abs() as i32).max(1e-9) };
                    if with_base {
                        g * base.freq(s) as f64
                    } else {
                        g
                    }
                })
                .collect();
            let t: f64 = w.iter().sum();
            let c: f64 = syms.iter().map(|&s| -(w[s] / t).log2() + if s == n { 32.0 } else { 0.0 }).sum();
            best = best.min(c);
        }
        bits += best + head;
    }
    bits
}

/// μ = the previous value's symbol (DPCM), per context only the ratio r (`head` bits).
fn parametric_prev(vals: &[i32], ctx: &[usize], nctx: usize, lo: i32, n: usize, head: f64, mix: bool) -> f64 {
    let mut by: Vec<Vec<(usize, i64)>> = vec![vec![]; nctx];
    for (i, &v) in vals.iter().enumerate() {
        let p = if i > 0 { vals[i - 1] } else { lo + n as i32 / 2 };
        by[ctx[i]].push((symbol_of(lo, n, v), (i64::from(p) - i64::from(lo)).clamp(0, n as i64 - 1)));
    }
    let mut bits = 0.0;
    for syms in by.iter().filter(|s| !s.is_empty()) {
        let mut sorted: Vec<usize> = syms.iter().map(|x| x.0).filter(|&s| s < n).collect();
        sorted.sort_unstable();
        let med = if sorted.is_empty() { 0 } else { sorted[sorted.len() / 2] } as i64;
        let mut best = f64::INFINITY;
        for a in if mix { vec![0i64, 1, 2, 3, 4] } else { vec![4] } {
            for k in 0..64 {
                let r = 1.0 - (k as f64 + 0.5) / 64.0 * 0.999;
                let r = r.powf(1.5);
                let mut c = 0.0;
                for &(s, p) in syms {
                    let mu = (a * p + (4 - a) * med + 2) / 4;
                    let w = |s: usize| if s == n { 1e-4 } else { r.powi((s as i64 - mu).unsigned_abs() as i32).max(1e-9) };
                    let t: f64 = (0..=n).map(w).sum();
                    c += -(w(s) / t).log2() + if s == n { 32.0 } else { 0.0 };
                }
                best = best.min(c);
            }
        }
        bits += best + head;
    }
    bits
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let scene = read_ply(Path::new(&args[1])).unwrap();
    let lambda: rate::Lambda = args[2].parse().unwrap();
    let (config, _) = rate::rd::search(&scene, lambda, |_| {}).unwrap();
    let s = quantise::prune(&scene, config.min_opacity);
    let q = quantise::quantise(&s, &config.steps, &[]);
    let (mut t0, mut t1, mut t2, mut t3) = (0.0, 0.0, 0.0, 0.0);
    for (g, _, chans) in &q.groups {
        let (mut a, mut b, mut c, mut d) = (0.0, 0.0, 0.0, 0.0);
        for (j, ch) in chans.iter().enumerate() {
            let n = ch.len();
            let plain: Vec<(u32, i32)> = ch.iter().map(|&v| (0, v)).collect();
            // previous Gaussian (Morton order), same channel
            let prev: Vec<(u32, i32)> = (0..n).map(|i| (if i > 0 { class(ch[i - 1]) } else { 0 }, ch[i])).collect();
            // previous channel of the same Gaussian (same group)
            let lower: Vec<(u32, i32)> = (0..n).map(|i| (if j > 0 { class(chans[j - 1][i]) } else { 0 }, ch[i])).collect();
            // both: magnitude class of prev-gaussian and of previous channel
            let both: Vec<(u32, i32)> = (0..n)
                .map(|i| (4 * (if i > 0 { class(ch[i - 1]) } else { 0 }) + if j > 0 { class(chans[j - 1][i]) } else { 0 }, ch[i]))
                .collect();
            a += h(&plain);
            b += h(&prev);
            c += h(&lower);
            d += h(&both);
        }
        println!("{:?}: H {:.0} B | prev {:.0} B | lower-channel {:.0} B | both {:.0} B", g, a / 8.0, b / 8.0, c / 8.0, d / 8.0);
        t0 += a;
        t1 += b;
        t2 += c;
        t3 += d;
    }
    println!("total: H {:.0} B | prev {:.3} | lower {:.3} | both {:.3}", t0 / 8.0, t1 / t0, t2 / t0, t3 / t0);

    // Adaptive context models on the file as written.
    let (bytes, _, q) = rate::encode(&scene, &config).unwrap();
    println!(
        "{} Gaussians, file {} B, codebooks {:?}, levels {:?}",
        q.morton.len(),
        bytes.len(),
        q.codebooks.iter().map(|c| c.0).collect::<Vec<_>>(),
        q.levels
    );
    let mut tot = [0.0f64; 10];
    let mut etot = [0.0f64; 14];
    for (g, _, chans) in &q.groups {
        if q.codebooks.iter().any(|c| c.0 == *g) {
            println!("{:?}: codebook, skipped", g);
            continue;
        }
        let mut t = [0.0f64; 10];
        let mut extra = [0.0f64; 14];
        for (j, ch) in chans.iter().enumerate() {
            let n = ch.len();
            let cmp = tables::histogram_only(ch, Some(&[0..n]));
            let hist = tables::choose(ch);
            t[0] += cmp.best.total_bits();
            let ChannelTable::Coded { lo, table } = &hist.table else {
                t[1..].iter_mut().for_each(|x| *x += cmp.best.total_bits());
                continue;
            };
            let tb = 8.0 * hist.bytes.len() as f64;
            let m = table.len();
            let freqs: Vec<f64> = (0..m).map(|s| table.freq(s) as f64 / 65536.0).collect();
            let centre = {
                let mut v = ch.clone();
                let h = n / 2;
                *v.select_nth_unstable(h).1
            };
            let prev: Vec<usize> = (0..n).map(|i| class(if i > 0 { ch[i - 1] - centre } else { 0 }) as usize).collect();
            let lower: Vec<usize> = (0..n).map(|i| if j > 0 { class(chans[j - 1][i]) as usize } else { 0 }).collect();
            let rich: Vec<usize> = (0..n)
                .map(|i| {
                    let a = if i > 0 { (ch[i - 1] - centre).unsigned_abs() } else { 0 };
                    let b = if i > 1 { (ch[i - 2] - centre).unsigned_abs() } else { 0 };
                    let s = a + b;
                    (match s {
                        0 => 0,
                        1 => 1,
                        2 => 2,
                        3..=4 => 3,
                        5..=8 => 4,
                        _ => 5,
                    }) * 4
                        + lower[i]
                })
                .collect();
            t[1] += tb + adaptive(ch, &vec![0; n], 1, *lo, &freqs, 64.0, 1.0);
            t[2] += tb + adaptive(ch, &prev, 4, *lo, &freqs, 64.0, 1.0);
            let both: Vec<usize> = (0..n).map(|i| prev[i] * 4 + lower[i]).collect();
            t[3] += tb + adaptive(ch, &both, 16, *lo, &freqs, 64.0, 1.0);
            t[4] += tb + adaptive(ch, &rich, 24, *lo, &freqs, 64.0, 1.0);
            t[5] += tb + adaptive(ch, &rich, 24, *lo, &freqs, 16.0, 1.0);
            let sclass = |d: i32| -> usize {
                match d {
                    i32::MIN..=-4 => 0,
                    -3..=-2 => 1,
                    -1 => 2,
                    0 => 3,
                    1 => 4,
                    2..=3 => 5,
                    _ => 6,
                }
            };
            let sprev: Vec<usize> = (0..n).map(|i| sclass(if i > 0 { ch[i - 1] - centre } else { 0 })).collect();
            t[6] += tb + adaptive(ch, &sprev, 7, *lo, &freqs, 64.0, 1.0);
            let lcentre = if j > 0 {
                let mut v = chans[j - 1].clone();
                *v.select_nth_unstable(n / 2).1
            } else {
                0
            };
            let slower: Vec<usize> = (0..n).map(|i| if j > 0 { sclass(chans[j - 1][i] - lcentre) } else { 3 }).collect();
            let sboth: Vec<usize> = (0..n).map(|i| sprev[i] * 7 + slower[i]).collect();
            t[7] += tb + adaptive(ch, &sboth, 49, *lo, &freqs, 64.0, 1.0);
            let s2: Vec<usize> = (0..n)
                .map(|i| {
                    let a = if i > 0 { ch[i - 1] - centre } else { 0 };
                    let b = if i > 1 { ch[i - 2] - centre } else { 0 };
                    sclass((a + b).div_euclid(2)) * 7 + slower[i]
                })
                .collect();
            t[8] += tb + adaptive(ch, &s2, 49, *lo, &freqs, 64.0, 1.0);
            t[9] += tb + adaptive(ch, &s2, 49, *lo, &freqs, 16.0, 1.0);
            // quantile buckets of the previous Gaussian's value (thresholds would be stored)
            let qb = |c: &Vec<i32>, k: usize| -> Vec<i32> {
                let mut v = c.clone();
                v.sort_unstable();
                (1..k).map(|t| v[t * v.len() / k]).collect()
            };
            let th = qb(ch, 8);
            let bucket = |th: &Vec<i32>, x: i32| th.iter().filter(|&&t| x >= t).count();
            let q8: Vec<usize> = (0..n).map(|i| if i > 0 { bucket(&th, ch[i - 1]) } else { 4 }).collect();
            t[6] = t[6] - 0.0; // keep
            let q8s: Vec<usize> = (0..n).map(|i| q8[i] * 7 + slower[i]).collect();
            let lth = if j > 0 { qb(&chans[j - 1], 8) } else { vec![] };
            let q8q8: Vec<usize> = (0..n).map(|i| q8[i] * 8 + if j > 0 { bucket(&lth, chans[j - 1][i]) } else { 0 }).collect();
            extra[0] += tb + adaptive(ch, &q8, 8, *lo, &freqs, 64.0, 1.0);
            extra[1] += tb + adaptive(ch, &q8s, 56, *lo, &freqs, 64.0, 1.0);
            extra[2] += tb + adaptive(ch, &q8q8, 64, *lo, &freqs, 64.0, 1.0);
            extra[3] += tb + adaptive(ch, &q8q8, 64, *lo, &freqs, 16.0, 1.0);
            extra[4] += tb + adaptive_int(ch, &q8q8, 64, *lo, table, 4096, 256);
            extra[5] += tb + adaptive_int(ch, &q8s, 56, *lo, table, 4096, 256);
            extra[6] += tb + adaptive_int(ch, &q8q8, 64, *lo, table, 4096, 64);
            extra[7] += tb + adaptive_int(ch, &q8q8, 64, *lo, table, 4096, 1);
            extra[8] += tb + parametric_prev(ch, &q8, 8, *lo, table.len() - 1, 8.0, false);
            extra[12] += tb + parametric_prev(ch, &q8, 8, *lo, table.len() - 1, 24.0, true);
            extra[13] += tb + parametric_prev(ch, &q8q8, 64, *lo, table.len() - 1, 24.0, true);
            let th16 = qb(ch, 16);
            let q16: Vec<usize> = (0..n).map(|i| if i > 0 { bucket(&th16, ch[i - 1]) } else { 8 }).collect();
            extra[9] += tb + parametric(ch, &q16, 16, *lo, table, false, 24.0);
            extra[10] += tb + parametric(ch, &q8s, 56, *lo, table, false, 24.0);
            extra[11] += tb + parametric(ch, &q8q8, 64, *lo, table, false, 24.0);
        }
        println!(
            "{:?}: stored {:.0} | ad-none {:.0} | ad-prev {:.0} | ad-prev×lower {:.0} | ad-rich {:.0} | rich p16 {:.0} | sprev {:.0} | sprev×slower {:.0} | s2×slower {:.0} | p16 {:.0}",
            g,
            t[0] / 8.0,
            t[1] / 8.0,
            t[2] / 8.0,
            t[3] / 8.0,
            t[4] / 8.0,
            t[5] / 8.0,
            t[6] / 8.0,
            t[7] / 8.0,
            t[8] / 8.0,
            t[9] / 8.0
        );
        println!("   q8 {:.0} | q8×slower {:.0} | q8×q8 {:.0} | p16 {:.0}", extra[0] / 8.0, extra[1] / 8.0, extra[2] / 8.0, extra[3] / 8.0);
        for k in 0..14 {
            etot[k] += extra[k];
        }
        for k in 0..10 {
            tot[k] += t[k];
        }
    }
    println!(
        "total B: stored {:.0} | none {:.3} | prev {:.3} | prev×lower {:.3} | rich {:.3} | rich p16 {:.3} | sprev {:.3} | sprev×slower {:.3} | s2×slower {:.3} | p16 {:.3}",
        tot[0] / 8.0,
        tot[1] / tot[0],
        tot[2] / tot[0],
        tot[3] / tot[0],
        tot[4] / tot[0],
        tot[5] / tot[0],
        tot[6] / tot[0],
        tot[7] / tot[0],
        tot[8] / tot[0],
        tot[9] / tot[0]
    );
    println!(
        "q8 {:.3} | q8×slower {:.3} | q8×q8 {:.3} | p16 {:.3}",
        etot[0] / tot[0],
        etot[1] / tot[0],
        etot[2] / tot[0],
        etot[3] / tot[0]
    );
    println!(
        "int q8×q8 p16 cap256 {:.3} | int q8×slower p16 {:.3} | int cap64 {:.3} | int p64 {:.3}",
        etot[4] / tot[0],
        etot[5] / tot[0],
        etot[6] / tot[0],
        etot[7] / tot[0]
    );
    println!(
        "param μ=prev q8 {:.3} | q16 {:.3} | q8×slower {:.3} | q8×q8 {:.3}",
        etot[8] / tot[0],
        etot[9] / tot[0],
        etot[10] / tot[0],
        etot[11] / tot[0]
    );
    println!("mixed μ q8 {:.3} | mixed μ q8×q8 {:.3}", etot[12] / tot[0], etot[13] / tot[0]);
}
