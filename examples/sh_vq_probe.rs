//! Does vector quantisation of the SH bands pay? (docs/codec.md, "SH vector quantisation")
//!
//! `cargo run --release --example sh_vq_probe -- SCENE.ply LAMBDA [K,K,…]`
//!
//! Runs the RD search at λ, then for each SH band of the chosen file replaces the band's
//! quantised rows by a significance-weighted k-means codebook of K rows (`rate::vq::kmeans`,
//! K capped at the band's distinct rows, where the codebook is the lossless palette) and
//! estimates the bytes the band would take: the codebook coded channel by channel with the
//! existing table coder (exact table bytes + ideal code length), the band's steps, and the
//! indices under one static-histogram table (K ≤ 4096; above, the ideal entropy plus 2 bytes of
//! table per row). Prints per (band, K): bytes now vs VQ, ΔD of the search's own views
//! (96², 8 orbit views), ΔJ = ΔD + λ·ΔR, and the `eval --orbit 8` PSNR of the whole file.

use gscodec::encoder::orbit_psnr;
use gscodec::io::read_scene;
use gscodec::rate::quantise::dequantise;
use gscodec::rate::rd::Evaluator;
use gscodec::rate::{self, tables, vq, Lambda};

fn index_bits(index: &[u32], k: usize) -> f64 {
    if k <= gscodec::decoder::entropy::MAX_SYMBOLS {
        let v: Vec<i32> = index.iter().map(|&i| i as i32).collect();
        return tables::choose(&v).total_bits();
    }
    let mut counts = vec![0f64; k];
    for &i in index {
        counts[i as usize] += 1.0;
    }
    let n = index.len() as f64;
    counts.iter().filter(|&&c| c > 0.0).map(|&c| -c * (c / n).log2()).sum::<f64>() + 16.0 * k as f64
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let scene = read_scene(args[1].as_ref()).expect("scene");
    let lambda: Lambda = args[2].parse().expect("λ");
    let ks: Vec<usize> =
        args.get(3).map_or(vec![64, 256, 1024, 4096], |s| s.split(',').map(|x| x.parse().expect("K")).collect());
    let t0 = std::time::Instant::now();
    let (chosen, _) = rate::rd::search(&scene, lambda, |_| {}).expect("search");
    let (bytes, report, q) = rate::encode(&scene, &chosen).expect("encode");
    let ev = Evaluator::new(&scene);
    let dec = dequantise(&q);
    let d0 = ev.distortion(&dec);
    let p0 = orbit_psnr(&scene, &dec);
    println!(
        "{}: λ {lambda}, {} → {} Gaussians, SH degree {}, {} B, D {d0:.3}, orbit PSNR {p0:.2} dB (search {:.1} s)",
        args[1],
        scene.len(),
        q.len(),
        q.sh_degree,
        bytes.len(),
        t0.elapsed().as_secs_f64()
    );
    let sig = rate::importance::significance(&dec);
    println!("| band | K | distinct rows | bytes now | VQ bytes (codebook + index) | ΔR B | ΔD | ΔJ | PSNR | k-means s |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let mut best_q = q.clone();
    let mut best_saving = 0usize;
    for gi in 0..q.groups.len() {
        let (g, steps, chans) = &q.groups[gi];
        if g.sh_band() == 0 {
            continue;
        }
        let now = report.groups.iter().find(|r| r.group == g.name()).map_or(0, |r| r.stream_bytes + r.table_bytes);
        let distinct = vq::palette(chans).len();
        let mut best: Option<(f64, Vec<Vec<i32>>, usize)> = None;
        for &k in &ks {
            let t = std::time::Instant::now();
            let cb = vq::kmeans(chans, &sig, k.min(distinct), 1);
            let secs = t.elapsed().as_secs_f64();
            let book: f64 = (0..cb.channels).map(|j| tables::choose(&cb.column(j)).total_bits()).sum::<f64>()
                + 8.0 * (4.0 * steps.len() as f64 + 3.0);
            let idx = index_bits(&cb.index, cb.len());
            let vq_bytes = ((book + idx) / 8.0).ceil() as usize;
            let mut q2 = q.clone();
            q2.groups[gi].2 = cb.decoded_channels();
            let dec2 = dequantise(&q2);
            let dd = ev.distortion(&dec2) - d0;
            let dr = vq_bytes as i64 - now as i64;
            let dj = dd + lambda.get() * (dr as f64 * 8.0 / 1e6);
            println!(
                "| {} | {} | {distinct} | {now} | {vq_bytes} ({:.0} + {:.0}) | {dr} | {dd:.3} | {dj:.3} | {:.2} | {secs:.1} |",
                g.name(),
                cb.len(),
                book / 8.0,
                idx / 8.0,
                orbit_psnr(&scene, &dec2)
            );
            if dj < 0.0 && best.as_ref().is_none_or(|b| dj < b.0) {
                best = Some((dj, q2.groups[gi].2.clone(), (now as i64 - vq_bytes as i64) as usize));
            }
        }
        if let Some((_, ch, saved)) = best {
            best_q.groups[gi].2 = ch;
            best_saving += saved;
        }
    }
    let dec = dequantise(&best_q);
    println!(
        "every band at its best K (ΔJ < 0): ≈{} B ({} B saved), D {:.3}, orbit PSNR {:.2} dB",
        bytes.len() - best_saving,
        best_saving,
        ev.distortion(&dec),
        orbit_psnr(&scene, &dec)
    );
}
