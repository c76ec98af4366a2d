//! λ sweeps: encode, decode and evaluate a scene at each (λ, loss) point, then tabulate and plot.
//!
//! | module | one job |
//! |---|---|
//! | [`results`] | per-point results, `rd.csv`, plots, BD-rates, `summary.json` |
//! | [`jobs`] | the sweep as independent jobs (Slurm array script, GNU parallel list) |
//!
//! Each point runs the encoder in process ([`crate::encoder::Encoder`]), decodes the file with
//! `gscodec_decoder::decode` and measures it as `gscodec eval` does; points run `--jobs` at a
//! time on threads. A point is finished when `DIR/points/<loss>_lambda<λ>/result.json` exists;
//! finished points are skipped, which makes sweeps resumable. The jobs `--emit-jobs` writes call
//! the CLI (`gscodec sweep … --points-only`), one point each.

pub mod jobs;
pub mod results;

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::ValueEnum;
use gscodec_decoder::Splats;
use serde_json::Value;

use crate::cli::render::View;
use crate::encoder::{Backend, EncodeReport, Encoder, EncoderConfig, Lambda, LossSpec, SearchDistortion};
use crate::io::atomic::write_bytes_atomic;
use crate::io::{Dataset, Split};
use crate::loss::{FeatureSpec, LossKind};
use crate::{Error, Result};
use results::{PointResult, TimelinePoint, RESULT_FILE};

/// Default λ grid of `sweep`, largest first (smallest files first).
///
/// λ is [`Lambda`]: `J = D + λ·R` with D = 255²·MSE of orbit renders and R in megabits
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

/// One (λ, loss, seed) point.
#[derive(Debug, Clone, PartialEq)]
pub struct Point {
    /// Rate weight.
    pub lambda: f64,
    /// Distortion loss name.
    pub loss: String,
    /// Training seed (`encode --seed`).
    pub seed: u64,
}

impl Point {
    /// Directory name of the point: `<loss>_lambda<λ>`, and `_seed<S>` after it for a seed other
    /// than 0 (so sweeps from before `--seeds` keep their names).
    pub fn dir_name(&self) -> String {
        match self.seed {
            0 => format!("{}_lambda{}", self.loss, self.lambda),
            s => format!("{}_lambda{}_seed{s}", self.loss, self.lambda),
        }
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
    /// Training seeds (`encode --seed`): every (λ, loss) is encoded once per seed.
    pub seeds: Vec<u64>,
    /// `encode --retrain-iters` (dataset input; None: the encoder's default).
    pub retrain_iters: Option<usize>,
    /// `encode --coding-breakdown` (dataset input).
    pub coding_breakdown: bool,
    /// `encode --features` (WD's feature space).
    pub features: FeatureSpec,
    /// `encode --wd-sigma` (None: the default σ).
    pub wd_sigma: Option<f64>,
    /// `encode --wd-warmup` (None: the default share).
    pub wd_warmup: Option<f64>,
    /// `encode --search-distortion` (dataset input).
    pub search_distortion: SearchDistortion,
    /// `encode --max-gaussians` (dataset input; None: the encoder's default).
    pub max_gaussians: Option<usize>,
    /// `encode --init` (dataset input): every point codes this trained scene against the
    /// dataset instead of training one from the images.
    pub init: Option<PathBuf>,
    /// Training backend of every encode.
    pub backend: Backend,
    /// Dataset options (`--downscale N`, …) as command-line words, passed on to emitted jobs;
    /// in process they are [`Input::load`]'s options.
    pub dataset_args: Vec<String>,
}

impl Plan {
    /// Every point, loss-major, then λ in the given order, then seed.
    pub fn points(&self) -> Vec<Point> {
        let mut out = Vec::new();
        for loss in &self.losses {
            for &lambda in &self.lambdas {
                out.extend(self.seeds.iter().map(|&seed| Point { lambda, loss: loss.clone(), seed }));
            }
        }
        out
    }

    /// Directory holding a point's files.
    pub fn point_dir(&self, p: &Point) -> PathBuf {
        self.out.join("points").join(p.dir_name())
    }

