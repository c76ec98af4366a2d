//! Per-point sweep results and the tables and plots made from them: `rd.csv`, `rd.svg`,
//! `time.svg`, `summary.json`, and the BD-rates of each loss against the anchor loss.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::io::atomic::write_bytes_atomic;
use crate::metrics::bdrate::{bd_rate, Interpolation, RdPoint};
use crate::metrics::plot::{Figure, Panel, Series};
use crate::{Error, Result};

/// Header of `rd.csv` (DESIGN §10).
pub const CSV_HEADER: &str = "lambda,loss,bytes,gaussians,psnr,ssim,ms_ssim,flip,wd,encode_s,decode_s";

/// The loss every other loss is compared with in BD-rates.
pub const ANCHOR_LOSS: &str = "l1ssim";

/// File name of a finished point's result inside its point directory.
pub const RESULT_FILE: &str = "result.json";

/// One sample of the encoder's held-out-error time series (its `--report`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TimelinePoint {
    /// Wall time since the encode started, seconds.
    pub time_s: f64,
    /// Held-out PSNR (dB), if reported.
    pub psnr: Option<f64>,
    /// Held-out WD, if reported.
    pub wd: Option<f64>,
}

/// The outcome of one (λ, loss) point: a row of `rd.csv` plus the encode's time series.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PointResult {
    /// λ passed to `encode --lambda`.
    pub lambda: f64,
    /// Distortion loss passed to `encode --loss`.
    pub loss: String,
    /// `encode --iters` (None: the encoder's default).
    #[serde(default)]
    pub iters: Option<usize>,
    /// `encode --seed` (0 in results written before it was an option).
    #[serde(default)]
    pub seed: u64,
    /// Retraining iterations the point ran with ([`super::Plan::retrain_iters_applied`]; 0 in
    /// results written before retraining existed).
    #[serde(default)]
    pub retrain_iters: usize,
    /// WD's feature space (`--features`) of a `wd` / `wdr` point; None for `l1ssim`, and in
    /// results written before it was an option (`pyramid` then).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wd_features: Option<String>,
    /// WD's σ (`--wd-sigma`) of a `wd` / `wdr` point; None for `l1ssim`, and in results written
    /// before σ was an option (σ = 4 then).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wd_sigma: Option<f64>,
    /// WD's warm-up share (`--wd-warmup`) of a `wd` / `wdr` point; None for `l1ssim`, and in
    /// results written before it was an option (0.1 then).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wd_warmup: Option<f64>,
    /// `encode --max-gaussians` (None: the encoder's default, and in results written before it
    /// was an option).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_gaussians: Option<usize>,
    /// `encode --init`: the trained scene the point coded against the dataset (None: trained
    /// from the images).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub init: Option<String>,
    /// What the RD search measured `D` with (`encode --search-distortion`; `mse` in results
    /// written before it was an option).
    #[serde(default)]
    pub search_distortion: crate::encoder::SearchDistortion,
    /// Size of the `.gsc` bitstream.
    pub bytes: u64,
    /// Gaussians in the decoded scene.
    pub gaussians: u64,
    /// Held-out PSNR (dB).
    pub psnr: Option<f64>,
    /// Held-out SSIM.
    pub ssim: Option<f64>,
    /// Held-out MS-SSIM (absent when the views are too small for 5 scales).
    pub ms_ssim: Option<f64>,
    /// Held-out mean ꟻLIP.
    pub flip: Option<f64>,
    /// Held-out WD (pyramid features).
    pub wd: Option<f64>,
    /// Wall time of the encode, seconds.
    pub encode_s: f64,
    /// Wall time of the decode, seconds.
    pub decode_s: f64,
    /// Held-out error against encode wall time, from the encode report.
    #[serde(default)]
    pub timeline: Vec<TimelinePoint>,
}

/// A quality metric of the RD table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Metric {
    Psnr,
    Ssim,
    MsSsim,
    Flip,
    Wd,
}

impl Metric {
    /// All metrics, in `rd.csv` column order.
    pub const ALL: [Metric; 5] = [Metric::Psnr, Metric::Ssim, Metric::MsSsim, Metric::Flip, Metric::Wd];

