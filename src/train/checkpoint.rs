//! Checkpoints of a training run: everything the loop carries from one iteration to the next
//! (scene, Adam moments and step, RNG, view order, densification statistics, SH degree, record so
//! far), so that a resumed run continues to the bit-identical result of an uninterrupted one on
//! the CPU backend.
//!
//! File `DIR/checkpoint.bin`: the 8 bytes `GSCKPT\r\n`, a little-endian `u32` format version
//! ([`VERSION`]), then the state serialised with bincode 2 (standard configuration). It is
//! rewritten atomically, so a kill while writing leaves the previous checkpoint.

use super::{ReportPoint, StageTimes};
use crate::io::atomic::write_bytes_atomic;
use crate::{Error, Result};
use gscodec_decoder::Splats;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

const MAGIC: &[u8; 8] = b"GSCKPT\r\n";
/// Bumped whenever [`State`]'s layout changes.
pub const VERSION: u32 = 1;
/// The checkpoint file inside a checkpoint folder.
pub const FILE: &str = "checkpoint.bin";

/// A scene's arrays, as stored.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SplatsData {
    sh_degree: u8,
    positions: Vec<[f32; 3]>,
    log_scales: Vec<[f32; 3]>,
    rotations: Vec<[f32; 4]>,
    opacity_logits: Vec<f32>,
    sh_dc: Vec<[f32; 3]>,
    sh_rest: Vec<f32>,
}

impl From<&Splats> for SplatsData {
    fn from(s: &Splats) -> Self {
        SplatsData {
            sh_degree: s.sh_degree,
            positions: s.positions.clone(),
            log_scales: s.log_scales.clone(),
            rotations: s.rotations.clone(),
            opacity_logits: s.opacity_logits.clone(),
            sh_dc: s.sh_dc.clone(),
            sh_rest: s.sh_rest.clone(),
        }
    }
}

impl SplatsData {
    fn consistent(&self, n: usize) -> bool {
        let rest = gscodec_decoder::math::sh_rest_coeffs(self.sh_degree.min(3)) * 3;
        self.sh_degree <= 3
            && [self.positions.len(), self.log_scales.len(), self.rotations.len(), self.opacity_logits.len(), self.sh_dc.len()]
                .iter()
                .all(|&l| l == n)
            && self.sh_rest.len() == n * rest
    }

    /// The scene (sizes checked by [`State::check`]).
    pub fn into_splats(self) -> Splats {
        Splats {
            sh_degree: self.sh_degree,
            positions: self.positions,
            log_scales: self.log_scales,
            rotations: self.rotations,
            opacity_logits: self.opacity_logits,
            sh_dc: self.sh_dc,
            sh_rest: self.sh_rest,
        }
    }
}

/// A [`ReportPoint`] as stored (the report's JSON form skips absent fields, which bincode cannot).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PointData {
    iteration: u64,
    seconds: f64,
    loss: f64,
    gaussians: u64,
    test_psnr: Option<f64>,
}

impl From<&ReportPoint> for PointData {
    fn from(p: &ReportPoint) -> Self {
        PointData { iteration: p.iteration as u64, seconds: p.seconds, loss: p.loss, gaussians: p.gaussians as u64, test_psnr: p.test_psnr }
    }
}

impl From<PointData> for ReportPoint {
    fn from(p: PointData) -> Self {
        ReportPoint {
            iteration: p.iteration as usize,
            seconds: p.seconds,
            loss: p.loss,
            gaussians: p.gaussians as usize,
            test_psnr: p.test_psnr,
        }
    }
}

/// The training loop's state after iteration `iteration`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct State {
    /// The run's settings (JSON of `TrainConfig`) and dataset (frame names); a resume must match.
    pub fingerprint: String,
    pub iteration: u64,
    pub params: SplatsData,
    pub adam_m: SplatsData,
    pub adam_v: SplatsData,
    pub adam_step: u64,
    pub rng: u64,
    pub order: Vec<u64>,
    pub degree: u8,
    pub peak: u64,
    pub grad_accum: Vec<f32>,
    pub count: Vec<u32>,
    pub max_radius: Vec<f32>,
    pub points: Vec<PointData>,
    pub stages: StageTimes,
    pub loss_sum: f64,
    pub loss_n: u64,
    pub train_seconds: f64,
}

impl State {
    /// Checks that the scene, moments and statistics have consistent sizes.
    pub fn check(&self, path: &Path) -> Result<()> {
        let n = self.params.positions.len();
        let ok = [&self.params, &self.adam_m, &self.adam_v].iter().all(|s| s.consistent(n))
            && [self.grad_accum.len(), self.count.len(), self.max_radius.len()].iter().all(|&l| l == n);
        if ok {
            Ok(())
        } else {
            Err(Error::input(path, "inconsistent scene, optimiser or statistics arrays"))
        }
    }
}

/// The checkpoint file of a folder.
pub fn file(dir: &Path) -> PathBuf {
    dir.join(FILE)
}

/// Writes `state` to `dir/checkpoint.bin` atomically (creating `dir`).
pub fn save(dir: &Path, state: &State) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::failure(dir, format!("cannot create: {e}")))?;
    let mut bytes = MAGIC.to_vec();
    bytes.extend(VERSION.to_le_bytes());
    let body = bincode::serde::encode_to_vec(state, bincode::config::standard()).map_err(|e| Error::failure(dir, e))?;
    bytes.extend(body);
    write_bytes_atomic(&file(dir), &bytes)
}

/// Reads `dir/checkpoint.bin`.
///
/// # Errors
/// [`Error::input`] when it is missing, of another format version, or malformed.
pub fn load(dir: &Path) -> Result<State> {
    let path = file(dir);
    let bytes = std::fs::read(&path).map_err(|e| Error::input(&path, format!("cannot read checkpoint: {e}")))?;
    if bytes.len() < 12 || &bytes[..8] != MAGIC {
        return Err(Error::input(&path, "not a gscodec checkpoint"));
    }
    let version = u32::from_le_bytes(bytes[8..12].try_into().expect("4 bytes"));
    if version != VERSION {
        return Err(Error::input(&path, format!("checkpoint format version {version}, this build reads version {VERSION}")));
    }
    let (state, used): (State, usize) = bincode::serde::decode_from_slice(&bytes[12..], bincode::config::standard())
        .map_err(|e| Error::input(&path, format!("corrupt checkpoint: {e}")))?;
    if used != bytes.len() - 12 {
        return Err(Error::input(&path, "trailing bytes after the checkpoint"));
    }
    Ok(state)
}

static INTERRUPTED: AtomicBool = AtomicBool::new(false);

#[cfg(unix)]
extern "C" fn on_sigint(_: libc::c_int) {
    INTERRUPTED.store(true, Ordering::SeqCst);
    // A second Ctrl-C ends the process at once.
    // SAFETY: `signal` is async-signal-safe.
    unsafe {
        libc::signal(libc::SIGINT, libc::SIG_DFL);
    }
}

/// Makes Ctrl-C (SIGINT) ask the training loop to stop after the current iteration (writing a
/// checkpoint) instead of killing the process; a second Ctrl-C kills it.
pub fn catch_interrupt() {
    #[cfg(unix)]
    // SAFETY: installs a handler that only stores an atomic and resets the disposition.
    unsafe {
        libc::signal(libc::SIGINT, on_sigint as *const () as libc::sighandler_t);
    }
}

/// Whether Ctrl-C was pressed since [`catch_interrupt`].
pub fn interrupted() -> bool {
    INTERRUPTED.load(Ordering::SeqCst)
}