    /// Whether a point has a result file from the same settings (`--iters`, `--seed`,
    /// `--retrain-iters`, `--search-distortion`, `--max-gaussians`, `--init`, and `--features`,
    /// `--wd-sigma` and `--wd-warmup` for `wd` / `wdr`); a result from other settings, or an
    /// unreadable one, is redone.
    pub fn is_done(&self, p: &Point) -> bool {
        let Ok(r) = results::read_result(&self.point_dir(p).join(RESULT_FILE)) else { return false };
        // Results written before σ and the warm-up were options were trained at σ = 4 with the
        // paper's warm-up share.
        let wd = r.loss != "l1ssim";
        let done_sigma = r.wd_sigma.or_else(|| wd.then_some(crate::loss::wd::DEFAULT_SIGMA));
        let done_warmup = r.wd_warmup.or_else(|| wd.then_some(crate::loss::wdr::PAPER_WARMUP_FRACTION));
        let done_features = r.wd_features.clone().or_else(|| wd.then(|| FeatureSpec::Pyramid.to_string()));
        // No budget given is the trainer's default one.
        let default_budget = crate::train::TrainConfig::default().max_gaussians;
        r.iters == self.iters
            && r.seed == p.seed
            && r.retrain_iters == self.retrain_iters_applied()
            && r.search_distortion == self.search_distortion
            && r.max_gaussians.unwrap_or(default_budget) == self.max_gaussians.unwrap_or(default_budget)
            && r.init == self.init_name()
            && self.loss_spec(p).is_ok_and(|s| {
                s.reported_sigma() == done_sigma && s.reported_warmup() == done_warmup && s.reported_features() == done_features
            })
    }

    /// `--init` as recorded in results and settings.
    fn init_name(&self) -> Option<String> {
        self.init.as_ref().map(|p| p.display().to_string())
    }

    /// The retraining iterations every point runs with: `--retrain-iters` or the encoder's
    /// default for this many `--iters` (or for `--init`), for a dataset; 0 for a `.ply`.
    pub fn retrain_iters_applied(&self) -> usize {
        let config = EncoderConfig::default().with_iters(self.iters).with_retrain_iters(self.retrain_iters);
        if is_ply(&self.input) {
            0
        } else {
            config.retrain_iters_of_dataset(self.init.is_some())
        }
    }

    /// Checks λs, losses, seeds, σ and the warm-up share.
    ///
    /// # Errors
    /// A negative or non-finite λ, an unknown loss, an empty grid, or a σ or warm-up share out
    /// of range (exit 2).
    pub fn validate(&self) -> Result<()> {
        let arg = Path::new("sweep");
        if self.lambdas.is_empty() || self.losses.is_empty() || self.seeds.is_empty() {
            return Err(Error::input(arg, "--lambdas, --loss and --seeds need at least one value each"));
        }
        if let Some(s) = self.seeds.iter().enumerate().find_map(|(i, s)| self.seeds[..i].contains(s).then_some(s)) {
            return Err(Error::input(arg, format!("--seeds: {s} is given twice")));
        }
        if let Some(l) = self.lambdas.iter().find(|l| !(l.is_finite() && **l >= 0.0)) {
            return Err(Error::input(arg, format!("--lambdas: {l} is not a finite value >= 0")));
        }
        if let Some(l) = self.losses.iter().find(|l| !KNOWN_LOSSES.contains(&l.as_str())) {
            return Err(Error::input(arg, format!("--loss: unknown loss '{l}' (expected one of {})", KNOWN_LOSSES.join(", "))));
        }
        if let Some(s) = self.wd_sigma {
            crate::loss::check_wd_sigma(s).map_err(|e| Error::input(arg, e))?;
        }
        if let Some(f) = self.wd_warmup {
            crate::loss::check_wd_warmup(f).map_err(|e| Error::input(arg, e))?;
        }
        if self.max_gaussians == Some(0) {
            return Err(Error::input(arg, crate::encoder::InvalidConfig::MaxGaussians));
        }
        if self.init.is_some() && is_ply(&self.input) {
            return Err(Error::input(&self.input, crate::cli::encode::INIT_NEEDS_DATASET));
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
            "seeds": self.seeds,
            "retrain_iters": self.retrain_iters_applied(),
            "features": self.features.to_string(),
            "wd_sigma": self.wd_sigma.unwrap_or(crate::loss::wd::DEFAULT_SIGMA),
            "wd_warmup": self.wd_warmup_applied(),
            "search_distortion": self.search_distortion,
            "max_gaussians": self.max_gaussians,
            "init": self.init_name(),
        })
    }

