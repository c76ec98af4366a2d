//! `gscodec info`: what a `.gsc` file holds (version, counts, importance levels, per-section bytes,
//! what was left out).

use std::path::PathBuf;

use gscodec_decoder::inspect;
use serde_json::json;

use crate::Error;

/// Describe a .gsc file.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Input .gsc file.
    pub input: PathBuf,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
    /// Accepted for uniformity (info prints no progress).
    #[arg(long)]
    pub quiet: bool,
}

pub fn run(args: Args) -> crate::Result<()> {
    let bytes = std::fs::read(&args.input).map_err(|e| Error::input(&args.input, e))?;
    let info = inspect(&bytes).map_err(|e| Error::input(&args.input, e))?;
    let h = info.info.header;
    let input_gaussians = info.encoder.map(|e| e.input_gaussians);
    let input_sh_degree = info.encoder.map(|e| e.input_sh_degree);
    let pruned = input_gaussians.map(|g| g.saturating_sub(h.gaussians));
    let dropped_bands = input_sh_degree.map(|d| d.saturating_sub(h.sh_degree));
    let mut groups: Vec<(String, usize)> = Vec::new();
    for s in &info.info.sections {
        match groups.iter_mut().find(|g| g.0 == s.name) {
            Some(g) => g.1 += s.bytes,
            None => groups.push((s.name.to_string(), s.bytes)),
        }
    }
    if args.json {
        let sections: Vec<_> = info
            .info
            .sections
            .iter()
            .map(|s| json!({"kind": s.kind, "chunk": s.chunk, "name": s.name, "optional": s.optional, "bytes": s.bytes}))
            .collect();
        let v = json!({
            "version": format!("{}.{}", h.version_major, h.version_minor),
            "gaussians": h.gaussians,
            "sh_degree": h.sh_degree,
            "bytes": info.info.file_bytes,
            "sections": sections,
            "levels": info.levels,
            "level_step_factors": info.level_step_factors,
            "group_bytes": groups.iter().map(|(n, b)| (n.clone(), json!(b))).collect::<serde_json::Map<_, _>>(),
            "left_out": {
                "pruned_gaussians": pruned,
                "input_gaussians": input_gaussians,
                "input_sh_degree": input_sh_degree,
                "dropped_sh_bands": dropped_bands,
                "constant_channels": info.constant_channels,
            },
            "context_channels": info.context_channels,
            "neighbour_channels": info.neighbour_channels,
            "profile": if info.anchors.is_some() { "anchor" } else { "explicit" },
            "anchors": info.anchors.as_ref().map(|a| json!({
                "anchors": a.anchors,
                "features": a.features,
                "anchor_cells": 1u32 << a.shift,
                "mlp_widths": a.widths,
            })),
            "sh_bands": (1..=h.sh_degree).map(|b| {
                let k = info.codebooks.iter().find(|c| c.0 == b).map(|c| c.1);
                let shared = info.shared_index.contains(&b);
                json!({"band": b, "mode": if k.is_some() { "codebook" } else { "per-coefficient" }, "codebook_rows": k, "index_of_band_below": shared})
            }).collect::<Vec<_>>(),
        });
        println!("{v}");
    } else {
        println!("{}: gscodec bitstream version {}.{}", args.input.display(), h.version_major, h.version_minor);
        println!("gaussians   {}", h.gaussians);
        println!("sh_degree   {}", h.sh_degree);
        println!("bytes       {}", info.info.file_bytes);
        if info.levels.len() > 1 {
            let sizes: Vec<String> = info.levels.iter().map(|k| k.to_string()).collect();
            println!("levels      {}: {} Gaussians", info.levels.len(), sizes.join(" + "));
        }
        if !info.level_step_factors.is_empty() {
            let f: Vec<String> = info.level_step_factors.iter().map(|f| format!("×{f}")).collect();
            println!("classes     steps per level (scale step over level 0's): {}", f.join(", "));
        }
        for (name, b) in &groups {
            println!("  {name:<10} {b:>10} bytes");
        }
        if let Some(p) = pruned {
            println!("left out: {p} pruned Gaussians of {}", input_gaussians.unwrap_or(0));
        }
        if let (Some(d), Some(n)) = (input_sh_degree, dropped_bands) {
            println!("left out: {n} SH band(s) (input degree {d})");
        }
        if let Some(a) = &info.anchors {
            let widths: Vec<String> = a.widths.iter().map(|w| w.to_string()).collect();
            println!(
                "profile     anchor: {} anchors of {}³ grid cells, {} features each; MLP {}",
                a.anchors,
                1u32 << a.shift,
                a.features,
                widths.join(" → ")
            );
        }
        for b in (1..=h.sh_degree).filter(|_| info.anchors.is_none()) {
            match info.codebooks.iter().find(|c| c.0 == b) {
                Some((_, k)) if info.shared_index.contains(&b) => {
                    println!("sh_band{b}    codebook of {k} rows, indexed by sh_band{}'s index", b - 1)
                }
                Some((_, k)) => println!("sh_band{b}    codebook of {k} rows, one index per Gaussian"),
                None => println!("sh_band{b}    per coefficient"),
            }
        }
        if !info.context_channels.is_empty() {
            println!("context-coded: {}", info.context_channels.join(", "));
        }
        if !info.neighbour_channels.is_empty() {
            println!("neighbour-coded: {}", info.neighbour_channels.join(", "));
        }
        if !info.constant_channels.is_empty() {
            println!("stored once (constant): {}", info.constant_channels.join(", "));
        }
    }
    Ok(())
}
