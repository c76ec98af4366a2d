//! λ sweeps: encode, decode and evaluate a scene at each (λ, loss) point, then tabulate and plot.
//!
//! | module | one job |
//! |---|---|
//! | [`results`] | per-point results, `rd.csv`, plots, BD-rates, `summary.json` |
//! | [`jobs`] | the sweep as independent jobs (Slurm array script, GNU parallel list) |
//!
//! Each point runs the `gscodec` executable itself (`encode`, `decode`, `eval --json`) as child
//! processes, so a point is exactly what a user would run by hand and a crashed point cannot take
//! the sweep down. A point is finished when `DIR/points/<loss>_lambda<λ>/result.json` exists;
//! finished points are skipped, which makes sweeps resumable.

pub mod jobs;
pub mod results;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use serde_json::Value;

use crate::io::atomic::write_bytes_atomic;
use crate::{Error, Result};
use results::{PointResult, TimelinePoint, RESULT_FILE};

/// Default λ grid of `sweep`, largest first (smallest files first).
///
/// `encode --lambda` is λ in `J = D + λ·R` with D = 255²·MSE of orbit renders and R in megabits
/// (larger: smaller files; 0: finest; the encoder's default is 20). The grid steps ×≈3 around
/// that default over two decades. Not yet re-measured with the RD-search encoder; see
/// `docs/sweep.md`.
pub const DEFAULT_LAMBDAS: [f64; 5] = [200.0, 60.0, 20.0, 6.0, 2.0];

/// Default losses compared by `sweep`.
pub const DEFAULT_LOSSES: [&str; 2] = ["l1ssim", "wdr"];

/// Losses `encode --loss` accepts.
pub const KNOWN_LOSSES: [&str; 3] = ["l1ssim", "wd", "wdr"];

/// Orbit views used to evaluate a sweep of a trained `.ply` (no held-out photos exist).
pub const PLY_EVAL_ORBIT: usize = 8;

/// One (λ, loss) point.
#[derive(Debug, Clone, PartialEq)]
pub struct Point {
    /// Rate weight.
    pub lambda: f64,
    /// Distortion loss name.
    pub loss: String,
}

impl Point {
    /// Directory name of the point: `<loss>_lambda<λ>`.
    pub fn dir_name(&self) -> String {
        format!("{}_lambda{}", self.loss, self.lambda)
    }
}

/// What to sweep and where.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// Dataset directory or trained `.ply`.
    pub input: PathBuf,
    /// Output directory.
    pub out: PathBuf,
    /// λ values.
    pub lambdas: Vec<f64>,
    /// Losses.
    pub losses: Vec<String>,
    /// `encode --iters`, or the encoder's default.
    pub iters: Option<usize>,
    /// Dataset options passed on to every `encode` and `eval` (`--downscale N`, …).
    pub dataset_args: Vec<String>,
}

impl Plan {
    /// Every point, loss-major, λ in the given order.
    pub fn points(&self) -> Vec<Point> {
        self.losses.iter().flat_map(|loss| self.lambdas.iter().map(|&lambda| Point { lambda, loss: loss.clone() })).collect()
    }

    /// Directory holding a point's files.
    pub fn point_dir(&self, p: &Point) -> PathBuf {
        self.out.join("points").join(p.dir_name())
    }

    /// Whether a point has a result file from the same settings (`--iters`); a result from other
    /// settings, or an unreadable one, is redone.
    pub fn is_done(&self, p: &Point) -> bool {
        results::read_result(&self.point_dir(p).join(RESULT_FILE)).is_ok_and(|r| r.iters == self.iters)
    }

    /// Checks λs and losses.
    ///
    /// # Errors
    /// A negative or non-finite λ, an unknown loss, or an empty grid (exit 2).
    pub fn validate(&self) -> Result<()> {
        let arg = Path::new("sweep");
        if self.lambdas.is_empty() || self.losses.is_empty() {
            return Err(Error::input(arg, "--lambdas and --loss need at least one value each"));
        }
        if let Some(l) = self.lambdas.iter().find(|l| !(l.is_finite() && **l >= 0.0)) {
            return Err(Error::input(arg, format!("--lambdas: {l} is not a finite value >= 0")));
        }
        if let Some(l) = self.losses.iter().find(|l| !KNOWN_LOSSES.contains(&l.as_str())) {
            return Err(Error::input(arg, format!("--loss: unknown loss '{l}' (expected one of {})", KNOWN_LOSSES.join(", "))));
        }
        Ok(())
    }

    /// The settings recorded in `summary.json`.
    pub fn settings(&self) -> Value {
        serde_json::json!({
            "input": self.input.display().to_string(),
            "lambdas": self.lambdas,
            "losses": self.losses,
            "iters": self.iters,
        })
    }

