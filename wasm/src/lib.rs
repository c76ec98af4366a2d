//! `gscodec-wasm`: the `.gsc` decoder for JavaScript (wasm-bindgen). `build.sh` makes the npm
//! package in `pkg/`; README.md documents the API.
//!
//! * [`decode`]`(bytes, options?)` → a scene of `Float32Array`s.
//! * [`info`]`(bytes)` → header, sections and their sizes, without decoding.
//! * [`StreamDecoder`]: `push(chunk)` hands out coarse scenes as importance levels and SH bands
//!   arrive, `finish()` the whole scene.
//!
//! The JavaScript layer here only converts; the logic is in [`scene`] (tested on the host) and the
//! decoder calls are in [`door`].

pub mod door;
pub mod scene;

use js_sys::{Array, Float32Array, Object, Reflect};
use scene::{Error, Stream, Units, WebScene};
use wasm_bindgen::prelude::*;

#[wasm_bindgen(typescript_custom_section)]
const TYPES: &'static str = r#"
/** Units of a scene's arrays: see README.md. */
export type Units = "linear" | "ply";

export interface DecodeOptions {
  /** SH bands above this degree are skipped (0–3; default 3). */
  maxShDegree?: number;
  /** "linear" (default): linear scales, opacity in [0, 1], quaternions (x, y, z, w).
   *  "ply": log scales, opacity logits, quaternions (w, x, y, z), as in the INRIA .ply. */
  units?: Units;
}

/** A decoded scene as structure-of-arrays. */
export interface Scene {
  count: number;
  shDegree: number;
  units: Units;
  /** 3 per Gaussian: x, y, z. */
  positions: Float32Array;
  /** 3 per Gaussian: linear (or log, units "ply") scales along the local axes. */
  scales: Float32Array;
  /** 4 per Gaussian: x, y, z, w (units "ply": w, x, y, z). */
  rotations: Float32Array;
  /** 1 per Gaussian: opacity in [0, 1] (units "ply": its logit). */
  opacities: Float32Array;
  /** (shDegree+1)² RGB coefficients per Gaussian, DC first: sh[(i·(d+1)² + k)·3 + c].
   *  Colour = 0.5 + Σ_k basis_k(dir) · sh_k (the reference 3DGS SH basis). */
  sh: Float32Array;
}

export interface Header {
  versionMajor: number;
  versionMinor: number;
  count: number;
  shDegree: number;
}

export interface SectionInfo {
  /** Attribute group (position, scale, …, sh_band3), or info / padding / unknown. */
  name: string;
  kind: number;
  chunk: number;
  bytes: number;
  optional: boolean;
}

export interface FileInfo extends Header {
  fileBytes: number;
  sections: SectionInfo[];
  /** Gaussians and SH degree of the encoder's input, when the file records them. */
  inputGaussians?: number;
  inputShDegree?: number;
  /** Gaussians of each importance level, in file order: several in a progressive (4.0) file,
   *  one (all) otherwise, none when empty. A StreamDecoder hands out the levels one by one. */
  levels: number[];
  /** Channels stored as one constant, and channels coded with context tables ("group/channel"). */
  constantChannels: string[];
  contextChannels: string[];
}

/** What the functions throw: an Error with a class to branch on. */
export interface GscodecError extends Error {
  name: "GscodecError";
  /** The decoder's error class, or "argument" for a caller's mistake (a bad option, a call on a
   *  finished stream). */
  kind: "format" | "checksum" | "unsupported" | "limits" | "io" | "argument";
  /** A "format" error that only says bytes are missing (a cut download). */
  truncated: boolean;
}
"#;

#[wasm_bindgen]
extern "C" {
    /// The `DecodeOptions` object of the TypeScript declarations above.
    #[wasm_bindgen(typescript_type = "DecodeOptions")]
    pub type Options;
}

/// The error as a JavaScript `Error` named `GscodecError` with `kind` and `truncated` properties.
fn js_error(e: Error) -> JsValue {
    let err = js_sys::Error::new(&e.message);
    err.set_name("GscodecError");
    let _ = Reflect::set(&err, &"kind".into(), &e.kind.into());
    let _ = Reflect::set(&err, &"truncated".into(), &e.truncated.into());
    err.into()
}

fn set(obj: &Object, key: &str, value: impl Into<JsValue>) {
    // Setting a data property on a fresh plain object cannot fail.
    let _ = Reflect::set(obj, &key.into(), &value.into());
}

/// `maxShDegree` and `units` of an options object (absent = the defaults).
fn read_options(options: Option<Options>) -> Result<(u8, Units), Error> {
    let Some(options) = options else { return Ok((3, Units::default())) };
    if !options.is_object() {
        return Err(Error::argument("options must be an object"));
    }
    let get = |key: &str| Reflect::get(&options, &key.into()).unwrap_or(JsValue::UNDEFINED);
    let degree = match get("maxShDegree") {
        v if v.is_undefined() => 3,
        v => match v.as_f64() {
            Some(d) if (0.0..=3.0).contains(&d) && d.fract() == 0.0 => d as u8,
            _ => return Err(Error::argument("maxShDegree must be 0, 1, 2 or 3")),
        },
    };
    let units = match get("units") {
        v if v.is_undefined() => Units::default(),
        v => Units::parse(&v.as_string().ok_or_else(|| Error::argument("units must be a string"))?)?,
    };
    Ok((degree, units))
}

