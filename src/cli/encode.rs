//! `gscodec encode`: a trained `.ply` or a posed-image dataset to a `.gsc` file (a shell over
//! [`crate::encoder::Encoder`]).

use std::path::PathBuf;

use crate::encoder::{Backend, Encoded, Encoder, EncoderConfig, Lambda, LossSpec, Profile, SearchDistortion, Target, TargetEvent};
use crate::loss::LossKind;
use crate::Error;
use gscodec_decoder::Splats;

/// The error of `--init` beside a scene input (`encode` and `sweep`).
pub(crate) const INIT_NEEDS_DATASET: &str = "--init needs a dataset input (the images the scene was trained on)";

/// Compress a scene into a .gsc bitstream.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// A trained scene (.ply, .spz, .splat, …), or a dataset directory.
    pub input: PathBuf,
    /// Output .gsc file.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Rate–distortion trade-off λ in J = D + λ·R, D = 255²·MSE of orbit renders, R = megabits.
    /// Larger gives smaller files; 0 = finest.
    #[arg(long, default_value_t = Lambda::DEFAULT)]
    pub lambda: Lambda,
    /// Instead of a λ: the smallest file whose PSNR reaches DB, found by a bracketing search on
    /// λ: from λ = 230,000 / Gaussians towards the target, then regula falsi (usually 4–9
    /// encodes, at most 14). The PSNR is measured as `gscodec eval OUTPUT --reference INPUT --orbit 8`
    /// measures it (8 orbit views at 256×256, up −y, black background). For a dataset: the
    /// held-out (test) views' PSNR as `gscodec eval OUTPUT DATASET` measures it; the scene is
    /// trained from the images once, at the default λ (or is --init), and each probe runs the
    /// RD search, the retraining and the coding at its λ. With --iters on a scene, the RD
    /// search alone brackets λ first, and the fine-tuned encodes start from the λ it found;
    /// the file is the better of both phases' (never worse than without --iters). Each encode
    /// prints a line as it finishes (not with --quiet).
    #[arg(long, value_name = "DB", conflicts_with_all = ["lambda", "target_bytes"])]
    pub target_psnr: Option<f64>,
    /// Instead of a λ: the best PSNR (measured as for --target-psnr) among files of at most N
    /// bytes, found by the same search on λ (a dataset: as for --target-psnr).
    #[arg(long, value_name = "N", conflicts_with = "lambda")]
    pub target_bytes: Option<u64>,
    /// Training distortion and its options.
    #[command(flatten)]
    pub loss: crate::loss::LossArgs,
    /// Fine-tuning (a .ply: against 24 orbit renders of itself, densification off, the rates of
    /// all but the positions falling to 0.3 over the second half) or training
    /// (a dataset) iterations under D + λ·R with straight-through quantisation; 0 = code as is.
    /// Default: 0 for a .ply, 3000 for a dataset.
    #[arg(long)]
    pub iters: Option<usize>,
    /// Dataset input: code SCENE, a scene trained on this dataset elsewhere (.ply, .spz, …, in
    /// the dataset's world frame), instead of training one from the images: the RD search
    /// measures on the dataset's training cameras, retraining (--retrain-iters, default 3000:
    /// as many as a dataset's default --iters) fine-tunes the Gaussians it keeps to the
    /// training images, and the report measures the held-out views.
    #[arg(long, value_name = "SCENE", conflicts_with_all = ["iters", "max_gaussians", "densify_grad_threshold"])]
    pub init: Option<PathBuf>,
    /// Dataset input: after the RD search has pruned the trained scene (and dropped SH bands),
    /// train the Gaussians it keeps N more iterations on the images under D + λ·R (no
    /// densification; WD / WD-R without warm-up), then code them. Default: a third of --iters,
    /// 3000 with --init; 0 codes the search's choice as it is.
    #[arg(long, value_name = "N")]
    pub retrain_iters: Option<usize>,
    /// Dataset input: report (in --report's `coding_breakdown`) the held-out PSNR of the
    /// trained scene before coding and as each of the RD search's choices is added (quantised,
    /// pruning, SH band dropping, SH codebooks, importance classes: the file), and with only the
    /// groups training quantises, or only the others, quantised. Seven more encodes.
    #[arg(long)]
    pub coding_breakdown: bool,
    /// Dataset input: what the RD search measures D with on views from 8 training cameras
    /// against the trained scene: `mse` (255² × mean squared error) or `loss`, the training
    /// loss's distortion (l1ssim: 0.8·L1 + 0.2·(1 − SSIM); wd: WD; wdr: WD + β·that; the
    /// built-in `pyramid` features and --wd-sigma), scaled to the squared error's unit at the
    /// search's first configuration so that λ means the same (docs/wd.md §15).
    #[arg(long, value_enum, default_value_t = SearchDistortion::Mse, value_name = "mse|loss")]
    pub search_distortion: SearchDistortion,
    /// Dataset input: densification never grows the scene beyond N Gaussians (the initial
    /// points are kept when there are more). Default: 100000.
    #[arg(long, value_name = "N")]
    pub max_gaussians: Option<usize>,
    /// Dataset input: densification clones or splits the Gaussians whose mean view-space
    /// positional gradient (NDC units) reaches G; lower grows more. Default: 0.0002 (the
    /// reference 3DGS value).
    #[arg(long, value_name = "G")]
    pub densify_grad_threshold: Option<f32>,
    /// Random seed of training and fine-tuning (initialisation, view order, densification). The
    /// CPU trainer gives the same file for the same seed; other seeds measure training noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Keep the quantisation steps fixed during training instead of learning them (per group:
    /// scale, opacity, SH DC, each SH band) under D + λ·R.
    #[arg(long)]
    pub fixed_steps: bool,
    /// Training backend: cpu, gpu (feature `gpu` and a GPU), or auto (a hardware GPU if there
    /// is one, else cpu).
    #[arg(long, value_enum, default_value_t = Backend::Auto)]
    pub backend: Backend,
    /// Write the Gaussians in importance levels (format 4.0): a player that has a prefix of the
    /// file draws the most important 1/16 first, then 1/16, 1/8, 1/4 and 1/2 more (docs/codec.md
    /// gives its cost in bytes).
    #[arg(long)]
    pub progressive: bool,
    /// How to code the scene: explicit (per-Gaussian attributes), anchor (anchors with features
    /// and a small fixed-point MLP, format 7.0; its fine-tuning: --anchor-iters, default 300),
    /// or auto (whichever has the lower J = D + λ·R). See docs/codec.md.
    #[arg(long, value_enum, default_value_t = Profile::Explicit)]
    pub profile: Profile,
    /// Anchor profile: features per anchor (1..=255, default 16). More features describe each
    /// anchor's Gaussians better and cost more bits.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u8).range(1..))]
    pub anchor_features: Option<u8>,
    /// Anchor profile: hidden units of the MLP (1..=512, default 32; with 255 features that is
    /// within the format's 2^18 weights).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u16).range(1..=512))]
    pub anchor_hidden: Option<u16>,
    /// Anchor profile: fine-tuning steps of the anchors against renders of the scene (default:
    /// --iters for a scene, 300 for a dataset, whose --iters train the scene first).
    #[arg(long, value_name = "N")]
    pub anchor_iters: Option<usize>,
    /// Write a JSON report (sizes per attribute group, estimated vs actual, stage times, time series).
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Dataset image options.
    #[command(flatten)]
    pub dataset: super::dataset_args::DatasetArgs,
    /// No progress output.
    #[arg(long)]
    pub quiet: bool,
}