    /// `points` in groups that share their training from the images: points whose encoders
    /// [`Encoder::trains_like`] each other (at a λ and seed, `l1ssim` and `wdr` with WD-R only
    /// in retraining, the default) form one group, at the place of its first point. A `.ply`
    /// or `--init` trains nothing to share: one point a group.
    ///
    /// # Errors
    /// A point's settings that make no encoder (exit 2); [`Plan::validate`] rules these out.
    pub fn training_groups(&self, points: &[Point]) -> Result<Vec<Vec<Point>>> {
        let from_images = !is_ply(&self.input) && self.init.is_none();
        let mut groups: Vec<(Encoder, Vec<Point>)> = Vec::new();
        for p in points {
            let encoder = Encoder::new(self.encoder_config(p)?)?;
            match groups.iter_mut().find(|(e, _)| from_images && e.trains_like(&encoder)) {
                Some((_, g)) => g.push(p.clone()),
                None => groups.push((encoder, vec![p.clone()])),
            }
        }
        Ok(groups.into_iter().map(|(_, g)| g).collect())
    }

    /// Command line (after the executable) that runs just point `p` and records its result.
    pub fn point_command(&self, p: &Point) -> Vec<String> {
        self.group_command(std::slice::from_ref(p))
    }

    /// Command line (after the executable) that runs one group of [`Plan::training_groups`]
    /// (points of one λ and seed) and records their results: what `--emit-jobs` writes, one
    /// per job.
    pub fn group_command(&self, group: &[Point]) -> Vec<String> {
        let p = &group[0];
        let losses = group.iter().map(|q| q.loss.as_str()).collect::<Vec<_>>().join(",");
        let mut c = vec![
            "sweep".to_string(),
            self.input.display().to_string(),
            "-o".into(),
            self.out.display().to_string(),
            "--lambdas".into(),
            p.lambda.to_string(),
            "--loss".into(),
            losses,
        ];
        if let Some(n) = self.iters {
            c.extend(["--iters".into(), n.to_string()]);
        }
        if let Some(n) = self.retrain_iters {
            c.extend(["--retrain-iters".into(), n.to_string()]);
        }
        if self.coding_breakdown {
            c.push("--coding-breakdown".into());
        }
        if self.search_distortion != SearchDistortion::default() {
            c.extend(["--search-distortion".into(), self.search_distortion.name().into()]);
        }
        if let Some(n) = self.max_gaussians {
            c.extend(["--max-gaussians".into(), n.to_string()]);
        }
        if let Some(init) = &self.init {
            c.extend(["--init".into(), init.display().to_string()]);
        }
        if p.seed != 0 {
            c.extend(["--seeds".into(), p.seed.to_string()]);
        }
        if self.features != FeatureSpec::default() {
            c.extend(["--features".into(), self.features.to_string()]);
        }
        if let Some(s) = self.wd_sigma {
            c.extend(["--wd-sigma".into(), s.to_string()]);
        }
        if let Some(f) = self.wd_warmup {
            c.extend(["--wd-warmup".into(), f.to_string()]);
        }
        c.extend(self.dataset_args.iter().cloned());
        if self.backend != Backend::Auto {
            let b = self.backend.to_possible_value().expect("no skipped variants");
            c.extend(["--backend".into(), b.get_name().to_string()]);
        }
        c.extend(["--points-only".into(), "--quiet".into()]);
        c
    }

    /// The encoder settings of point `p`.
    ///
    /// # Errors
    /// An unknown loss or a negative λ (exit 2); [`Plan::validate`] rules these out.
    pub fn encoder_config(&self, p: &Point) -> Result<EncoderConfig> {
        let loss = self.loss_spec(p)?;
        let lambda = Lambda::new(p.lambda).ok_or_else(|| Error::input(Path::new("--lambdas"), format!("{} is not >= 0", p.lambda)))?;
        Ok(EncoderConfig::default()
            .with_lambda(lambda)
            .with_iters(self.iters)
            .with_seed(p.seed)
            .with_retrain_iters(self.retrain_iters)
            .with_coding_breakdown(self.coding_breakdown)
            .with_search_distortion(self.search_distortion)
            .with_max_gaussians(self.max_gaussians)
            .with_loss(loss)
            .with_backend(self.backend))
    }