/// The scene as a plain object of `Float32Array`s (copied out of the WASM memory, so they stay
/// valid and can be transferred to another thread).
fn scene_object(s: WebScene) -> JsValue {
    let obj = Object::new();
    set(&obj, "count", s.count() as f64);
    set(&obj, "shDegree", s.sh_degree);
    set(&obj, "units", s.units.name());
    set(&obj, "positions", Float32Array::from(s.positions.as_flattened()));
    set(&obj, "scales", Float32Array::from(s.scales.as_flattened()));
    set(&obj, "rotations", Float32Array::from(s.rotations.as_flattened()));
    set(&obj, "opacities", Float32Array::from(&s.opacities[..]));
    set(&obj, "sh", Float32Array::from(&s.sh[..]));
    obj.into()
}

fn header_object(h: &door::Header) -> Object {
    let obj = Object::new();
    set(&obj, "versionMajor", h.version_major);
    set(&obj, "versionMinor", h.version_minor);
    set(&obj, "count", h.gaussians);
    set(&obj, "shDegree", h.sh_degree);
    obj
}

/// Decodes a whole `.gsc` file.
#[wasm_bindgen(unchecked_return_type = "Scene")]
pub fn decode(bytes: &[u8], options: Option<Options>) -> Result<JsValue, JsValue> {
    let (degree, units) = read_options(options).map_err(js_error)?;
    let splats = door::decode(bytes, degree).map_err(|e| js_error(e.into()))?;
    Ok(scene_object(WebScene::new(splats, units)))
}

/// Checks a file's structure and CRCs and lists what it holds, without decoding the streams.
#[wasm_bindgen(unchecked_return_type = "FileInfo")]
pub fn info(bytes: &[u8]) -> Result<JsValue, JsValue> {
    let fi = door::info(bytes).map_err(|e| js_error(e.into()))?;
    let obj = header_object(&fi.info.header);
    set(&obj, "fileBytes", fi.info.file_bytes as f64);
    let sections = Array::new();
    for s in &fi.info.sections {
        let o = Object::new();
        set(&o, "name", s.name);
        set(&o, "kind", s.kind);
        set(&o, "chunk", s.chunk);
        set(&o, "bytes", s.bytes as f64);
        set(&o, "optional", s.optional);
        sections.push(&o);
    }
    set(&obj, "sections", sections);
    set(&obj, "levels", fi.levels.iter().map(|&k| JsValue::from(k as f64)).collect::<Array>());
    if let Some(e) = fi.encoder {
        set(&obj, "inputGaussians", e.input_gaussians);
        set(&obj, "inputShDegree", e.input_sh_degree);
    }
    let strings = |v: &[String]| v.iter().map(|s| JsValue::from_str(s)).collect::<Array>();
    set(&obj, "constantChannels", strings(&fi.constant_channels));
    set(&obj, "contextChannels", strings(&fi.context_channels));
    Ok(obj.into())
}

/// Decodes a file as it arrives (e.g. from a `fetch` body): `push` each chunk, then `finish`.
#[wasm_bindgen]
pub struct StreamDecoder {
    stream: Stream,
    units: Units,
}

#[wasm_bindgen]
impl StreamDecoder {
    #[wasm_bindgen(constructor)]
    pub fn new(options: Option<Options>) -> Result<StreamDecoder, JsValue> {
        let (degree, units) = read_options(options).map_err(js_error)?;
        Ok(StreamDecoder { stream: Stream::new(degree), units })
    }

    /// Appends the next bytes. Returns a coarse scene when one with more than the last became
    /// available (in a progressive file each importance level of Gaussians, then in any file each
    /// SH band, short of the full scene), else `undefined`. Throws on a malformed file; after an
    /// error every call throws it again.
    #[wasm_bindgen(unchecked_return_type = "Scene | undefined")]
    pub fn push(&mut self, chunk: &[u8]) -> Result<JsValue, JsValue> {
        let scene = self.stream.push(chunk).map_err(js_error)?;
        Ok(scene.map_or(JsValue::UNDEFINED, |s| scene_object(WebScene::new(s, self.units))))
    }

    /// Decodes and checks the complete file (a `truncated` error if bytes are missing).
    #[wasm_bindgen(unchecked_return_type = "Scene")]
    pub fn finish(&mut self) -> Result<JsValue, JsValue> {
        let splats = self.stream.finish().map_err(js_error)?;
        Ok(scene_object(WebScene::new(splats, self.units)))
    }

    /// The file's header once its first 16 bytes have arrived, else `undefined`.
    #[wasm_bindgen(getter, unchecked_return_type = "Header | undefined")]
    pub fn header(&self) -> JsValue {
        self.stream.header().map_or(JsValue::UNDEFINED, |h| header_object(&h).into())
    }

    #[wasm_bindgen(getter, js_name = bytesReceived)]
    pub fn bytes_received(&self) -> f64 {
        self.stream.bytes_received() as f64
    }
}

/// The package version.
#[wasm_bindgen]
pub fn version() -> String {
    env!("CARGO_PKG_VERSION").to_string()
}