    /// Command line (after the executable) that runs just point `p` and records its result:
    /// what `--emit-jobs` writes, one per job.
    pub fn point_command(&self, p: &Point) -> Vec<String> {
        let mut c = vec![
            "sweep".to_string(),
            self.input.display().to_string(),
            "-o".into(),
            self.out.display().to_string(),
            "--lambdas".into(),
            p.lambda.to_string(),
            "--loss".into(),
            p.loss.clone(),
        ];
        if let Some(n) = self.iters {
            c.extend(["--iters".into(), n.to_string()]);
        }
        c.extend(self.dataset_args.iter().cloned());
        c.extend(["--points-only".into(), "--quiet".into()]);
        c
    }
}

/// Runs `exe` with `args`, appending its stdout/stderr to `log`; returns stdout and wall seconds.
fn run_child(exe: &Path, args: &[String], log: &Path, what: &str) -> Result<(String, f64)> {
    let start = Instant::now();
    let out = Command::new(exe).args(args).output().map_err(|e| Error::failure(exe, format!("cannot run {what}: {e}")))?;
    let secs = start.elapsed().as_secs_f64();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let mut text = format!("$ gscodec {}\n", args.join(" "));
    text.push_str(&stdout);
    text.push_str(&String::from_utf8_lossy(&out.stderr));
    text.push_str(&format!("[exit {:?}, {secs:.3} s]\n", out.status.code()));
    let old = std::fs::read_to_string(log).unwrap_or_default();
    std::fs::write(log, old + &text).map_err(|e| Error::failure(log, e))?;
    if !out.status.success() {
        let last = String::from_utf8_lossy(&out.stderr).lines().last().unwrap_or("").to_string();
        return Err(Error::failure(log, format!("{what} failed ({last}); see this log")));
    }
    Ok((stdout, secs))
}

/// Encodes, decodes and evaluates one point with `exe` (the `gscodec` executable) and writes its
/// `result.json`. Intermediate files stay in the point directory (`scene.gsc`, `decoded.ply`,
/// `report.json`, `log.txt`).
///
/// # Errors
/// A failing child process (exit 1, naming the point's log) or an unparsable eval output.
pub fn run_point(exe: &Path, plan: &Plan, p: &Point) -> Result<PointResult> {
    let dir = plan.point_dir(p);
    std::fs::create_dir_all(&dir).map_err(|e| Error::failure(&dir, e))?;
    let s = |p: PathBuf| p.display().to_string();
    let (gsc, ply, report, log) = (dir.join("scene.gsc"), dir.join("decoded.ply"), dir.join("report.json"), dir.join("log.txt"));
    let _ = std::fs::remove_file(&log);

    let mut enc = vec![
        "encode".to_string(),
        s(plan.input.clone()),
        "-o".into(),
        s(gsc.clone()),
        "--lambda".into(),
        p.lambda.to_string(),
        "--loss".into(),
        p.loss.clone(),
        "--report".into(),
        s(report.clone()),
        "--quiet".into(),
    ];
    if let Some(n) = plan.iters {
        enc.extend(["--iters".into(), n.to_string()]);
    }
    enc.extend(plan.dataset_args.iter().cloned());
    let (_, encode_s) = run_child(exe, &enc, &log, "encode")?;
    let dec = vec!["decode".to_string(), s(gsc.clone()), "-o".into(), s(ply.clone()), "--quiet".into()];
    let (_, decode_s) = run_child(exe, &dec, &log, "decode")?;
    let mut ev = vec!["eval".to_string(), s(ply)];
    if is_ply(&plan.input) {
        ev.extend(["--reference".into(), s(plan.input.clone()), "--orbit".into(), PLY_EVAL_ORBIT.to_string()]);
    } else {
        ev.extend([s(plan.input.clone()), "--split".into(), "test".into()]);
        ev.extend(plan.dataset_args.iter().cloned());
    }
    ev.extend(["--json".into(), "--quiet".into()]);
    let (stdout, _) = run_child(exe, &ev, &log, "eval")?;
    let eval: Value = serde_json::from_str(stdout.trim()).map_err(|e| Error::failure(&log, format!("eval printed no JSON object: {e}")))?;

    let bytes = std::fs::metadata(&gsc).map_err(|e| Error::failure(&gsc, e))?.len();
    let timeline = std::fs::read_to_string(&report)
        .ok()
        .and_then(|t| serde_json::from_str::<Value>(&t).ok())
        .map(|v| timeline_from_report(&v))
        .unwrap_or_default();
    let result = PointResult { iters: plan.iters, ..point_result(p, bytes, &eval, encode_s, decode_s, timeline) };
    let json = serde_json::to_string_pretty(&result).unwrap_or_default();
    write_bytes_atomic(&dir.join(RESULT_FILE), json.as_bytes())?;
    Ok(result)
}

fn is_ply(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("ply"))
}

