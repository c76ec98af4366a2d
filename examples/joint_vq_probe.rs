//! Would one codebook for all SH bands together pay? (docs/codec.md §28)
//!
//! `cargo run --release --example joint_vq_probe -- SCENE.ply LAMBDA [K,K,…]`
//!
//! Runs the RD search at λ, then codes the chosen file's SH bands 1..=D two ways, both with the
//! project's k-means ([`vq::kmeans`]: integer rows, each weighted by its Gaussian's significance):
//! each band by its own codebook of the K the search chose (the file's codebooks, computed again
//! with these weights), and all bands by one codebook whose row holds every band's coefficients,
//! one index per Gaussian (what `EncodeConfig::sh_joint` now codes, format 9.0). Bytes are estimated by the file's own table coder
//! (codebook columns with neighbour contexts, rows sorted; indices in file order), D on the
//! search's views; prints ΔR, ΔD and ΔJ of the joint codebook against the separate ones.
//! Importance classes are off in both (they do not touch codebook bands).

use gscodec::io::read_scene;
use gscodec::rate::quantise::dequantise;
use gscodec::rate::rd::Evaluator;
use gscodec::rate::{self, tables, vq, CoarseTail, EncodeConfig, Lambda};

/// The project's k-means ([`vq::kmeans`]) on rows of `dims` values (`data` row-major).
/// Returns (rows, index).
fn kmeans(data: &[i32], dims: usize, w: &[f32], k: usize, seed: u64) -> (Vec<i32>, Vec<u32>) {
    let chans: Vec<Vec<i32>> = (0..dims).map(|t| data.iter().skip(t).step_by(dims).copied().collect()).collect();
    let cb = vq::kmeans(&chans, w, k, seed);
    (cb.rows, cb.index)
}

/// Bits of a codebook (columns with neighbour contexts) and its index channel.
fn bits(rows: &[i32], dims: usize, idx: &[u32]) -> (f64, f64) {
    let k = rows.len() / dims;
    let col = |t: usize| -> Vec<i32> { (0..k).map(|j| rows[j * dims + t]).collect() };
    let mut book = 0.0;
    for t in 0..dims {
        let v = col(t);
        let lower = if t > 0 { col(t - 1) } else { Vec::new() };
        book += tables::histogram_only(&v, Some(&[0..k]), Some(&lower)).best.total_bits() + 32.0;
    }
    let iv: Vec<i32> = idx.iter().map(|&i| i as i32).collect();
    let ib = if k <= gscodec::decoder::entropy::MAX_SYMBOLS {
        tables::histogram_only(&iv, Some(&[0..iv.len()]), Some(&[])).best.total_bits()
    } else {
        let mut counts = vec![0f64; k];
        iv.iter().for_each(|&i| counts[i as usize] += 1.0);
        let n = iv.len() as f64;
        counts.iter().filter(|&&c| c > 0.0).map(|&c| -c * (c / n).log2()).sum::<f64>() + 16.0 * k as f64
    };
    (book, ib)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let scene = read_scene(args[1].as_ref()).expect("scene");
    let lambda: Lambda = args[2].parse().expect("λ");
    let ks: Vec<usize> = args.get(3).map_or(vec![1024, 2048, 4096, 8192], |s| s.split(',').map(|x| x.parse().expect("K")).collect());
    let (chosen, _) = rate::rd::search(&scene, lambda, |_| {}).expect("search");
    let (bytes, _, q) = rate::encode(&scene, &chosen).expect("encode");
    let ev = Evaluator::new(&scene);
    println!(
        "{}: λ {lambda}: {} B, {} Gaussians, SH K {:?}, steps {:?}, orbit D {:.4}",
        args[1],
        bytes.len(),
        q.len(),
        chosen.sh_vq,
        chosen.steps.sh_rest,
        ev.distortion(&dequantise(&q))
    );
    for (g, cb) in &q.codebooks {
        let (bb, ib) = bits(&cb.rows, cb.channels, &cb.index);
        println!("file {g:?}: K {} → codebook {:.0} B, index {:.0} B", cb.len(), bb / 8.0, ib / 8.0);
    }
    // The raw rows at the chosen steps: no codebooks, no classes.
    let raw_cfg = EncodeConfig { sh_vq: [0; 3], tail: CoarseTail::OFF, ..chosen };
    let (_, _, raw) = rate::encode(&scene, &raw_cfg).expect("encode");
    let sig: Vec<f32> = rate::importance::significance(&dequantise(&raw)).iter().map(|s| s + 1e-6).collect();
    let n = raw.len();
    let bands: Vec<usize> = (0..raw.groups.len()).filter(|&gi| raw.groups[gi].0.sh_band() > 0).collect();
    // Separate codebooks at the search's K (per-coefficient bands left as they are: skipped).
    let mut sep = raw.clone();
    let (mut sep_bits, mut dims_all) = (0.0, 0);
    let mut joint_data = vec![Vec::new(); n];
    for &gi in &bands {
        let (g, _, chans) = &raw.groups[gi];
        let b = usize::from(g.sh_band());
        let dims = chans.len();
        let data: Vec<i32> = (0..n).flat_map(|i| chans.iter().map(move |c| c[i])).collect();
        (0..n).for_each(|i| joint_data[i].extend(chans.iter().map(|c| c[i])));
        dims_all += dims;
        let k = chosen.sh_vq[b - 1] as usize;
        if k == 0 {
            println!("band {b}: per coefficient in the file; the joint codebook must replace that");
            continue;
        }
        let (rows, idx) = kmeans(&data, dims, &sig, k, b as u64);
        let (bb, ib) = bits(&rows, dims, &idx);
        println!("band {b}: K {} → codebook {:.0} B, index {:.0} B", rows.len() / dims, bb / 8.0, ib / 8.0);
        sep_bits += bb + ib;
        sep.groups[gi].2 = (0..dims).map(|t| idx.iter().map(|&i| rows[i as usize * dims + t]).collect()).collect();
    }
    let d_sep = ev.distortion(&dequantise(&sep));
    println!("separate: {:.0} B, D {d_sep:.4}", sep_bits / 8.0);
    let data: Vec<i32> = joint_data.concat();
    for k in ks {
        let (rows, idx) = kmeans(&data, dims_all, &sig, k, 0);
        let (bb, ib) = bits(&rows, dims_all, &idx);
        let mut jq = raw.clone();
        let mut off = 0;
        for &gi in &bands {
            let dims = jq.groups[gi].2.len();
            jq.groups[gi].2 = (0..dims).map(|t| idx.iter().map(|&i| rows[i as usize * dims_all + off + t]).collect()).collect();
            off += dims;
        }
        let d = ev.distortion(&dequantise(&jq));
        let dr = (bb + ib - sep_bits) / 8.0;
        let dj = d - d_sep + lambda.get() * dr * 8.0 / 1e6; // λ is per megabit
        println!(
            "joint K {k} ({} used): codebook {:.0} B + index {:.0} B, ΔR {dr:+.0} B, ΔD {:+.4}, ΔJ {dj:+.4}",
            rows.len() / dims_all,
            bb / 8.0,
            ib / 8.0,
            d - d_sep
        );
    }
}