    /// Column name.
    pub fn name(self) -> &'static str {
        match self {
            Metric::Psnr => "psnr",
            Metric::Ssim => "ssim",
            Metric::MsSsim => "ms_ssim",
            Metric::Flip => "flip",
            Metric::Wd => "wd",
        }
    }

    /// Axis label, with the direction of "better".
    pub fn label(self) -> &'static str {
        match self {
            Metric::Psnr => "PSNR (dB, higher is better)",
            Metric::Ssim => "SSIM (higher is better)",
            Metric::MsSsim => "MS-SSIM (higher is better)",
            Metric::Flip => "FLIP (lower is better)",
            Metric::Wd => "WD (lower is better)",
        }
    }

    /// This metric's value in a point result.
    pub fn of(self, p: &PointResult) -> Option<f64> {
        match self {
            Metric::Psnr => p.psnr,
            Metric::Ssim => p.ssim,
            Metric::MsSsim => p.ms_ssim,
            Metric::Flip => p.flip,
            Metric::Wd => p.wd,
        }
        .filter(|v| v.is_finite())
    }
}

/// Sorts results by loss, then λ (descending, so sizes grow down a loss's rows), then seed.
pub fn sort_results(rows: &mut [PointResult]) {
    rows.sort_by(|a, b| a.loss.cmp(&b.loss).then(b.lambda.total_cmp(&a.lambda)).then(a.seed.cmp(&b.seed)));
}

/// The training seeds of the rows, ascending.
pub fn seeds(rows: &[PointResult]) -> Vec<u64> {
    let mut s: Vec<u64> = rows.iter().map(|r| r.seed).collect();
    s.sort_unstable();
    s.dedup();
    s
}

/// One row per (loss, λ): the mean over its seeds of the size, the Gaussian count, each metric
/// (over the seeds that have it) and the times, with the lowest seed's other fields and no time
/// series; sorted. With one seed per (loss, λ) these are the rows. The RD table, plot and
/// BD-rates of a sweep with several seeds are of these mean points.
pub fn mean_rows(rows: &[PointResult]) -> Vec<PointResult> {
    let mut sorted = rows.to_vec();
    sort_results(&mut sorted);
    let mut out: Vec<PointResult> = Vec::new();
    for group in sorted.chunk_by(|a, b| a.loss == b.loss && a.lambda == b.lambda) {
        let n = group.len() as f64;
        let mean = |f: &dyn Fn(&PointResult) -> f64| group.iter().map(f).sum::<f64>() / n;
        let mean_of = |m: Metric| {
            let v: Vec<f64> = group.iter().filter_map(|r| m.of(r)).collect();
            (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
        };
        out.push(PointResult {
            bytes: mean(&|r| r.bytes as f64).round() as u64,
            gaussians: mean(&|r| r.gaussians as f64).round() as u64,
            psnr: mean_of(Metric::Psnr),
            ssim: mean_of(Metric::Ssim),
            ms_ssim: mean_of(Metric::MsSsim),
            flip: mean_of(Metric::Flip),
            wd: mean_of(Metric::Wd),
            encode_s: mean(&|r| r.encode_s),
            decode_s: mean(&|r| r.decode_s),
            timeline: Vec::new(),
            ..group[0].clone()
        });
    }
    out
}

/// Reads every finished point (`DIR/points/*/result.json`), sorted by [`sort_results`].
///
/// # Errors
/// A result file that cannot be read or parsed (exit 2, naming the file).
pub fn read_results(dir: &Path) -> Result<Vec<PointResult>> {
    let points = dir.join("points");
    let mut rows = Vec::new();
    let entries = match std::fs::read_dir(&points) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(rows),
        Err(e) => return Err(Error::input(&points, e)),
    };
    let mut files: Vec<PathBuf> = entries.filter_map(|e| e.ok()).map(|e| e.path().join(RESULT_FILE)).filter(|p| p.is_file()).collect();
    files.sort();
    for f in files {
        rows.push(read_result(&f)?);
    }
    sort_results(&mut rows);
    Ok(rows)
}

/// Reads one point result file.
///
/// # Errors
/// Unreadable or malformed file (exit 2, naming it).
pub fn read_result(path: &Path) -> Result<PointResult> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::input(path, e))?;
    serde_json::from_str(&text).map_err(|e| Error::input(path, format!("not a sweep point result: {e}")))
}

/// `rd.csv`: [`CSV_HEADER`] and one row per point; missing metrics are empty fields.
pub fn to_csv(rows: &[PointResult]) -> String {
    let opt = |v: Option<f64>| v.map(|v| format!("{v}")).unwrap_or_default();
    let mut s = format!("{CSV_HEADER}\n");
    for r in rows {
        s.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{:.6},{:.6}\n",
            r.lambda,
            r.loss,
            r.bytes,
            r.gaussians,
            opt(r.psnr),
            opt(r.ssim),
            opt(r.ms_ssim),
            opt(r.flip),
            opt(r.wd),
            r.encode_s,
            r.decode_s
        ));
    }
    s
}

/// Losses in first-seen order of sorted rows, with the anchor first when present.
fn losses(rows: &[PointResult]) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for r in rows {
        if !out.contains(&r.loss) {
            out.push(r.loss.clone());
        }
    }
    out.sort_by_key(|l| l != ANCHOR_LOSS);
    out
}