/// A point result from the `eval --json` object (`bytes` is the `.gsc` size measured by the sweep).
pub fn point_result(p: &Point, bytes: u64, eval: &Value, encode_s: f64, decode_s: f64, timeline: Vec<TimelinePoint>) -> PointResult {
    let f = |k: &str| eval.get(k).and_then(Value::as_f64);
    PointResult {
        lambda: p.lambda,
        loss: p.loss.clone(),
        iters: None,
        bytes,
        gaussians: eval.get("gaussians").and_then(Value::as_u64).unwrap_or(0),
        psnr: f("psnr"),
        ssim: f("ssim"),
        ms_ssim: f("ms_ssim"),
        flip: f("flip"),
        wd: f("wd"),
        encode_s,
        decode_s,
        timeline,
    }
}

/// Held-out error against wall time from an encode `--report` JSON. Accepts a top-level array or
/// the first array under `timeline`, `series`, `history`, `evals` or `points`, whose objects carry
/// a time (`time_s`, `wall_s`, `elapsed_s` or `seconds`) and `psnr` and/or `wd` (also with a
/// `test_` / `heldout_` prefix or inside a `test` / `heldout` object). Entries without a time or
/// without any error value are skipped.
pub fn timeline_from_report(report: &Value) -> Vec<TimelinePoint> {
    let arr = report
        .as_array()
        .or_else(|| ["timeline", "series", "history", "evals", "points"].iter().find_map(|k| report.get(*k).and_then(Value::as_array)));
    let Some(arr) = arr else { return Vec::new() };
    let num = |o: &Value, keys: &[&str]| keys.iter().find_map(|k| o.get(*k).and_then(Value::as_f64));
    let metric = |o: &Value, name: &str| {
        num(o, &[&format!("test_{name}"), &format!("heldout_{name}"), name])
            .or_else(|| ["test", "heldout"].iter().find_map(|k| o.get(*k).and_then(|t| num(t, &[name]))))
    };
    arr.iter()
        .filter_map(|o| {
            let time_s = num(o, &["time_s", "wall_s", "elapsed_s", "seconds"])?;
            let (psnr, wd) = (metric(o, "psnr"), metric(o, "wd"));
            (psnr.is_some() || wd.is_some()).then_some(TimelinePoint { time_s, psnr, wd })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timeline_accepts_the_usual_report_shapes() {
        let a: Value = serde_json::json!({"timeline": [
            {"iter": 0, "time_s": 0.5, "psnr": 20.0},
            {"iter": 100, "time_s": 3.0, "psnr": 24.0, "wd": 0.3},
            {"iter": 150, "psnr": 25.0},
            {"iter": 200, "time_s": 5.0, "bytes": 1000}
        ]});
        let t = timeline_from_report(&a);
        assert_eq!(t.len(), 2);
        assert_eq!(t[1], TimelinePoint { time_s: 3.0, psnr: Some(24.0), wd: Some(0.3) });
        let b: Value = serde_json::json!([{"wall_s": 1.0, "test": {"psnr": 21.5}}, {"elapsed_s": 2.0, "test_wd": 0.1}]);
        let t = timeline_from_report(&b);
        assert_eq!(
            t,
            vec![TimelinePoint { time_s: 1.0, psnr: Some(21.5), wd: None }, TimelinePoint { time_s: 2.0, psnr: None, wd: Some(0.1) }]
        );
        assert!(timeline_from_report(&serde_json::json!({"final": 1})).is_empty());
    }

    #[test]
    fn plan_points_and_commands() {
        let plan = Plan {
            input: "data/lego".into(),
            out: "sw".into(),
            lambdas: vec![0.1, 0.01],
            losses: vec!["l1ssim".into(), "wdr".into()],
            iters: Some(300),
            dataset_args: Vec::new(),
        };
        let pts = plan.points();
        assert_eq!(pts.len(), 4);
        assert_eq!(pts[3].dir_name(), "wdr_lambda0.01");
        assert_eq!(plan.point_dir(&pts[0]), Path::new("sw/points/l1ssim_lambda0.1"));
        assert_eq!(
            plan.point_command(&pts[1]).join(" "),
            "sweep data/lego -o sw --lambdas 0.01 --loss l1ssim --iters 300 --points-only --quiet"
        );
        let scaled = Plan { dataset_args: vec!["--downscale".into(), "2".into()], ..plan.clone() };
        assert!(scaled.point_command(&pts[1]).join(" ").ends_with("--iters 300 --downscale 2 --points-only --quiet"));
        plan.validate().unwrap();
        let bad = Plan { lambdas: vec![-1.0], ..plan.clone() };
        assert!(bad.validate().unwrap_err().to_string().contains("-1"));
        let bad = Plan { losses: vec!["mse".into()], ..plan };
        assert_eq!(bad.validate().unwrap_err().exit_code(), 2);
    }
}
