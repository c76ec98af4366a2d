//! The Rust side of the package, free of JavaScript types so that it is tested on the host: a
//! decoded scene in the arrays and units a web player uploads ([`WebScene`]), the streaming
//! decoder's state machine ([`Stream`]) and the package's error ([`Error`]).

use crate::door::{self, math, DecodeError, Header, Splats};

/// Units of the arrays handed out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Units {
    /// What web renderers upload and glTF's `KHR_gaussian_splatting` stores: linear scales
    /// (`exp` of the coded log scales), opacity in [0, 1] (the sigmoid of the logit), unit
    /// quaternions in (x, y, z, w) order (three.js, glTF).
    #[default]
    Linear,
    /// As in the INRIA `.ply` (what `gscodec decode` writes, bit for bit): log scales, opacity
    /// logits, quaternions (w, x, y, z) as decoded (not renormalised).
    Ply,
}

impl Units {
    pub fn parse(s: &str) -> Result<Units, Error> {
        match s {
            "linear" => Ok(Units::Linear),
            "ply" => Ok(Units::Ply),
            _ => Err(Error::argument(format!("units must be \"linear\" or \"ply\", not {s:?}"))),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Units::Linear => "linear",
            Units::Ply => "ply",
        }
    }
}

/// A decoded scene as flat arrays for upload. Positions are the coded world coordinates
/// (unchanged in either unit system).
#[derive(Debug, Clone, PartialEq)]
pub struct WebScene {
    pub units: Units,
    pub sh_degree: u8,
    pub positions: Vec<[f32; 3]>,
    pub scales: Vec<[f32; 3]>,
    pub rotations: Vec<[f32; 4]>,
    pub opacities: Vec<f32>,
    /// All `(d+1)²` SH coefficients per Gaussian, RGB interleaved, DC first:
    /// `sh[(i·(d+1)² + k)·3 + c]`. The raw coefficients: a colour is `0.5 + Σ_k basis_k · sh_k`.
    pub sh: Vec<f32>,
}

impl WebScene {
    /// Converts a decoded scene, reusing its buffers (only `sh` is new).
    pub fn new(s: Splats, units: Units) -> WebScene {
        let k = s.rest_coeffs();
        let mut sh = Vec::with_capacity(s.len() * (k + 1) * 3);
        for (i, dc) in s.sh_dc.iter().enumerate() {
            sh.extend_from_slice(dc);
            sh.extend_from_slice(&s.sh_rest[i * k * 3..(i + 1) * k * 3]);
        }
        let (mut scales, mut rotations, mut opacities) = (s.log_scales, s.rotations, s.opacity_logits);
        if units == Units::Linear {
            scales.iter_mut().flatten().for_each(|v| *v = v.exp());
            opacities.iter_mut().for_each(|v| *v = math::sigmoid(*v));
            rotations.iter_mut().for_each(|q| {
                let [w, x, y, z] = math::normalize_quat(*q);
                *q = [x, y, z, w];
            });
        }
        WebScene { units, sh_degree: s.sh_degree, positions: s.positions, scales, rotations, opacities, sh }
    }

    pub fn count(&self) -> usize {
        self.positions.len()
    }
}

/// The package's error: a class (`kind`) to branch on and a message.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Error {
    /// The decoder's class (`DecodeError::class`: `io`, `format`, `checksum`, `unsupported`,
    /// `limits`) or `argument` (the caller's mistake: a bad option, a call out of order).
    pub kind: &'static str,
    /// A `format` error that only says bytes are missing.
    pub truncated: bool,
    pub message: String,
}

impl Error {
    pub fn argument(message: impl Into<String>) -> Error {
        Error { kind: "argument", truncated: false, message: message.into() }
    }
}

impl From<DecodeError> for Error {
    fn from(e: DecodeError) -> Error {
        Error { kind: e.class(), truncated: door::is_truncation(&e), message: e.to_string() }
    }
}