    /// The training loss of point `p`.
    ///
    /// # Errors
    /// An unknown loss (exit 2); [`Plan::validate`] rules it out.
    pub fn loss_spec(&self, p: &Point) -> Result<LossSpec> {
        let kind = <LossKind as ValueEnum>::from_str(&p.loss, true).map_err(|e| Error::input(Path::new("--loss"), e))?;
        let features = self.features.clone();
        Ok(LossSpec { kind, features, wd_sigma: self.wd_sigma, ..LossSpec::default() }.with_default_warmup(self.wd_warmup_applied()))
    }

    /// The warm-up share the `wd` / `wdr` points train with: `--wd-warmup`, else the encoder's
    /// default for the input (a dataset trained from its images: WD-R only in retraining).
    pub fn wd_warmup_applied(&self) -> f64 {
        let from_images = !is_ply(&self.input) && self.init.is_none();
        let config = EncoderConfig::default().with_iters(self.iters).with_retrain_iters(self.retrain_iters);
        self.wd_warmup.unwrap_or_else(|| config.default_wd_warmup(from_images))
    }
}

/// What a sweep encodes and measures against, loaded once for all points.
pub struct Input {
    /// The scene (a `.ply`) or the dataset to encode.
    pub source: Source,
    /// The views the decoded scenes are measured on, with targets: the reference scene's
    /// [`PLY_EVAL_ORBIT`] orbit views, or the dataset's test split (as `gscodec eval`).
    pub views: Vec<View>,
    /// Background of the measuring renders.
    pub background: [f32; 3],
}

/// A sweep's input.
pub enum Source {
    /// A trained scene.
    Scene(Splats),
    /// A posed-image dataset.
    Dataset(Dataset),
    /// A posed-image dataset and a scene trained on it (`--init`).
    Trained(Dataset, Splats),
}

impl Input {
    /// Loads `path`: a `.ply` scene or a dataset directory (with `opts`), and with a dataset
    /// the scene `init` trained on it, when given.
    ///
    /// # Errors
    /// An unreadable input or scene (exit 2, naming it).
    pub fn load(path: &Path, opts: &crate::io::LoadOptions, init: Option<&Path>) -> Result<Input> {
        if is_ply(path) {
            let scene = crate::io::read_ply(path)?;
            let (views, background) = crate::cli::eval::reference_views(&scene, PLY_EVAL_ORBIT, None, crate::views::UpAxis::NegY);
            Ok(Input { source: Source::Scene(scene), views, background })
        } else {
            let ds = crate::io::load_dataset(path, opts)?;
            let views: Vec<View> = ds
                .split(Split::Test)
                .into_iter()
                .map(|f| View { index: f.index, camera: f.camera, target: Some(f.image.clone()) })
                .collect();
            if views.is_empty() {
                return Err(Error::input(path, "the dataset has no test views to measure a sweep on"));
            }
            let background = ds.background;
            let source = match init {
                Some(init) => Source::Trained(ds, crate::io::read_scene(init)?),
                None => Source::Dataset(ds),
            };
            Ok(Input { source, views, background })
        }
    }
}

/// Encodes, decodes and measures one point and writes its `result.json`; the point directory
/// also keeps `scene.gsc` and `report.json` (the typed [`EncodeReport`]).
///
/// # Errors
/// A failing encode (bad input: exit 2; training failure: exit 1) or an unwritable file.
pub fn run_point(input: &Input, plan: &Plan, p: &Point) -> Result<PointResult> {
    let encoder = Encoder::new(plan.encoder_config(p)?)?;
    let t = Instant::now();
    let out = match &input.source {
        Source::Scene(s) => encoder.encode_scene(s, &mut |_| {}),
        Source::Dataset(d) => encoder.encode_dataset(d, &mut |_| {}),
        Source::Trained(d, s) => encoder.encode_trained(d, s, &mut |_| {}),
    };
    record_point(input, plan, p, out.map_err(|e| named(plan, e))?, t.elapsed().as_secs_f64())
}

