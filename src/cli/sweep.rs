//! `gscodec sweep`: rate–distortion curves in one command (see `docs/sweep.md`).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use crate::encoder::{Backend, SearchDistortion};
use crate::loss::FeatureSpec;
use crate::sweep::results::{bd_report, read_results, write_outputs};
use crate::sweep::{jobs, run_group, Input, Plan, DEFAULT_LAMBDAS, DEFAULT_LOSSES};
use crate::{Error, Result};

/// Encode a scene at several λ and losses, decode, evaluate, and write RD tables and plots.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset directory (transforms*.json or COLMAP) or a trained .ply.
    pub input: PathBuf,
    /// Output directory: rd.csv, rd.svg, time.svg, summary.json and points/<loss>_lambda<λ>/.
    #[arg(short, long)]
    pub out: PathBuf,
    /// λ values, comma-separated [default: 200,60,20,6,2].
    #[arg(long, value_delimiter = ',')]
    pub lambdas: Vec<f64>,
    /// Losses, comma-separated (l1ssim, wd, wdr); BD-rates are against l1ssim [default: l1ssim,wdr].
    #[arg(long = "loss", value_delimiter = ',')]
    pub losses: Vec<String>,
    /// Training iterations per encode (encoder default when absent).
    #[arg(long)]
    pub iters: Option<usize>,
    /// Training seeds, comma-separated: every (λ, loss) is encoded once per seed (`encode
    /// --seed`). With several, the curves and BD-rates are of the seeds' mean points, and
    /// summary.json also has each seed's BD-rates (the training noise) [default: 0].
    #[arg(long, value_delimiter = ',')]
    pub seeds: Vec<u64>,
    /// `encode --retrain-iters` of every point (dataset input; default: a third of --iters, 3000 with --init).
    #[arg(long, value_name = "N")]
    pub retrain_iters: Option<usize>,
    /// `encode --coding-breakdown` for every point (dataset input): each point's report.json
    /// gives where coding loses the held-out PSNR.
    #[arg(long)]
    pub coding_breakdown: bool,
    /// Feature space of `wd` / `wdr`: `pyramid-colour`, `pyramid` or `vgg16=PATH` (`encode
    /// --features`).
    #[arg(long, default_value = "pyramid-colour", value_name = "pyramid-colour|pyramid|vgg16=PATH")]
    pub features: FeatureSpec,
    /// Pooling scale σ of `wd` / `wdr` (1 ≤ S ≤ 32) [default: 4].
    #[arg(long = "wd-sigma", value_name = "S")]
    pub wd_sigma: Option<f64>,
    /// Share of each encode's iterations trained with L1-SSIM before `wd` / `wdr`
    /// (0 ≤ F ≤ 1; 1: only in retraining) [default: encode's: 1 for a dataset that retrains,
    /// else 0.3].
    #[arg(long = "wd-warmup", value_name = "F")]
    pub wd_warmup: Option<f64>,
    /// `encode --search-distortion` of every point (dataset input): what the RD search
    /// measures D with, `mse` or the training `loss`'s distortion.
    #[arg(long, value_enum, default_value_t = SearchDistortion::Mse, value_name = "mse|loss")]
    pub search_distortion: SearchDistortion,
    /// `encode --max-gaussians` of every point (dataset input): densification never grows a
    /// scene beyond N Gaussians [default: 100000].
    #[arg(long, value_name = "N")]
    pub max_gaussians: Option<usize>,
    /// `encode --init` of every point (dataset input): code SCENE, trained on the dataset
    /// elsewhere, at each λ (its Gaussians retrained to the images with each loss, as
    /// --retrain-iters says) instead of training a scene from the images per point.
    #[arg(long, value_name = "SCENE", conflicts_with_all = ["iters", "max_gaussians"])]
    pub init: Option<PathBuf>,
    /// Training backend of every encode: cpu, gpu, or auto (a hardware GPU if there is one).
    #[arg(long, value_enum, default_value_t = Backend::Auto)]
    pub backend: Backend,
    /// Points encoded at the same time, in this process (each encode is itself multi-threaded).
    #[arg(long, default_value_t = 1)]
    pub jobs: usize,
    /// Write the sweep as jobs instead of running it: FILE (Slurm array script) and
    /// FILE with extension .commands.txt (one command per line, for GNU parallel).
    #[arg(long, value_name = "FILE", conflicts_with = "collect")]
    pub emit_jobs: Option<PathBuf>,
    /// Merge the finished points under DIR/points into the outputs in -o (after emitted jobs ran).
    #[arg(long, value_name = "DIR")]
    pub collect: Option<PathBuf>,
    /// Run the points and record their results, but write no tables or plots (what emitted jobs run).
    #[arg(long)]
    pub points_only: bool,
    /// Dataset image options, for each encode and the test views it is measured on.
    #[command(flatten)]
    pub dataset: super::dataset_args::DatasetArgs,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

