//! Does importance-adaptive quantisation pay? (probe, docs/codec.md)
//!
//! `cargo run --release --example class_probe -- SCENE.ply LAMBDA`
//!
//! Runs the RD search at λ (its importance classes turned off: the probe measures what they
//! could give), then splits the chosen file's Gaussians by significance into a
//! "low" class (the least significant fraction p) and codes the low class with every non-position
//! group's integer values coarsened by f (values round(v/f), decoded as f·round(v/f)). Bits are
//! estimated per channel with static histograms (one table per class), the same estimator for the
//! baseline ("one table": both classes under one table per channel). Prints ΔR, ΔD (the
//! search's views), ΔJ and orbit PSNR. Positions are left alone (one grid).

use gscodec::encoder::orbit_psnr;
use gscodec::io::read_scene;
use gscodec::rate::quantise::dequantise;
use gscodec::rate::rd::Evaluator;
use gscodec::rate::{self, tables, Lambda};

fn bits(v: &[i32]) -> f64 {
    if v.is_empty() {
        0.0
    } else {
        tables::choose(v).total_bits()
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let scene = read_scene(args[1].as_ref()).expect("scene");
    let lambda: Lambda = args[2].parse().expect("λ");
    let (chosen, _) = rate::rd::search(&scene, lambda, |_| {}).expect("search");
    let chosen = rate::EncodeConfig { tail: rate::CoarseTail::OFF, ..chosen };
    let (bytes, _report, q) = rate::encode(&scene, &chosen).expect("encode");
    let ev = Evaluator::new(&scene);

    let dec = dequantise(&q);
    let d0 = ev.distortion(&dec);
    let p0 = orbit_psnr(&scene, &dec);
    let sig = rate::importance::significance(&dec);
    let n = q.len();
    let vq: Vec<_> = q.codebooks.iter().map(|c| c.0).collect();
    let base_bits: f64 = q.groups.iter().filter(|g| !vq.contains(&g.0)).flat_map(|g| g.2.iter()).map(|c| bits(c)).sum();
    println!(
        "{}: λ {lambda}, {} Gaussians, SH {}, {} B, D {d0:.3}, PSNR {p0:.2}; non-position non-VQ est {:.0} B; codebooks {:?}",
        args[1],
        n,
        q.sh_degree,
        bytes.len(),
        base_bits / 8.0,
        vq
    );
    let mut rank: Vec<usize> = (0..n).collect();
    rank.sort_by(|&a, &b| sig[a].total_cmp(&sig[b]));
    println!("| p | f | groups | ΔR B | ΔR % file | ΔR one table B | ΔD | ΔJ | PSNR | ΔPSNR |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let sets: Vec<(&str, Vec<&str>)> =
        vec![("all", vec![]), ("sh", vec!["sh_dc", "sh_band1", "sh_band2", "sh_band3"]), ("geom", vec!["scale", "rotation", "opacity"])];
    for p in [0.25, 0.5] {
        let cut = (n as f64 * p) as usize;
        let mut low = vec![false; n];
        for &i in &rank[..cut] {
            low[i] = true;
        }
        for f in [2, 3] {
            for (set_name, set) in &sets {
                let mut q2 = q.clone();
                let mut new_bits = 0.0;
                let mut shared_bits = 0.0;
                for (g, _, chans) in q2.groups.iter_mut() {
                    if vq.contains(g) {
                        continue;
                    }
                    let on = set.is_empty() || set.contains(&g.name());
                    for (ci, c) in chans.iter_mut().enumerate() {
                        let rot_index = *g == gscodec::rate::group::Group::Rotation && ci == 0;
                        let (mut hi_v, mut lo_v) = (Vec::new(), Vec::new());
                        for (i, v) in c.iter_mut().enumerate() {
                            if low[i] && on && !rot_index {
                                let r = (*v as f64 / f as f64).round() as i32;
                                lo_v.push(r);
                                *v = r * f;
                            } else if low[i] {
                                lo_v.push(*v);
                            } else {
                                hi_v.push(*v);
                            }
                        }
                        new_bits += bits(&hi_v) + bits(&lo_v);
                        shared_bits += bits(c);
                    }
                }
                let dec2 = dequantise(&q2);
                let dd = ev.distortion(&dec2) - d0;
                let dr = (new_bits - base_bits) / 8.0;
                let drs = (shared_bits - base_bits) / 8.0;
                let dj = dd + lambda.get() * dr * 8.0 / 1e6;
                let p2 = orbit_psnr(&scene, &dec2);
                println!(
                    "| {p} | {f} | {set_name} | {dr:.0} | {:.1} | {drs:.0} | {dd:.3} | {dj:.3} | {p2:.2} | {:.2} |",
                    100.0 * dr / bytes.len() as f64,
                    p2 - p0
                );
            }
        }
    }
}