impl Args {
    /// The target these flags ask for, if any.
    pub fn target(&self) -> Option<Target> {
        self.target_psnr.map(Target::Psnr).or(self.target_bytes.map(Target::Bytes))
    }

    /// The encoder settings these flags ask for.
    pub fn config(&self) -> EncoderConfig {
        EncoderConfig::default()
            .with_lambda(self.lambda)
            .with_iters(self.iters)
            .with_seed(self.seed)
            .with_retrain_iters(self.retrain_iters)
            .with_coding_breakdown(self.coding_breakdown)
            .with_search_distortion(self.search_distortion)
            .with_max_gaussians(self.max_gaussians)
            .with_densify_grad_threshold(self.densify_grad_threshold)
            .with_learned_steps(!self.fixed_steps)
            .with_loss(LossSpec::from_args(&self.loss, LossKind::Wdr))
            .with_backend(self.backend)
            .with_progressive(self.progressive)
            .with_profile(self.profile)
            .with_anchor_shape(self.anchor_features.map(usize::from), self.anchor_hidden.map(usize::from))
            .with_anchor_iters(self.anchor_iters)
    }
}

/// The scene or dataset at `args.input`, encoded with `encoder` (a progress bar while training).
///
/// # Errors
/// Bad input (exit 2, naming the input) or a failing training run.
pub fn encode_input(args: &Args, encoder: &Encoder) -> crate::Result<Encoded> {
    let name = |e: Error| match e {
        Error::Input(m) if !m.starts_with(&args.input.display().to_string()) => Error::input(&args.input, m),
        other => other,
    };
    let dataset = args.input.is_dir();
    if args.init.is_some() && !dataset {
        return Err(Error::input(&args.input, INIT_NEEDS_DATASET));
    }
    let init = args.init.is_some();
    let training = if init { 0 } else { encoder.config().iters_for(dataset) };
    let iters = training + if dataset { encoder.config().retrain_iters_of_dataset(init) } else { 0 };
    let pb = super::progress::bar(iters as u64, "train", args.quiet || iters == 0);
    let mut progress = |p: &crate::train::Progress| pb.set_position(p.iteration as u64);
    let out = if let Some(target) = args.target() {
        // A line per encode of the search as it finishes (the search takes minutes on large
        // scenes), printed above the training bar.
        let measure = if dataset { "held-out" } else { "orbit" };
        let mut probes = 0;
        let mut events = |e: TargetEvent| match e {
            TargetEvent::Train(p) => progress(p),
            _ if args.quiet => {}
            TargetEvent::Probe { probe: p, met } => {
                probes += 1;
                let (tuned, verdict) = (if p.trained { " (trained)" } else { "" }, if met { "meets" } else { "misses" });
                pb.suspend(|| {
                    eprintln!(
                        "encode {probes}{tuned}: λ = {}, {} bytes, {measure} PSNR {:.2} dB: {verdict} the target ({:.1} s)",
                        p.lambda, p.bytes, p.psnr, p.seconds
                    );
                });
            }
            TargetEvent::Mixing => pb.suspend(|| eprintln!("mixing the best encode's choices with its nearest miss's")),
        };
        target.validate()?;
        if dataset {
            let init: Option<Splats> = args.init.as_ref().map(|p| crate::io::read_scene(p)).transpose()?;
            if init.is_some() {
                encoder.config().validate().map_err(|e| name(e.into()))?;
            } else {
                encoder.config().validate_for_dataset().map_err(|e| name(e.into()))?;
            }
            let ds = crate::io::load_dataset(&args.input, &args.dataset.load_options())?;
            encoder.encode_dataset_to(&ds, init.as_ref(), target, &mut events).map(|mut e| {
                e.report.init = args.init.as_ref().map(|p| p.display().to_string());
                e
            })
        } else {
            let scene: Splats = crate::io::read_scene(&args.input)?;
            encoder.encode_scene_to(&scene, target, &mut events)
        }
    } else if let Some(init) = &args.init {
        encoder.config().validate().map_err(|e| name(e.into()))?;
        let scene: Splats = crate::io::read_scene(init)?;
        let ds = crate::io::load_dataset(&args.input, &args.dataset.load_options())?;
        encoder.encode_trained(&ds, &scene, &mut progress).map(|mut e| {
            e.report.init = Some(init.display().to_string());
            e
        })
    } else if dataset {
        encoder.config().validate_for_dataset().map_err(|e| name(e.into()))?;
        let ds = crate::io::load_dataset(&args.input, &args.dataset.load_options())?;
        encoder.encode_dataset(&ds, &mut progress)
    } else {
        let scene: Splats = crate::io::read_scene(&args.input)?;
        encoder.encode_scene(&scene, &mut progress)
    }
    .map_err(name)?;
    pb.finish_and_clear();
    let mut out = out;
    out.report.input = args.input.display().to_string();
    Ok(out)
}

