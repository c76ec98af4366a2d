//! BD-rates (PCHIP, `metrics::bdrate`) of RD curves given as `DIR/<name>-<λ>.gsc` files (the rate)
//! with `DIR/<name>-<λ>.eval.json` (`gscodec eval … --json`: psnr, ms_ssim, flip, wd), each curve
//! against the anchor's. Prints the points and one row per tested curve.
//!
//! `cargo run --example bd_table -- DIR ANCHOR NAME...`

use gscodec::metrics::bdrate::{bd_rate, Interpolation, RdPoint};

const METRICS: [&str; 4] = ["flip", "ms_ssim", "psnr", "wd"];

fn curve(dir: &std::path::Path, name: &str) -> Vec<(f64, serde_json::Value)> {
    let mut pts = Vec::new();
    for e in std::fs::read_dir(dir).expect("readable DIR") {
        let p = e.unwrap().path();
        let file = p.file_name().unwrap().to_string_lossy().to_string();
        let Some(rest) = file.strip_prefix(&format!("{name}-")) else { continue };
        let Some(lam) = rest.strip_suffix(".eval.json") else { continue };
        let Ok(bytes) = std::fs::metadata(dir.join(format!("{name}-{lam}.gsc"))).map(|m| m.len()) else { continue };
        let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).expect("eval json");
        println!(
            "{name:<8} λ={lam:<5} bytes={bytes:<8} psnr={:.3} ms_ssim={:.4} flip={:.4} wd={:.4}",
            v["psnr"].as_f64().unwrap_or(f64::NAN),
            v["ms_ssim"].as_f64().unwrap_or(f64::NAN),
            v["flip"].as_f64().unwrap_or(f64::NAN),
            v["wd"].as_f64().unwrap_or(f64::NAN)
        );
        pts.push((bytes as f64, v));
    }
    pts
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let dir = std::path::PathBuf::from(&args[1]);
    let anchor = curve(&dir, &args[2]);
    let pick = |c: &[(f64, serde_json::Value)], m: &str| -> Vec<RdPoint> {
        c.iter().map(|(r, v)| RdPoint { rate: *r, quality: v[m].as_f64().unwrap_or(f64::NAN) }).collect()
    };
    let tests: Vec<(String, Vec<(f64, serde_json::Value)>)> = args[3..].iter().map(|n| (n.clone(), curve(&dir, n))).collect();
    println!("BD-rate vs {} (percent, negative = smaller files at equal quality)", args[2]);
    println!("{:<8} {:>10} {:>10} {:>10} {:>10}", "curve", METRICS[0], METRICS[1], METRICS[2], METRICS[3]);
    for (n, c) in &tests {
        print!("{n:<8}");
        for m in METRICS {
            match bd_rate(&pick(&anchor, m), &pick(c, m), Interpolation::Pchip) {
                Ok(b) => print!(" {b:>10.1}"),
                Err(e) => print!(" {:>10}", format!("n/a ({e})").chars().take(10).collect::<String>()),
            }
        }
        println!();
    }
}