/// Runs `gscodec sweep`.
///
/// # Errors
/// Bad flags or input (exit 2); a failing point or unwritable output (exit 1).
pub fn run(args: Args) -> Result<()> {
    let lambdas = if args.lambdas.is_empty() { DEFAULT_LAMBDAS.to_vec() } else { args.lambdas.clone() };
    let losses = if args.losses.is_empty() { DEFAULT_LOSSES.iter().map(|s| s.to_string()).collect() } else { args.losses.clone() };
    let mut plan = Plan {
        input: args.input.clone(),
        out: args.out.clone(),
        lambdas,
        losses,
        iters: args.iters,
        retrain_iters: args.retrain_iters,
        coding_breakdown: args.coding_breakdown,
        seeds: if args.seeds.is_empty() { vec![0] } else { args.seeds.clone() },
        features: args.features.clone(),
        wd_sigma: args.wd_sigma,
        wd_warmup: args.wd_warmup,
        search_distortion: args.search_distortion,
        max_gaussians: args.max_gaussians,
        init: args.init.clone(),
        backend: args.backend,
        dataset_args: args.dataset.to_args(),
    };
    plan.validate()?;

    if let Some(dir) = &args.collect {
        let rows = read_results(dir)?;
        if rows.is_empty() {
            return Err(Error::input(dir, "no finished sweep points (points/*/result.json) to collect"));
        }
        let bd = write_outputs(&plan.out, &rows, plan.settings())?;
        print!("{}", bd_report(&bd));
        return Ok(());
    }

    if !plan.input.exists() {
        return Err(Error::input(&plan.input, "no such file or directory"));
    }
    if args.jobs == 0 {
        return Err(Error::input(Path::new("--jobs"), "must be at least 1"));
    }
    // Absolute paths: children and emitted jobs may run from elsewhere.
    plan.input = std::fs::canonicalize(&plan.input).map_err(|e| Error::input(&plan.input, e))?;
    if let Some(init) = &plan.init {
        plan.init = Some(std::fs::canonicalize(init).map_err(|e| Error::input(init, e))?);
    }
    let created = !plan.out.exists();
    std::fs::create_dir_all(&plan.out).map_err(|e| Error::failure(&plan.out, e))?;
    plan.out = std::fs::canonicalize(&plan.out).map_err(|e| Error::failure(&plan.out, e))?;
    // An unreadable input leaves no output directory behind (one this run did not create stays).
    let unmade = |e: Error| {
        if created {
            let _ = std::fs::remove_dir(&plan.out);
        }
        e
    };
    let exe = std::env::current_exe().map_err(|e| Error::failure(Path::new("gscodec"), format!("cannot find own executable: {e}")))?;

    if let Some(file) = &args.emit_jobs {
        return emit_jobs(file, &exe, &plan, &args);
    }

    let pending: Vec<_> = plan.points().into_iter().filter(|p| !plan.is_done(p)).collect();
    let skipped = plan.points().len() - pending.len();
    if skipped > 0 && !args.quiet {
        eprintln!("sweep: {skipped} finished point(s) kept, {} to run", pending.len());
    }
    // Loaded once for every point, and only when a point is to run.
    let input = if pending.is_empty() {
        None
    } else {
        Some(Input::load(&plan.input, &args.dataset.load_options(), plan.init.as_deref()).map_err(unmade)?)
    };
    // Points that train alike from the images (l1ssim and wdr at a λ and seed, by default) are
    // one job: trained once, coded once each.
    let groups = plan.training_groups(&pending)?;
    let bar = super::progress::bar(pending.len() as u64, "sweep", args.quiet || pending.is_empty());
    let next = AtomicUsize::new(0);
    let failures = Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..args.jobs.min(groups.len()) {
            s.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::SeqCst);
                let Some(group) = groups.get(i) else { break };
                let input = input.as_ref().expect("loaded when points are pending");
                for (p, r) in group.iter().zip(run_group(input, &plan, group)) {
                    if let Err(e) = r {
                        failures.lock().unwrap_or_else(|e| e.into_inner()).push(format!("{}: {e}", p.dir_name()));
                    }
                    bar.inc(1);
                }
            });
        }
    });
    bar.finish_and_clear();
    let failures = failures.into_inner().unwrap_or_else(|e| e.into_inner());

    if !args.points_only {
        let rows = read_results(&plan.out)?;
        if !rows.is_empty() {
            let bd = write_outputs(&plan.out, &rows, plan.settings())?;
            print!("{}", bd_report(&bd));
        }
    }
    match failures.first() {
        None => Ok(()),
        Some(first) => Err(Error::Failure(format!(
            "{} of {} point(s) failed (rerun to retry only those); first: {first}",
            failures.len(),
            pending.len()
        ))),
    }
}

fn emit_jobs(file: &Path, exe: &Path, plan: &Plan, args: &Args) -> Result<()> {
    use crate::io::atomic::write_bytes_atomic;
    let lines = jobs::command_lines(exe, plan, &plan.training_groups(&plan.points())?);
    let collect =
        [exe.display().to_string(), "sweep".into(), plan.input.display().to_string(), "-o".into(), plan.out.display().to_string()]
            .into_iter()
            .chain(["--collect".into(), plan.out.display().to_string()])
            .map(|w| jobs::shell_quote(&w))
            .collect::<Vec<_>>()
            .join(" ");
    write_bytes_atomic(file, jobs::slurm_script(&lines, &plan.out, &collect).as_bytes())?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let _ = std::fs::set_permissions(file, std::fs::Permissions::from_mode(0o755));
    }
    let list = jobs::list_path(file);
    write_bytes_atomic(&list, jobs::command_list(&lines).as_bytes())?;
    if !args.quiet {
        eprintln!(
            "sweep: {} jobs written to {} (sbatch) and {} (parallel < it); then run: {collect}",
            lines.len(),
            file.display(),
            list.display()
        );
    }
    Ok(())
}
