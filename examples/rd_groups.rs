//! Where the bytes and the error go (docs/codec.md, "Where the bytes and the error go").
//!
//! `cargo run --release --example rd_groups -- SCENE.ply LAMBDA [SCENE.spz]`
//!
//! Runs the RD search at λ, then prints per attribute group: our bits per *input* Gaussian in the
//! chosen file, SPZ's (the compressed size of each attribute stream in the `.spz` file's table of
//! contents, SPZ v4), and the orbit PSNR (`eval --reference SCENE --orbit 8`: 8 views, 256², black
//! background, up −y) of a file where only that group takes the chosen setting and every other
//! group stays at the search's fine start (the λ = 0 steps, pruning at 1/255 only).

use gscodec::encoder::orbit_psnr;
use gscodec::io::read_scene;
use gscodec::rate::group::Group;
use gscodec::rate::quantise::{dequantise, Steps};
use gscodec::rate::{self, EncodeConfig, Lambda};

/// SPZ v4 streams, in file order (NgspFileHeader: 32 bytes, then a TOC of (compressed,
/// uncompressed) u64 pairs at `tocByteOffset`).
const SPZ_STREAMS: [&str; 6] = ["position", "opacity", "sh_dc", "scale", "rotation", "sh_rest"];

fn spz_streams(path: &str) -> Vec<(&'static str, u64)> {
    let d = std::fs::read(path).expect("spz");
    let u32_at = |o: usize| u32::from_le_bytes(d[o..o + 4].try_into().unwrap());
    assert_eq!(u32_at(4), 4, "SPZ version 4 expected");
    let streams = usize::from(d[15]);
    let toc = u32_at(16) as usize;
    (0..streams).map(|i| (SPZ_STREAMS[i], u64::from_le_bytes(d[toc + 16 * i..toc + 16 * i + 8].try_into().unwrap()))).collect()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let scene = read_scene(args[1].as_ref()).expect("scene");
    let lambda: Lambda = args[2].parse().expect("λ");
    let n = scene.len() as f64;
    let (chosen, _) = rate::rd::search(&scene, lambda, |_| {}).expect("search");
    let fine = EncodeConfig { steps: Steps::default().scaled(0.7), ..EncodeConfig::default() };
    let psnr_of = |c: &EncodeConfig| {
        let (bytes, _, q) = rate::encode(&scene, c).expect("encode");
        (bytes.len(), orbit_psnr(&scene, &dequantise(&q)))
    };
    let (all_bytes, all_psnr) = psnr_of(&chosen);
    let (_, r, _) = rate::encode(&scene, &chosen).expect("encode");
    let (fine_bytes, fine_psnr) = psnr_of(&fine);
    println!("{}: λ {lambda}, {} → {} Gaussians, SH degree {}", args[1], scene.len(), r.gaussians, r.sh_degree);
    println!("chosen: {all_bytes} B, {all_psnr:.2} dB; fine start: {fine_bytes} B, {fine_psnr:.2} dB");
    println!(
        "chosen steps: {:?}, min_opacity {}/255, min_removal_error {:e}, sh_drop {:?}",
        chosen.steps,
        chosen.min_opacity * 255.0,
        chosen.min_removal_error,
        chosen.sh_drop
    );
    let spz = args.get(3).map(|p| spz_streams(p)).unwrap_or_default();
    let spz_bits = |names: &[&str]| -> String {
        if spz.is_empty() {
            return "—".into();
        }
        format!("{:.1}", spz.iter().filter(|s| names.contains(&s.0)).map(|s| s.1).sum::<u64>() as f64 * 8.0 / n)
    };
    println!("| group | ours bits/G | SPZ bits/G | PSNR, this group alone at the chosen setting |");
    println!("|---|---|---|---|");
    let ours = |g: &str| r.groups.iter().find(|x| x.group == g).map_or(0.0, |x| 8.0 * (x.stream_bytes + x.table_bytes) as f64 / n);
    for g in Group::ALL {
        let mut c = fine;
        *c.steps.of_mut(g) = chosen.steps.of(g);
        if g.sh_band() > 0 {
            c.steps.rest_deadzone = chosen.steps.rest_deadzone;
            c.sh_drop[usize::from(g.sh_band()) - 1] = chosen.sh_drop[usize::from(g.sh_band()) - 1];
        }
        let spz_col = match g {
            Group::Sh1 => spz_bits(&["sh_rest"]) + " (all bands)",
            Group::Sh2 | Group::Sh3 => String::new(),
            _ => spz_bits(&[g.name()]),
        };
        println!("| {} | {:.1} | {spz_col} | {:.2} |", g.name(), ours(g.name()), psnr_of(&c).1);
    }
    let prune = EncodeConfig { min_opacity: chosen.min_opacity, min_removal_error: chosen.min_removal_error, ..fine };
    println!("| pruning ({} kept) | | | {:.2} |", r.gaussians, psnr_of(&prune).1);
    let (b, p) = psnr_of(&EncodeConfig { sh_drop: [0.0; 3], ..chosen });
    println!("| chosen without SH band dropping: {b} B | | | {p:.2} |");
    let deg = EncodeConfig { max_sh_degree: chosen.max_sh_degree, ..fine };
    println!("| SH degree {} | | | {:.2} |", chosen.max_sh_degree, psnr_of(&deg).1);
    let total: f64 = r.groups.iter().map(|x| 8.0 * (x.stream_bytes + x.table_bytes) as f64).sum::<f64>() / n;
    let spz_total = if spz.is_empty() { "—".into() } else { format!("{:.1}", spz.iter().map(|s| s.1).sum::<u64>() as f64 * 8.0 / n) };
    println!("| all (streams + tables) | {total:.1} | {spz_total} | {all_psnr:.2} |");
}
