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
use gscodec_decoder::entropy::{symbol_of, ChannelTable};
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
    let mut tot = [0.0f64; 6];
    for (g, _, chans) in &q.groups {
        if q.codebooks.iter().any(|c| c.0 == *g) {
            println!("{:?}: codebook, skipped", g);
            continue;
        }
        let mut t = [0.0f64; 6];
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
        }
        println!(
            "{:?}: stored {:.0} | ad-none {:.0} | ad-prev {:.0} | ad-prev×lower {:.0} | ad-rich {:.0} | rich p16 {:.0}",
            g,
            t[0] / 8.0,
            t[1] / 8.0,
            t[2] / 8.0,
            t[3] / 8.0,
            t[4] / 8.0,
            t[5] / 8.0
        );
        for k in 0..6 {
            tot[k] += t[k];
        }
    }
    println!(
        "total B: stored {:.0} | none {:.3} | prev {:.3} | prev×lower {:.3} | rich {:.3} | rich p16 {:.3}",
        tot[0] / 8.0,
        tot[1] / tot[0],
        tot[2] / tot[0],
        tot[3] / tot[0],
        tot[4] / tot[0],
        tot[5] / tot[0]
    );
}