impl std::fmt::Display for Error {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

/// The fixed header's size: [`Stream`] reads the header once this much has arrived.
const HEADER_BYTES: usize = 16;
/// [`Stream`] looks for newly arrived SH bands once the data has grown by an eighth (at least
/// this many bytes) since it last looked: each look checks the CRCs of everything received, so
/// looking on every small network chunk would cost time quadratic in the file size.
const MIN_CHECK_STEP: usize = 16 << 10;

/// Decodes a file as it arrives. [`Stream::push`] hands out a coarse scene whenever more has
/// arrived than the last one had — in a progressive (4.0) file each importance level of
/// Gaussians (their base: positions, scales, rotations, opacities, DC colour), then, in any file,
/// each SH band — as long as that is still short of the full scene;
/// [`Stream::finish`] decodes and checks the whole file. A failure is final: later calls repeat it.
#[derive(Debug)]
pub struct Stream {
    max_sh_degree: u8,
    min_check_step: usize,
    buf: Vec<u8>,
    header: Option<Header>,
    /// Gaussians and SH degree of the last coarse scene handed out.
    shown: Option<(usize, u8)>,
    next_check: usize,
    failed: Option<Error>,
    finished: bool,
}

impl Stream {
    /// A stream decoding SH bands up to `max_sh_degree` (0–3).
    pub fn new(max_sh_degree: u8) -> Stream {
        Stream::with_check_step(max_sh_degree, MIN_CHECK_STEP)
    }

    fn with_check_step(max_sh_degree: u8, min_check_step: usize) -> Stream {
        Stream { max_sh_degree, min_check_step, buf: Vec::new(), header: None, shown: None, next_check: 0, failed: None, finished: false }
    }

    /// The file's header, once its first 16 bytes have arrived.
    pub fn header(&self) -> Option<Header> {
        self.header
    }

    pub fn bytes_received(&self) -> usize {
        self.buf.len()
    }

    /// Appends the next bytes of the file; a coarse scene when one with more SH bands than the
    /// last became available, else `None`.
    pub fn push(&mut self, chunk: &[u8]) -> Result<Option<Splats>, Error> {
        self.usable()?;
        self.buf.extend_from_slice(chunk);
        let result = self.preview();
        if let Err(e) = &result {
            self.failed = Some(e.clone());
        }
        result
    }

    /// The whole scene: the bytes pushed must be the complete file (else a `truncated` error).
    pub fn finish(&mut self) -> Result<Splats, Error> {
        self.usable()?;
        self.finished = true;
        let result = door::decode(&std::mem::take(&mut self.buf), self.max_sh_degree).map_err(Error::from);
        if let Err(e) = &result {
            self.failed = Some(e.clone());
        }
        result
    }

    fn usable(&self) -> Result<(), Error> {
        match (&self.failed, self.finished) {
            (Some(e), _) => Err(e.clone()),
            (None, true) => Err(Error::argument("the stream is finished")),
            (None, false) => Ok(()),
        }
    }