/// Below this orbit PSNR a scene's encode at a given λ says how to ask for a quality instead.
const LOW_PSNR_DB: f64 = 30.0;

/// The note of an encode at `lambda` whose orbit PSNR is below [`LOW_PSNR_DB`]. `R` is the
/// file's megabits, so at one λ a scene of many Gaussians trades far harder than a small one
/// (docs/codec.md §15): the default λ 20 gives a 1.1 M-Gaussian scene 21 dB.
fn low_psnr_note(lambda: Lambda) -> String {
    format!(
        "note: orbit PSNR below {LOW_PSNR_DB} dB at λ {lambda}; for a quality ask --target-psnr DB, or give a smaller --lambda \
         (λ weighs the file's megabits, so one λ trades harder the more Gaussians a scene has)"
    )
}

pub fn run(args: Args) -> crate::Result<()> {
    crate::io::atomic::check_output_file(&args.output)?;
    if let Some(report) = &args.report {
        crate::io::atomic::check_output_file(report)?;
    }
    let encoder = Encoder::new(args.config())?;
    let out = encode_input(&args, &encoder)?;
    crate::io::atomic::write_bytes_atomic(&args.output, &out.bytes)?;
    let r = &out.report;
    if !args.quiet {
        let per_gaussian = match r.gaussians {
            0 => String::new(),
            n => format!(" ({:.2} bytes/Gaussian)", r.file_bytes as f64 / n as f64),
        };
        // A scene's orbit PSNR is against the input, what `eval --reference INPUT --orbit 8`
        // reads; a dataset's against the scene trained from it, so a dataset shows the coded
        // file's held-out PSNR instead, what `eval OUTPUT DATASET` reads.
        let scene = !args.input.is_dir();
        let psnr = if scene {
            format!(", orbit PSNR {:.2} dB", r.orbit_psnr)
        } else {
            r.heldout_psnr().map_or(String::new(), |h| format!(", held-out PSNR {h:.2} dB"))
        };
        eprintln!(
            "{}: {} Gaussians (of {}), SH degree {}, {} bytes{per_gaussian}{psnr}",
            args.output.display(),
            r.gaussians,
            r.input_gaussians,
            r.sh_degree,
            r.file_bytes,
        );
        if let Some(t) = &r.target {
            // A dataset's target reads the held-out views, a scene's the orbit views.
            let heldout = t.probes.iter().find(|p| p.lambda == r.lambda && p.bytes == r.file_bytes).filter(|_| !scene);
            let (psnr, measure) = heldout.map_or((r.orbit_psnr, "orbit"), |p| (p.psnr, "held-out"));
            eprintln!("λ = {} ({measure} PSNR {psnr:.2} dB), chosen among {} encodes", r.lambda, t.probes.len());
        } else if scene && r.orbit_psnr < LOW_PSNR_DB {
            eprintln!("{}", low_psnr_note(r.lambda));
        }
        super::warn_truncated(r.train.as_ref().map_or(0, |t| t.truncated_frames));
    }
    if let Some(path) = &args.report {
        let text = serde_json::to_string_pretty(r).map_err(|e| Error::failure(path, e))?;
        crate::io::atomic::write_bytes_atomic(path, text.as_bytes())?;
    }
    Ok(())
}
