//! Empirical entropy of each quantised channel, plain and conditioned on candidate contexts (the
//! previous Gaussian's value in Morton order, the previous channel of the same Gaussian, both):
//! the measurement behind the context tables of format 3.0 (docs/codec.md). Table costs are not
//! counted, so these are lower bounds.
//!
//! `cargo run --release --example ctx_probe -- SCENE.ply LAMBDA`
use gscodec::io::ply::read_ply;
use gscodec::rate::{self, quantise};
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
}
