//! `gscodec render`: render a scene from a dataset's cameras or an orbit, to PNG or EXR.

use super::progress;
use super::sample::parse_size;
use crate::io::atomic::write_dir_atomic;
use crate::io::image::{write_exr, write_png};
use crate::io::{load_dataset, read_scene, LoadOptions, Split};
use crate::views::{orbit_cameras, UpAxis};
use crate::{Error, Result};
use gscodec_decoder::render::render;
use gscodec_decoder::{Camera, RenderOptions, Splats};
use std::path::{Path, PathBuf};

/// Render a scene (.gsc, .ply, .spz, .splat) into DIR, one image per camera, named by frame index.
#[derive(Debug, clap::Args)]
#[command(group = clap::ArgGroup::new("views").required(true).args(["cameras", "orbit"]))]
pub struct Args {
    /// Scene file (.gsc, .ply, .spz, .splat).
    pub scene: PathBuf,
    /// Output directory.
    #[arg(short, long)]
    pub out: PathBuf,
    /// Render from the cameras of this dataset (transforms*.json directory or COLMAP).
    #[arg(long)]
    pub cameras: Option<PathBuf>,
    /// Which frames of the dataset.
    #[arg(long, value_enum, default_value = "test", requires = "cameras")]
    pub split: Split,
    /// Render N views on an orbit around the scene's robust centre instead.
    #[arg(long, value_name = "N")]
    pub orbit: Option<usize>,
    /// World up axis of the orbit (the reference 3DGS / COLMAP convention is -y).
    #[arg(long, value_enum, default_value = "-y", allow_hyphen_values = true)]
    pub up: UpAxis,
    /// Image size WxH (default: the dataset's frame size; 256x256 for --orbit).
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
    /// Output image format.
    #[arg(long, value_enum, default_value = "png")]
    pub format: Format,
    /// Renderer.
    #[arg(long, value_enum, default_value = "cpu")]
    pub backend: Backend,
    /// Dataset image options (--cameras) and --background (default: the dataset's, black for --orbit).
    #[command(flatten)]
    pub dataset: super::dataset_args::DatasetArgs,
    /// No progress output.
    #[arg(long)]
    pub quiet: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    Png,
    Exr,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Backend {
    Cpu,
    /// wgpu compute renderer (builds with the `gpu` cargo feature; any Vulkan/Metal/DX12 adapter,
    /// including Mesa's software lavapipe).
    Gpu,
}

/// Parses `r,g,b` with finite components in [0,1].
pub fn parse_rgb(s: &str) -> std::result::Result<[f32; 3], String> {
    let v: Vec<f32> =
        s.split(',').map(|t| t.trim().parse::<f32>()).collect::<std::result::Result<_, _>>().map_err(|_| format!("`{s}` is not r,g,b"))?;
    match v.as_slice() {
        &[r, g, b] if v.iter().all(|x| (0.0..=1.0).contains(x)) => Ok([r, g, b]),
        _ => Err(format!("`{s}` must be three numbers in [0,1], e.g. 1,1,1")),
    }
}

/// A camera to render from, with the frame index it is named by and (for datasets) its photo.
pub struct View {
    pub index: usize,
    pub camera: Camera,
    pub target: Option<crate::io::FrameImage>,
}

/// The views of a dataset split (at the frames' own size unless `size` is given) and its background.
pub fn dataset_views(data: &Path, split: Split, size: Option<(u32, u32)>, opts: &LoadOptions) -> Result<(Vec<View>, [f32; 3])> {
    let ds = load_dataset(data, opts)?;
    let views: Vec<View> = ds
        .split(split)
        .into_iter()
        .map(|f| View { index: f.index, camera: size.map_or(f.camera, |(w, h)| f.camera.resized(w, h)), target: Some(f.image.clone()) })
        .collect();
    if views.is_empty() {
        return Err(Error::input(data, format!("the {split:?} split has no frames").to_lowercase()));
    }
    Ok((views, ds.background))
}

/// Orbit views around `scene`.
pub fn orbit_views(scene: &Splats, n: usize, size: Option<(u32, u32)>, up: UpAxis) -> Vec<View> {
    let (w, h) = size.unwrap_or((256, 256));
    orbit_cameras(scene, n, w, h, up.vector()).into_iter().enumerate().map(|(index, camera)| View { index, camera, target: None }).collect()
}

/// Output file name of frame `index`: zero-padded to the digits of `max_index` (at least 3).
pub fn frame_name(index: usize, max_index: usize, ext: &str) -> String {
    let digits = max_index.max(1).to_string().len().max(3);
    format!("{index:0digits$}.{ext}")
}

pub fn run(args: Args) -> Result<()> {
    let scene = read_scene(&args.scene)?;
    let (views, default_bg) = match (&args.cameras, args.orbit) {
        (Some(data), _) => dataset_views(data, args.split, args.size, &args.dataset.load_options())?,
        (None, Some(0)) => return Err(Error::input(&args.scene, "--orbit needs at least one view")),
        (None, Some(n)) => (orbit_views(&scene, n, args.size, args.up), [0.0; 3]),
        (None, None) => unreachable!("clap requires --cameras or --orbit"),
    };
    let renderer = Renderer::new(args.backend, &args.scene)?;
    let opts = RenderOptions { background: args.dataset.background.unwrap_or(default_bg), max_sh_degree: 3 };
    let max_index = views.iter().map(|v| v.index).max().unwrap_or(0);
    let pb = progress::bar(views.len() as u64, "render", args.quiet);
    write_dir_atomic(&args.out, |tmp| {
        for v in &views {
            let img = renderer.render(&scene, &v.camera, &opts).map_err(|e| Error::failure(&args.out, e))?;
            match args.format {
                Format::Png => write_png(&tmp.join(frame_name(v.index, max_index, "png")), &img)?,
                Format::Exr => write_exr(&tmp.join(frame_name(v.index, max_index, "exr")), &img)?,
            }
            pb.inc(1);
        }
        Ok(())
    })?;
    pb.finish_and_clear();
    Ok(())
}

/// The selected backend, ready to draw frames.
enum Renderer {
    Cpu,
    #[cfg(feature = "gpu")]
    Gpu(Box<gscodec_decoder::render::gpu::GpuRenderer>),
}

impl Renderer {
    fn new(backend: Backend, scene: &Path) -> Result<Renderer> {
        match backend {
            Backend::Cpu => Ok(Renderer::Cpu),
            #[cfg(feature = "gpu")]
            Backend::Gpu => gscodec_decoder::render::gpu::GpuRenderer::new()
                .map(|r| Renderer::Gpu(Box::new(r)))
                .map_err(|e| Error::failure(scene, format!("--backend gpu: {e}"))),
            #[cfg(not(feature = "gpu"))]
            Backend::Gpu => Err(Error::input(scene, "--backend gpu: this build has no GPU renderer (build with `--features gpu`)")),
        }
    }

    fn render(&self, scene: &Splats, cam: &Camera, opts: &RenderOptions) -> std::result::Result<gscodec_decoder::Image, String> {
        match self {
            Renderer::Cpu => Ok(render(scene, cam, opts)),
            #[cfg(feature = "gpu")]
            Renderer::Gpu(r) => r.render(scene, cam, opts).map_err(|e| e.to_string()),
        }
    }
}