    fn preview(&mut self) -> Result<Option<Splats>, Error> {
        let header = match self.header {
            Some(h) => h,
            None if self.buf.len() < HEADER_BYTES => return Ok(None),
            None => *self.header.insert(door::peek(&self.buf)?),
        };
        // The full scene is `finish`'s; the best coarse one has every Gaussian and one band less.
        let (n, wanted) = (header.gaussians as usize, header.sh_degree.min(self.max_sh_degree));
        let done = |s: (usize, u8)| s.0 == n && s.1 + 1 >= wanted;
        if n == 0 || self.shown.is_some_and(done) || self.buf.len() < self.next_check {
            return Ok(None);
        }
        self.next_check = self.buf.len() + (self.buf.len() / 8).max(self.min_check_step);
        match door::prefix_extent(&self.buf, self.max_sh_degree)? {
            // More Gaussians, or as many with more bands (levels arrive before the bands).
            Some(e) if e != (n, wanted) && self.shown.is_none_or(|s| e > s) => {
                let scene = door::decode_prefix(&self.buf, self.max_sh_degree)?;
                self.shown = scene.as_ref().map(|s| (s.len(), s.sh_degree)).or(self.shown);
                Ok(scene)
            }
            _ => Ok(None),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vector(name: &str) -> Vec<u8> {
        let path = format!("{}/../bitstream-spec/vectors/{name}", env!("CARGO_MANIFEST_DIR"));
        std::fs::read(&path).unwrap_or_else(|e| panic!("{path}: {e}"))
    }

    #[test]
    fn linear_units_are_exp_sigmoid_and_xyzw() {
        let bytes = vector("tiny.gsc");
        let s = door::decode(&bytes, 3).unwrap();
        let w = WebScene::new(s.clone(), Units::Linear);
        assert_eq!((w.count(), w.sh_degree, w.units), (1000, 3, Units::Linear));
        for i in 0..s.len() {
            assert_eq!(w.positions[i], s.positions[i]);
            for a in 0..3 {
                assert_eq!(w.scales[i][a], s.log_scales[i][a].exp());
                assert!(w.scales[i][a] > 0.0);
            }
            let o = w.opacities[i];
            assert!((0.0..=1.0).contains(&o));
            assert!((o / (1.0 - o)).ln() - s.opacity_logits[i] < 1e-3 * (1.0 + s.opacity_logits[i].abs()));
            // (x, y, z, w), unit length, the same rotation as the decoded (w, x, y, z).
            let [x, y, z, qw] = w.rotations[i];
            assert!(((x * x + y * y + z * z + qw * qw).sqrt() - 1.0).abs() < 1e-6);
            let r = s.rotations[i];
            let n = (r.iter().map(|v| v * v).sum::<f32>()).sqrt();
            for (got, want) in [x, y, z, qw].into_iter().zip([r[1], r[2], r[3], r[0]]) {
                assert!((got - want / n).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn ply_units_are_the_decoded_values_and_sh_is_coefficient_major() {
        let bytes = vector("tiny.gsc");
        let s = door::decode(&bytes, 3).unwrap();
        let w = WebScene::new(s.clone(), Units::Ply);
        assert_eq!(w.scales, s.log_scales);
        assert_eq!(w.rotations, s.rotations);
        assert_eq!(w.opacities, s.opacity_logits);
        assert_eq!(w.sh.len(), 1000 * 16 * 3);
        for i in [0, 1, 517, 999] {
            assert_eq!(w.sh[i * 48..i * 48 + 3], s.sh_dc[i]);
            assert_eq!(w.sh[i * 48 + 3..(i + 1) * 48], *s.rest_of(i));
        }
        // A lower SH degree keeps (d+1)² coefficients per Gaussian.
        let w1 = WebScene::new(door::decode(&bytes, 1).unwrap(), Units::Ply);
        assert_eq!((w1.sh_degree, w1.sh.len()), (1, 1000 * 4 * 3));
        assert_eq!(w1.sh[4 * 12..4 * 12 + 12], w.sh[4 * 48..4 * 48 + 12]);
    }

    #[test]
    fn units_parse() {
        assert_eq!(Units::parse("linear"), Ok(Units::Linear));
        assert_eq!(Units::parse("ply"), Ok(Units::Ply));
        assert_eq!(Units::parse("log").unwrap_err().kind, "argument");
        assert_eq!(Units::default().name(), "linear");
    }

    /// Pushes `bytes` in pieces of `step`; returns the coarse scenes and the final one.
    fn stream(bytes: &[u8], max: u8, step: usize, check: usize) -> (Vec<Splats>, Splats) {
        let mut st = Stream::with_check_step(max, check);
        let mut previews = Vec::new();
        for piece in bytes.chunks(step) {
            previews.extend(st.push(piece).unwrap());
        }
        assert_eq!(st.bytes_received(), bytes.len());
        (previews, st.finish().unwrap())
    }

    #[test]
    fn stream_hands_out_each_coarser_level_then_the_full_scene() {
        let bytes = vector("tiny.gsc");
        let full = door::decode(&bytes, 3).unwrap();
        let (previews, last) = stream(&bytes, 3, 97, 1);
        assert_eq!(last, full);
        // Base, then band 1, then band 2; each equals a decode limited to that degree.
        assert_eq!(previews.iter().map(|s| s.sh_degree).collect::<Vec<_>>(), [0, 1, 2]);
        for p in &previews {
            assert_eq!(*p, door::decode(&bytes, p.sh_degree).unwrap());
        }
        // Limited to SH 1: only the base is coarser.
        let (previews, last) = stream(&bytes, 1, 97, 1);
        assert_eq!(previews.iter().map(|s| s.sh_degree).collect::<Vec<_>>(), [0]);
        assert_eq!(last, door::decode(&bytes, 1).unwrap());
        // In one piece there is nothing coarse to show.
        let (previews, last) = stream(&bytes, 3, bytes.len(), 1);
        assert!(previews.is_empty());
        assert_eq!(last, full);
    }

    #[test]
    fn stream_hands_out_each_importance_level_then_each_band() {
        let bytes = vector("levels.gsc");
        let full = door::decode(&bytes, 3).unwrap();
        let (previews, last) = stream(&bytes, 3, 97, 1);
        assert_eq!(last, full);
        // Growing, from the first level on, each a whole-level prefix; the growing look interval
        // may skip a step that arrives between two looks.
        let shown: Vec<(usize, u8)> = previews.iter().map(|s| (s.len(), s.sh_degree)).collect();
        let steps = [(63, 0), (125, 0), (250, 0), (500, 0), (1000, 0), (1000, 1), (1000, 2)];
        assert!(shown.len() >= 5 && shown[0] == steps[0] && shown.windows(2).all(|w| w[0] < w[1]), "{shown:?}");
        assert!(shown.iter().all(|s| steps.contains(s)), "{shown:?}");
        // Each is the first Gaussians of the full scene, with the bands that arrived.
        for p in &previews {
            let mut first = full.clone();
            first.retain_indices(|i| i < p.len());
            assert_eq!(*p, first.with_sh_degree(p.sh_degree));
        }
        // Limited to SH 0, the levels are still handed out, short of the last one.
        let (previews, _) = stream(&bytes, 0, 97, 1);
        let shown: Vec<(usize, u8)> = previews.iter().map(|s| (s.len(), s.sh_degree)).collect();
        assert!(!shown.is_empty() && shown.iter().all(|s| steps[..4].contains(s)), "{shown:?}");
    }

    #[test]
    fn stream_looks_for_bands_at_growing_intervals() {
        let bytes = vector("chunks.gsc");
        let full = door::decode(&bytes, 3).unwrap();
        let mut st = Stream::new(3);
        let mut looks = 0;
        let mut degrees = Vec::new();
        for piece in bytes.chunks(1000) {
            let before = st.next_check;
            if let Some(p) = st.push(piece).unwrap() {
                degrees.push(p.sh_degree);
            }
            looks += usize::from(st.next_check != before);
        }
        // Strictly increasing degrees, fewer looks than pieces (132), and the same final scene.
        assert!(degrees.windows(2).all(|w| w[0] < w[1]), "{degrees:?}");
        assert!(looks < 30, "{looks} looks");
        assert_eq!(st.finish().unwrap(), full);
    }

    #[test]
    fn stream_errors_are_classified_and_final() {
        let bytes = vector("tiny.gsc");
        // Truncated at finish.
        let mut st = Stream::new(3);
        assert!(st.push(&bytes[..bytes.len() - 1]).is_ok());
        assert_eq!(st.header().map(|h| (h.gaussians, h.sh_degree)), Some((1000, 3)));
        let e = st.finish().unwrap_err();
        assert_eq!((e.kind, e.truncated), ("format", true), "{e}");
        assert_eq!(st.push(&bytes[bytes.len() - 1..]).unwrap_err(), e);
        // Not a .gsc: known once the header has arrived, and final.
        let mut st = Stream::new(3);
        let e = st.push(b"ply\nformat binary").unwrap_err();
        assert_eq!((e.kind, e.truncated), ("format", false), "{e}");
        assert_eq!(st.push(&bytes).unwrap_err(), e);
        // A flipped payload byte fails its CRC, on push (when the section is looked at) or finish.
        let mut bad = bytes.clone();
        let at = bad.len() - 10;
        bad[at] ^= 0x40;
        let mut st = Stream::with_check_step(3, 1);
        let e = bad.chunks(500).map(|c| st.push(c)).find_map(Result::err).or_else(|| st.finish().err()).unwrap();
        assert_eq!(e.kind, "checksum", "{e}");
        // Finishing twice is the caller's mistake.
        let mut st = Stream::new(3);
        st.push(&bytes).unwrap();
        assert!(st.finish().is_ok());
        assert_eq!(st.finish().unwrap_err().kind, "argument");
        assert_eq!(st.push(&bytes).unwrap_err().kind, "argument");
    }

    #[test]
    fn stream_of_sh0_and_empty_files() {
        for name in ["hand.gsc", "empty.gsc", "empty3.gsc", "one.gsc"] {
            let bytes = vector(name);
            let (previews, last) = stream(&bytes, 3, 7, 1);
            assert_eq!(last, door::decode(&bytes, 3).unwrap(), "{name}");
            assert!(previews.iter().all(|p| p.sh_degree < last.sh_degree), "{name}");
        }
    }
}