/// Runs one group of [`training_groups`]: a dataset's points train once and are each coded from
/// that scene ([`Encoder::code_dataset`]), a single point as [`run_point`]. A point's encode time
/// counts the shared training, as if it had trained alone. One result per point, in order.
pub fn run_group(input: &Input, plan: &Plan, group: &[Point]) -> Vec<Result<PointResult>> {
    let dataset = match &input.source {
        Source::Dataset(d) if group.len() > 1 => d,
        _ => return group.iter().map(|p| run_point(input, plan, p)).collect(),
    };
    let shared = || -> Result<(crate::encoder::TrainedScene, Vec<Encoder>)> {
        let encoders = group.iter().map(|p| Ok(Encoder::new(plan.encoder_config(p)?)?)).collect::<Result<Vec<_>>>()?;
        Ok((encoders[0].train_dataset(dataset, &mut |_| {}).map_err(|e| named(plan, e))?, encoders))
    };
    let (trained, encoders) = match shared() {
        Ok(t) => t,
        // Every point of the group fails as its training did.
        Err(e) => return group.iter().map(|_| Err(same_error(&e))).collect(),
    };
    group
        .iter()
        .zip(&encoders)
        .map(|(p, encoder)| {
            let t = Instant::now();
            let out = encoder.code_dataset(dataset, &trained, &mut |_| {}).map_err(|e| named(plan, e))?;
            record_point(input, plan, p, out, (trained.elapsed() + t.elapsed()).as_secs_f64())
        })
        .collect()
}

/// An encoder's bad-input error named after the sweep's input.
fn named(plan: &Plan, e: Error) -> Error {
    match e {
        Error::Input(m) => Error::input(&plan.input, m),
        other => other,
    }
}

/// `e` again, for another point that shares its cause.
fn same_error(e: &Error) -> Error {
    match e {
        Error::Input(m) => Error::Input(m.clone()),
        Error::Failure(m) => Error::Failure(m.clone()),
    }
}

/// Writes point `p`'s file and report, decodes and measures the file, and writes its
/// `result.json`; `encode_s` is the encode's wall time.
fn record_point(input: &Input, plan: &Plan, p: &Point, mut out: crate::encoder::Encoded, encode_s: f64) -> Result<PointResult> {
    let dir = plan.point_dir(p);
    std::fs::create_dir_all(&dir).map_err(|e| Error::failure(&dir, e))?;
    out.report.input = plan.input.display().to_string();
    write_bytes_atomic(&dir.join("scene.gsc"), &out.bytes)?;
    let report = serde_json::to_string_pretty(&out.report).map_err(|e| Error::failure(&dir, e))?;
    write_bytes_atomic(&dir.join("report.json"), report.as_bytes())?;

    let t = Instant::now();
    let decoded = gscodec_decoder::decode(&out.bytes).map_err(|e| Error::failure(&dir.join("scene.gsc"), e))?;
    let decode_s = t.elapsed().as_secs_f64();
    let (per_view, _) = crate::cli::eval::measure(&decoded, &input.views, input.background, &mut || {})?;
    let m = crate::metrics::view::mean(&per_view).ok_or_else(|| Error::input(&plan.input, "no views to measure"))?;
    let spec = plan.loss_spec(p)?;
    let result = PointResult {
        lambda: p.lambda,
        loss: p.loss.clone(),
        iters: plan.iters,
        seed: p.seed,
        retrain_iters: plan.retrain_iters_applied(),
        wd_features: spec.reported_features(),
        wd_sigma: spec.reported_sigma(),
        wd_warmup: spec.reported_warmup(),
        search_distortion: plan.search_distortion,
        max_gaussians: plan.max_gaussians,
        init: plan.init_name(),
        bytes: out.bytes.len() as u64,
        gaussians: decoded.len() as u64,
        psnr: Some(m.psnr),
        ssim: Some(m.ssim),
        ms_ssim: m.ms_ssim,
        flip: Some(m.flip),
        wd: m.wd,
        encode_s,
        decode_s,
        timeline: timeline(&out.report),
    };
    let json = serde_json::to_string_pretty(&result).map_err(|e| Error::failure(&dir, e))?;
    write_bytes_atomic(&dir.join(RESULT_FILE), json.as_bytes())?;
    Ok(result)
}