/// BD-rate of one loss against the anchor on one metric.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BdEntry {
    /// The compared loss.
    pub loss: String,
    /// Metric column name.
    pub metric: &'static str,
    /// BD-rate in percent (negative: smaller than the anchor at equal quality), when computable.
    pub bd_rate: Option<f64>,
    /// Why it is not computable.
    pub note: Option<String>,
}

/// The RD curve of one loss on one metric: (bytes, value) of the points having that metric.
fn curve(rows: &[PointResult], loss: &str, metric: Metric) -> Vec<RdPoint> {
    rows.iter().filter(|r| r.loss == loss).filter_map(|r| metric.of(r).map(|q| RdPoint { rate: r.bytes as f64, quality: q })).collect()
}

/// PCHIP BD-rate of every non-anchor loss against [`ANCHOR_LOSS`] on every metric.
pub fn bd_rates(rows: &[PointResult]) -> Vec<BdEntry> {
    let mut out = Vec::new();
    for loss in losses(rows).into_iter().filter(|l| l != ANCHOR_LOSS) {
        for m in Metric::ALL {
            let anchor = curve(rows, ANCHOR_LOSS, m);
            let (bd, note) = if anchor.is_empty() {
                (None, Some(format!("no {ANCHOR_LOSS} points")))
            } else {
                match bd_rate(&anchor, &curve(rows, &loss, m), Interpolation::Pchip) {
                    Ok(v) => (Some(v), None),
                    Err(e) => (None, Some(e.to_string())),
                }
            };
            out.push(BdEntry { loss: loss.clone(), metric: m.name(), bd_rate: bd, note });
        }
    }
    out
}

/// The BD-rates of a sweep: of its (mean) curves, and with several seeds of each seed's own.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepBd {
    /// BD-rates of the curves of [`mean_rows`].
    pub mean: Vec<BdEntry>,
    /// Each seed's BD-rates from its own points; empty for a sweep with one seed.
    pub by_seed: Vec<(u64, Vec<BdEntry>)>,
}

impl SweepBd {
    /// The BD-rates of `rows`: see [`SweepBd`].
    pub fn of(rows: &[PointResult]) -> SweepBd {
        let seeds = seeds(rows);
        let by_seed = if seeds.len() > 1 {
            seeds.iter().map(|&s| (s, bd_rates(&rows.iter().filter(|r| r.seed == s).cloned().collect::<Vec<_>>()))).collect()
        } else {
            Vec::new()
        };
        SweepBd { mean: bd_rates(&mean_rows(rows)), by_seed }
    }
}

/// Human-readable BD-rate lines, as the sweep prints them; with several seeds each line ends with
/// the seeds' own values.
pub fn bd_report(bd: &SweepBd) -> String {
    let value = |e: &BdEntry| match (e.bd_rate, &e.note) {
        (Some(v), _) => format!("{v:+.2}%"),
        (None, note) => format!("n/a ({})", note.as_deref().unwrap_or("")),
    };
    let mut s = String::new();
    for e in &bd.mean {
        s.push_str(&format!("BD-rate {} vs {ANCHOR_LOSS} on {}: {}", e.loss, e.metric, value(e)));
        if !bd.by_seed.is_empty() {
            let each: Vec<String> = bd
                .by_seed
                .iter()
                .map(|(seed, v)| match v.iter().find(|o| o.loss == e.loss && o.metric == e.metric) {
                    Some(o) => format!("seed {seed} {}", value(o)),
                    None => format!("seed {seed} n/a (no {} points)", e.loss),
                })
                .collect();
            s.push_str(&format!(" (mean of {} seeds; {})", bd.by_seed.len(), each.join(", ")));
        }
        s.push('\n');
    }
    s
}

/// `rd.svg`: size (log bytes) against each metric, one curve per loss.
pub fn rd_figure(rows: &[PointResult]) -> Figure {
    let panels = Metric::ALL
        .iter()
        .map(|&m| {
            let mut p = Panel::new(m.name().to_uppercase().replace('_', "-"), "size (bytes, log)", m.label()).log_x(true);
            for loss in losses(rows) {
                let mut pts: Vec<(f64, f64)> = curve(rows, &loss, m).iter().map(|p| (p.rate, p.quality)).collect();
                pts.sort_by(|a, b| a.0.total_cmp(&b.0));
                p = p.series(Series::new(loss, pts));
            }
            p
        })
        .collect();
    Figure::new(panels)
}

