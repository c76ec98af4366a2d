//! Empirical entropy of each quantised channel, plain and conditioned on candidate contexts (the
//! previous Gaussian's value in Morton order, the previous channel of the same Gaussian, both):
//! the measurement behind the context tables of format 3.0 (docs/codec.md). Table costs are not
//! counted, so these are lower bounds.
//!
//! Then, on the file `encode --lambda LAMBDA` writes (pruned, importance classes, SH codebooks;
//! bands with a codebook skipped; with neighbour tables off), the cost of its channels under
//! models that store no table per context: *adaptive* ones (per context, counts seeded by the
//! channel's stored histogram and updated after every value; in floating point, and as a decoder
//! would run them in integers with tables rebuilt now and then) and *parametric* ones (a window
//! per context, a few bytes each), against what the file stores, and against the neighbour
//! tables the encoder builds (mode 3, format 8.0). The measurement behind "Neighbour contexts"
//! in docs/codec.md.
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

/// Per context a two-sided geometric window `r^|s − μ|` over the channel's symbols (μ the
/// context's median symbol, r the best of 64 ratios): the values' cost plus `head` bits per used
/// context for (μ, r).
fn parametric(vals: &[i32], ctx: &[usize], nctx: usize, lo: i32, base: &FreqTable, head: f64) -> f64 {
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
        let best = (0..64)
            .map(|k| {
                let r = (1.0 - (k as f64 + 0.5) / 64.0 * 0.999).powf(1.5);
                let w: Vec<f64> =
                    (0..m).map(|s| if s == n { 1e-4 } else { r.powi((s as i64 - mu).unsigned_abs() as i32).max(1e-9) }).collect();
                let t: f64 = w.iter().sum();
                syms.iter().map(|&s| -(w[s] / t).log2() + if s == n { 32.0 } else { 0.0 }).sum::<f64>()
            })
            .fold(f64::INFINITY, f64::min);
        bits += best + head;
    }
    bits
}

/// As [`parametric`] with μ = (a·prev + (4 − a)·median + 2) / 4 for the best a in 0..=4 per
/// context (`prev` the previous value's symbol): mode 3's model, in floating point.
fn parametric_prev(vals: &[i32], ctx: &[usize], nctx: usize, lo: i32, n: usize, head: f64) -> f64 {
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
        for a in 0..=4i64 {
            for k in 0..64 {
                let r = (1.0 - (k as f64 + 0.5) / 64.0 * 0.999).powf(1.5);
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

    // Models that need no table per context, on the file as written (codebook bands skipped).
    let config = rate::EncodeConfig { neighbour_tables: false, ..config };
    let (bytes, _, q) = rate::encode(&scene, &config).unwrap();
    println!(
        "{} Gaussians, file {} B, codebooks {:?}, levels {:?}",
        q.morton.len(),
        bytes.len(),
        q.codebooks.iter().map(|c| c.0).collect::<Vec<_>>(),
        q.levels
    );
    const NAMES: [&str; 7] = [
        "stored (file's tables)",
        "adaptive, |prev| class x lower class (16 ctx)",
        "adaptive, prev octile x lower octile (64 ctx, 16 pseudo-counts)",
        "the same in integers, table rebuilt at 1, 2, 4 .. 256 values, then every 256",
        "window per context, centre = median (64 ctx, 3 bytes each)",
        "window per context, centre mixed with prev (64 ctx)",
        "mode 3 as the encoder builds it (tables::with_neighbours)",
    ];
    let mut tot = [0.0f64; NAMES.len()];
    for (g, _, chans) in &q.groups {
        if q.codebooks.iter().any(|c| c.0 == *g) {
            println!("{:?}: codebook, skipped", g);
            continue;
        }
        let mut t = [0.0f64; NAMES.len()];
        for (j, ch) in chans.iter().enumerate() {
            let n = ch.len();
            let stored = tables::histogram_only(ch, Some(&[0..n]), None).best.total_bits();
            let hist = tables::choose(ch);
            let ChannelTable::Coded { lo, table } = &hist.table else {
                t.iter_mut().for_each(|x| *x += stored);
                continue;
            };
            let tb = 8.0 * hist.bytes.len() as f64;
            let freqs: Vec<f64> = (0..table.len()).map(|s| table.freq(s) as f64 / 65536.0).collect();
            let lower: &[i32] = if j > 0 { &chans[j - 1] } else { &[] };
            let centre = median(ch);
            let prev_class: Vec<usize> = (0..n).map(|i| class(if i > 0 { ch[i - 1] - centre } else { 0 }) as usize).collect();
            let lower_class: Vec<usize> = (0..n).map(|i| if j > 0 { class(lower[i]) as usize } else { 0 }).collect();
            let old: Vec<usize> = (0..n).map(|i| prev_class[i] * 4 + lower_class[i]).collect();
            let (pt, lt) = (octiles(ch), if j > 0 { octiles(lower) } else { vec![] });
            let bucket = |th: &[i32], x: i32| th.iter().filter(|&&t| x >= t).count();
            let octs: Vec<usize> = (0..n)
                .map(|i| bucket(&pt, if i > 0 { ch[i - 1] } else { centre }) * 8 + if j > 0 { bucket(&lt, lower[i]) } else { 0 })
                .collect();
            t[0] += stored;
            t[1] += tb + adaptive(ch, &old, 16, *lo, &freqs, 64.0, 1.0);
            t[2] += tb + adaptive(ch, &octs, 64, *lo, &freqs, 16.0, 1.0);
            t[3] += tb + adaptive_int(ch, &octs, 64, *lo, table, 4096, 256);
            t[4] += tb + parametric(ch, &octs, 64, *lo, table, 24.0);
            t[5] += tb + parametric_prev(ch, &octs, 64, *lo, table.len() - 1, 24.0);
            t[6] += tables::with_neighbours(ch, lower, &[0..n]).map_or(stored, |c| c.total_bits());
        }
        println!("{:?}: {}", g, t.iter().map(|b| format!("{:.0}", b / 8.0)).collect::<Vec<_>>().join(" | "));
        tot.iter_mut().zip(t).for_each(|(a, b)| *a += b);
    }
    println!("bytes of the non-codebook channels, and against the stored tables:");
    for (name, b) in NAMES.iter().zip(tot) {
        println!("  {name}: {:.0} B ({:.3})", b / 8.0, b / tot[0]);
    }
}

fn median(v: &[i32]) -> i32 {
    let mut v = v.to_vec();
    let h = v.len() / 2;
    *v.select_nth_unstable(h).1
}

/// Thresholds splitting `v` into eight parts of about equal count.
fn octiles(v: &[i32]) -> Vec<i32> {
    let mut v = v.to_vec();
    v.sort_unstable();
    (1..8).map(|t| v[t * v.len() / 8]).collect()
}