fn is_ply(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("ply"))
}

/// Held-out PSNR against encode wall time: the report's series points that have a PSNR.
pub fn timeline(report: &EncodeReport) -> Vec<TimelinePoint> {
    report.series.iter().filter_map(|s| s.heldout_psnr.map(|psnr| TimelinePoint { time_s: s.wall_s, psnr: Some(psnr), wd: None })).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plan_points_and_commands() {
        let plan = Plan {
            input: "data/lego".into(),
            out: "sw".into(),
            lambdas: vec![0.1, 0.01],
            losses: vec!["l1ssim".into(), "wdr".into()],
            iters: Some(300),
            seeds: vec![0],
            retrain_iters: None,
            coding_breakdown: false,
            features: FeatureSpec::default(),
            wd_sigma: None,
            wd_warmup: None,
            search_distortion: SearchDistortion::Mse,
            max_gaussians: None,
            init: None,
            backend: Backend::Auto,
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
        plan.validate().unwrap();
        let scaled = Plan { dataset_args: vec!["--downscale".into(), "2".into()], ..plan.clone() };
        assert!(scaled.point_command(&pts[1]).join(" ").ends_with("--iters 300 --downscale 2 --points-only --quiet"));
        // --seeds: each (loss, λ) once per seed, seed 0 under the old directory name
        let seeded = Plan { seeds: vec![0, 7], ..plan.clone() };
        let sp = seeded.points();
        assert_eq!(sp.len(), 8);
        assert_eq!((sp[0].dir_name(), sp[1].dir_name()), ("l1ssim_lambda0.1".into(), "l1ssim_lambda0.1_seed7".into()));
        assert!(seeded.point_command(&sp[1]).join(" ").ends_with("--iters 300 --seeds 7 --points-only --quiet"));
        assert!(seeded.point_command(&sp[0]).join(" ").ends_with("--iters 300 --points-only --quiet"));
        assert_eq!((seeded.encoder_config(&sp[1]).unwrap().seed, seeded.encoder_config(&sp[0]).unwrap().seed), (7, 0));
        assert_eq!(seeded.settings()["seeds"], serde_json::json!([0, 7]));
        let rt = Plan { retrain_iters: Some(0), ..plan.clone() };
        assert!(rt.point_command(&pts[1]).join(" ").ends_with("--iters 300 --retrain-iters 0 --points-only --quiet"));
        assert_eq!((rt.encoder_config(&pts[1]).unwrap().retrain_iters, rt.settings()["retrain_iters"].as_u64()), (Some(0), Some(0)));
        assert_eq!(
            (plan.encoder_config(&pts[1]).unwrap().retrain_iters_for(true), plan.settings()["retrain_iters"].as_u64()),
            (100, Some(100))
        );
        // --init retrains as long as a default training, whatever --iters says
        let init = Plan { init: Some("scene.ply".into()), ..plan.clone() };
        assert_eq!((init.retrain_iters_applied(), init.settings()["retrain_iters"].as_u64()), (3000, Some(3000)));
        assert_eq!(Plan { retrain_iters: Some(10), ..init }.retrain_iters_applied(), 10);
        let cb = Plan { coding_breakdown: true, ..rt.clone() };
        assert!(cb.point_command(&pts[1]).join(" ").ends_with("--retrain-iters 0 --coding-breakdown --points-only --quiet"));
        assert!(cb.encoder_config(&pts[1]).unwrap().coding_breakdown && !rt.encoder_config(&pts[1]).unwrap().coding_breakdown);
        let ply = Plan { input: "scene.ply".into(), ..plan.clone() };
        assert_eq!((ply.retrain_iters_applied(), rt.retrain_iters_applied()), (0, 0), "a .ply has nothing to retrain");
        let bad = Plan { seeds: vec![1, 1], ..plan.clone() };
        assert_eq!(bad.validate().unwrap_err().to_string(), "sweep: --seeds: 1 is given twice");
        let cpu = Plan { backend: Backend::Cpu, ..plan.clone() };
        assert!(cpu.point_command(&pts[0]).join(" ").ends_with("--iters 300 --backend cpu --points-only --quiet"));
        let c = plan.encoder_config(&pts[3]).unwrap();
        assert_eq!((c.lambda.get(), c.loss.kind, c.iters, c.loss.wd_sigma), (0.01, LossKind::Wdr, Some(300), None));
        assert_eq!(plan.settings()["wd_sigma"], 4.0, "the default σ is recorded");
        // --wd-sigma reaches the encoder, the emitted jobs and the summary; l1ssim points record none
        let s2 = Plan { wd_sigma: Some(2.0), ..plan.clone() };
        s2.validate().unwrap();
        assert!(s2.point_command(&pts[3]).join(" ").ends_with("--iters 300 --wd-sigma 2 --points-only --quiet"));
        assert_eq!(s2.encoder_config(&pts[3]).unwrap().loss.wd_sigma, Some(2.0));
        assert_eq!(s2.settings()["wd_sigma"], 2.0);
        assert_eq!((s2.loss_spec(&pts[0]).unwrap().reported_sigma(), s2.loss_spec(&pts[3]).unwrap().reported_sigma()), (None, Some(2.0)));
        // --wd-warmup likewise
        // the default share is the encoder's: WD-R only in retraining for a dataset that
        // retrains, else 0.3 (no retraining, a .ply, a scene given with --init)
        assert_eq!(plan.settings()["wd_warmup"], 1.0, "the default warm-up is recorded");
        assert_eq!(plan.encoder_config(&pts[3]).unwrap().loss.wd_warmup, Some(1.0));
        assert_eq!(plan.encoder_config(&pts[0]).unwrap().loss.reported_warmup(), None, "l1ssim has no warm-up");
        let init = Plan { init: Some("scene.ply".into()), ..plan.clone() };
        for other in [&rt, &ply, &init] {
            assert_eq!(other.settings()["wd_warmup"], 0.3);
            assert_eq!(other.loss_spec(&pts[3]).unwrap().reported_warmup(), Some(0.3));
        }
        let w = Plan { wd_warmup: Some(0.25), ..plan.clone() };
        w.validate().unwrap();
        assert!(w.point_command(&pts[3]).join(" ").ends_with("--iters 300 --wd-warmup 0.25 --points-only --quiet"));
        assert_eq!(w.encoder_config(&pts[3]).unwrap().loss.wd_warmup, Some(0.25));
        assert_eq!(w.settings()["wd_warmup"], 0.25);
        assert_eq!((w.loss_spec(&pts[0]).unwrap().reported_warmup(), w.loss_spec(&pts[3]).unwrap().reported_warmup()), (None, Some(0.25)));
        Plan { wd_warmup: Some(1.0), ..plan.clone() }.validate().unwrap();
        // l1ssim and wdr at a λ share the training from the images (one job each λ) unless
        // WD-R acts in it, or nothing is trained from the images
        let groups = plan.training_groups(&pts).unwrap();
        assert_eq!(groups, vec![vec![pts[0].clone(), pts[2].clone()], vec![pts[1].clone(), pts[3].clone()]]);
        assert_eq!(
            plan.group_command(&groups[1]).join(" "),
            "sweep data/lego -o sw --lambdas 0.01 --loss l1ssim,wdr --iters 300 --points-only --quiet"
        );
        assert_eq!(seeded.training_groups(&sp).unwrap().len(), 4, "one training per λ and seed");
        for other in [&w, &rt, &ply, &init] {
            assert!(other.training_groups(&pts).unwrap().iter().all(|g| g.len() == 1));
        }
        let bad = Plan { wd_warmup: Some(1.5), ..plan.clone() };
        assert_eq!(bad.validate().unwrap_err().to_string(), "sweep: --wd-warmup 1.5: must be in [0, 1]");
        let bad = Plan { wd_sigma: Some(0.5), ..plan.clone() };
        assert_eq!(bad.validate().unwrap_err().to_string(), "sweep: --wd-sigma 0.5: must be in [1, 32]");
        let bad = Plan { lambdas: vec![-1.0], ..plan.clone() };
        assert!(bad.validate().unwrap_err().to_string().contains("-1"));
        let bad = Plan { losses: vec!["mse".into()], ..plan };
        assert_eq!(bad.validate().unwrap_err().exit_code(), 2);
    }
}