/// `time.svg`: held-out PSNR and WD against encode wall time, one panel per loss and error
/// measure, one curve per run (λ). Panels without any reported values are left out.
pub fn time_figure(rows: &[PointResult]) -> Figure {
    let mut panels = Vec::new();
    let measures: [(&str, &str, fn(&TimelinePoint) -> Option<f64>); 2] =
        [("PSNR", "held-out PSNR (dB)", |t| t.psnr), ("WD", "held-out WD", |t| t.wd)];
    for (name, label, get) in measures {
        for loss in losses(rows) {
            let mut p = Panel::new(format!("{loss}: {name} during encode"), "encode wall time (s)", label);
            for r in rows.iter().filter(|r| r.loss == loss) {
                let pts: Vec<(f64, f64)> = r.timeline.iter().filter_map(|t| get(t).map(|v| (t.time_s, v))).collect();
                let name = match r.seed {
                    0 => format!("λ={}", r.lambda),
                    s => format!("λ={} seed {s}", r.lambda),
                };
                p = p.series(Series::new(name, pts));
            }
            if p.series.iter().any(|s| !s.points.is_empty()) {
                panels.push(p);
            }
        }
    }
    let columns = losses(rows).len().clamp(1, 3);
    Figure { columns, ..Figure::new(panels) }
}

/// `{<loss>: {<metric>: BD-rate or null}}` and the same map of the notes.
fn bd_maps(bd: &[BdEntry]) -> (serde_json::Value, serde_json::Value) {
    let mut rates = serde_json::Map::new();
    let mut notes = serde_json::Map::new();
    for e in bd {
        rates.entry(e.loss.clone()).or_insert_with(|| serde_json::json!({}))[e.metric] = serde_json::json!(e.bd_rate);
        if let Some(n) = &e.note {
            notes.entry(e.loss.clone()).or_insert_with(|| serde_json::json!({}))[e.metric] = serde_json::json!(n);
        }
    }
    (rates.into(), notes.into())
}

/// `summary.json`: the points (every seed's), the BD-rates and how the sweep was run.
/// `bd_rate.<loss>.<metric>` is the BD-rate of `loss` against [`ANCHOR_LOSS`] in percent
/// (negative: a saving) of the mean curves, or null with the reason in
/// `bd_rate_notes.<loss>.<metric>`; with several seeds, `bd_rate_by_seed.<seed>.<loss>.<metric>`
/// (and `bd_rate_notes_by_seed`) are each seed's own.
pub fn summary_json(rows: &[PointResult], bd: &SweepBd, settings: serde_json::Value) -> serde_json::Value {
    let (rates, notes) = bd_maps(&bd.mean);
    let mut extra = serde_json::Map::new();
    if !bd.by_seed.is_empty() {
        let (mut by_seed, mut notes_by_seed) = (serde_json::Map::new(), serde_json::Map::new());
        for (seed, entries) in &bd.by_seed {
            let (r, n) = bd_maps(entries);
            by_seed.insert(seed.to_string(), r);
            notes_by_seed.insert(seed.to_string(), n);
        }
        extra.insert("bd_rate_by_seed".into(), by_seed.into());
        extra.insert("bd_rate_notes_by_seed".into(), notes_by_seed.into());
    }
    let mut v = serde_json::json!({
        "anchor": ANCHOR_LOSS,
        "bd_method": "pchip",
        "settings": settings,
        "points": rows.iter().map(|r| {
            let mut v = serde_json::to_value(r).unwrap_or_default();
            if let Some(o) = v.as_object_mut() { o.remove("timeline"); }
            v
        }).collect::<Vec<_>>(),
        "bd_rate": rates,
        "bd_rate_notes": notes,
    });
    v.as_object_mut().expect("an object").extend(extra);
    v
}

/// Writes `rd.csv`, `rd.svg` (both of [`mean_rows`]), `time.svg` and `summary.json` into `dir`
/// (each atomically) and returns the BD-rates.
///
/// # Errors
/// Failure to write an output (exit 1).
pub fn write_outputs(dir: &Path, rows: &[PointResult], settings: serde_json::Value) -> Result<SweepBd> {
    std::fs::create_dir_all(dir).map_err(|e| Error::failure(dir, e))?;
    let bd = SweepBd::of(rows);
    let table = mean_rows(rows);
    write_bytes_atomic(&dir.join("rd.csv"), to_csv(&table).as_bytes())?;
    write_bytes_atomic(&dir.join("rd.svg"), rd_figure(&table).to_svg().as_bytes())?;
    write_bytes_atomic(&dir.join("time.svg"), time_figure(rows).to_svg().as_bytes())?;
    let summary = serde_json::to_string_pretty(&summary_json(rows, &bd, settings)).unwrap_or_default();
    write_bytes_atomic(&dir.join("summary.json"), summary.as_bytes())?;
    Ok(bd)
}
