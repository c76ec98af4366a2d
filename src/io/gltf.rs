//! glTF 2.0 with `KHR_gaussian_splatting` (Khronos release candidate): read and write `.glb`
//! (binary) and `.gltf` (JSON; written with its buffer embedded as a `data:` URI, read with
//! embedded, GLB or external buffers).
//!
//! Attributes, per the extension's text: `POSITION` (VEC3), `KHR_gaussian_splatting:ROTATION`
//! (VEC4 unit quaternion, glTF order `x, y, z, w`), `:SCALE` (VEC3, **linear** standard
//! deviations, `exp` of the `.ply` log-scales), `:OPACITY` (SCALAR, **linear** in [0, 1], the
//! sigmoid of the `.ply` logit), `:SH_DEGREE_0_COEF_0` (VEC3, the raw DC coefficients: colour =
//! `SH_C0·c + ½`) and `:SH_DEGREE_l_COEF_n` (VEC3, `n = 0..2l` in `m = −l..l` order, with the
//! Condon–Shortley phase — the reference 3DGS basis, so the coefficients are the `.ply`'s `f_rest`
//! in coefficient order); mode POINTS; extension object `kernel: "ellipse"`,
//! `colorSpace: "srgb_rec709_display"`.
//!
//! Coordinates: like PlayCanvas's splat-transform, the writer turns the `.ply` frame (the COLMAP /
//! reference-3DGS convention, −y up) into glTF's (+y up) by a 180° rotation about z:
//! `(x, y, z) → (−x, −y, z)`, quaternions are pre-multiplied by that rotation, and each SH
//! coefficient of order `m` is multiplied by `(−1)^m` (exactly the SH rotation for this turn). The
//! reader undoes it, so `.ply → .glb → .ply` keeps the scene in place. All of it is exact except
//! `exp`/`ln` of the scales and `sigmoid`/`logit` of the opacity (a few f32 ulps; logits beyond
//! about ±16 saturate).
//!
//! The reader takes every primitive that carries the extension in the default scene (or in all
//! meshes when there are no nodes), with node transforms made of translations and uniform scales;
//! a node rotation (which would rotate the SH) is refused. Accessors may be float or the
//! normalized integer types the extension allows; sparse accessors are refused.

use crate::io::atomic::write_bytes_atomic;
use crate::{Error, Result};
use base64::Engine;
use glam::{Mat4, Quat, Vec3};
use gscodec_decoder::math::{normalize_quat, sh_rest_coeffs, sigmoid};
use gscodec_decoder::Splats;
use serde_json::{json, Value};
use std::path::{Component, Path};

/// The extension's name and attribute prefix.
pub const EXT: &str = "KHR_gaussian_splatting";
const GLB_MAGIC: u32 = 0x4654_6C67; // "glTF"
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;
const FLOAT: u64 = 5126;
const BYTE: u64 = 5120;
const UNSIGNED_BYTE: u64 = 5121;
const SHORT: u64 = 5122;
const UNSIGNED_SHORT: u64 = 5123;
/// Largest node depth followed (a guard against cyclic node graphs).
const MAX_DEPTH: usize = 64;
/// Largest number of node instances visited (a guard against node graphs that fan out).
const MAX_NODE_VISITS: usize = 1 << 16;

/// `(l, m)` of the 0-based non-DC SH coefficient `k` (`k = l² + l + m − 1`).
fn sh_lm(k: usize) -> (usize, i32) {
    let l = ((k + 1) as f64).sqrt().floor() as usize;
    (l, (k + 1) as i32 - (l * l + l) as i32)
}

/// The 180° turn about z between the `.ply` frame and glTF's, applied to a position.
fn flip_position(p: [f32; 3]) -> [f32; 3] {
    [-p[0], -p[1], p[2]]
}

/// The same turn applied to a `(w, x, y, z)` quaternion: `(0, 0, 0, 1) ⊗ q` (its own inverse up
/// to sign, so it maps both ways).
fn flip_rotation(q: [f32; 4]) -> [f32; 4] {
    let [w, x, y, z] = q;
    [-z, -y, x, w]
}

/// The same turn applied to SH coefficient `k`: `(−1)^m`.
fn flip_sh(k: usize, v: f32) -> f32 {
    if sh_lm(k).1 % 2 != 0 {
        -v
    } else {
        v
    }
}

/// glTF document and binary buffer for `splats` (one primitive, one node, no transform).
fn build(splats: &Splats) -> Result<(Value, Vec<u8>), String> {
    splats.validate().map_err(|e| e.to_string())?;
    let n = splats.len();
    if n == 0 {
        return Err("glTF accessors cannot be empty: the scene has no Gaussians".into());
    }
    let k = splats.rest_coeffs();
    let mut bin: Vec<u8> = Vec::new();
    let (mut views, mut accessors) = (Vec::new(), Vec::new());
    let mut attributes = serde_json::Map::new();
    let mut add = |name: String, ty: &str, values: Vec<f32>, extra: Value| {
        let offset = bin.len();
        values.iter().for_each(|v| bin.extend_from_slice(&v.to_le_bytes()));
        views.push(json!({ "buffer": 0, "byteOffset": offset, "byteLength": values.len() * 4, "target": 34962 }));
        let mut acc = json!({ "bufferView": views.len() - 1, "componentType": FLOAT, "count": n, "type": ty });
        if let (Value::Object(a), Value::Object(e)) = (&mut acc, extra) {
            a.extend(e);
        }
        attributes.insert(name, json!(accessors.len()));
        accessors.push(acc);
    };
    let pos: Vec<[f32; 3]> = splats.positions.iter().map(|&p| flip_position(p)).collect();
    let (lo, hi) = pos.iter().fold(([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]), |(lo, hi), p| {
        (std::array::from_fn(|a| lo[a].min(p[a])), std::array::from_fn(|a| hi[a].max(p[a])))
    });
    add("POSITION".into(), "VEC3", pos.concat(), json!({ "min": lo, "max": hi }));
    let rot = splats.rotations.iter().flat_map(|&q| {
        let [w, x, y, z] = flip_rotation(normalize_quat(q));
        [x, y, z, w]
    });
    add(format!("{EXT}:ROTATION"), "VEC4", rot.collect(), json!({}));
    add(format!("{EXT}:SCALE"), "VEC3", splats.log_scales.iter().flat_map(|s| s.map(f32::exp)).collect(), json!({}));
    add(format!("{EXT}:OPACITY"), "SCALAR", splats.opacity_logits.iter().map(|&o| sigmoid(o)).collect(), json!({}));
    add(format!("{EXT}:SH_DEGREE_0_COEF_0"), "VEC3", splats.sh_dc.concat(), json!({}));
    for kk in 0..k {
        let (l, m) = sh_lm(kk);
        let values = (0..n).flat_map(|i| (0..3).map(move |c| (i, c))).map(|(i, c)| flip_sh(kk, splats.sh_rest[(i * k + kk) * 3 + c]));
        add(format!("{EXT}:SH_DEGREE_{l}_COEF_{}", m + l as i32), "VEC3", values.collect(), json!({}));
    }
    let doc = json!({
        "asset": { "version": "2.0", "generator": format!("gscodec {}", env!("CARGO_PKG_VERSION")) },
        "extensionsUsed": [EXT],
        "scene": 0,
        "scenes": [{ "nodes": [0] }],
        "nodes": [{ "mesh": 0 }],
        "meshes": [{ "primitives": [{
            "mode": 0,
            "attributes": attributes,
            "extensions": { EXT: {
                "kernel": "ellipse",
                "colorSpace": "srgb_rec709_display",
                "projection": "perspective",
                "sortingMethod": "cameraDistance"
            } }
        }] }],
        "buffers": [{ "byteLength": bin.len() }],
        "bufferViews": views,
        "accessors": accessors,
    });
    Ok((doc, bin))
}

/// Encodes a scene as a `.glb` file.
pub fn encode_glb(splats: &Splats) -> Result<Vec<u8>, String> {
    let (doc, mut bin) = build(splats)?;
    let mut text = serde_json::to_vec(&doc).map_err(|e| e.to_string())?;
    text.resize(text.len().next_multiple_of(4), b' ');
    bin.resize(bin.len().next_multiple_of(4), 0);
    let total = 12 + 8 + text.len() + 8 + bin.len();
    let total = u32::try_from(total).map_err(|_| "scene too large for a GLB file (4 GiB)".to_string())?;
    let mut out = Vec::with_capacity(total as usize);
    for w in [GLB_MAGIC, 2, total, text.len() as u32, CHUNK_JSON] {
        out.extend_from_slice(&w.to_le_bytes());
    }
    out.extend_from_slice(&text);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(&CHUNK_BIN.to_le_bytes());
    out.extend_from_slice(&bin);
    Ok(out)
}

/// Encodes a scene as a self-contained `.gltf` (JSON, buffer as a base64 `data:` URI).
pub fn encode_gltf(splats: &Splats) -> Result<Vec<u8>, String> {
    let (mut doc, bin) = build(splats)?;
    let uri = format!("data:application/octet-stream;base64,{}", base64::engine::general_purpose::STANDARD.encode(&bin));
    doc["buffers"][0]["uri"] = json!(uri);
    serde_json::to_vec(&doc).map_err(|e| e.to_string())
}

fn is_glb(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("glb"))
}

/// Writes `.glb` or `.gltf` (by extension) atomically.
pub fn write_gltf(path: &Path, splats: &Splats) -> Result<()> {
    let bytes = if is_glb(path) { encode_glb(splats) } else { encode_gltf(splats) };
    write_bytes_atomic(path, &bytes.map_err(|m| Error::input(path, format!("cannot encode as glTF: {m}")))?)
}

/// Reads a `.glb` or `.gltf` scene (external buffers are looked up beside the file).
pub fn read_gltf(path: &Path) -> Result<Splats> {
    let bytes = std::fs::read(path).map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
    let dir = path.parent().unwrap_or(Path::new("."));
    decode_gltf(&bytes, Some(dir)).map_err(|m| Error::input(path, format!("not a valid glTF splat scene: {m}")))
}

/// Splits GLB bytes into its JSON text and BIN chunk.
fn split_glb(b: &[u8]) -> Result<(&[u8], Option<&[u8]>), String> {
    let u32_at = |at: usize| b.get(at..at + 4).map(|s| u32::from_le_bytes(s.try_into().unwrap()));
    let (version, total) = (u32_at(4).ok_or("truncated GLB header")?, u32_at(8).ok_or("truncated GLB header")? as usize);
    if version != 2 {
        return Err(format!("GLB version {version} (2 expected)"));
    }
    if total > b.len() {
        return Err(format!("truncated: the GLB header announces {total} bytes, the file has {}", b.len()));
    }
    let b = &b[..total];
    let mut at = 12;
    let (mut json, mut bin) = (None, None);
    while at < b.len() {
        let (len, ty) = (u32_at(at).ok_or("truncated GLB chunk header")? as usize, u32_at(at + 4).ok_or("truncated GLB chunk header")?);
        let data = b.get(at + 8..at + 8 + len).ok_or("truncated: a GLB chunk runs past the end of the file")?;
        match ty {
            CHUNK_JSON if json.is_none() => json = Some(data),
            CHUNK_BIN if bin.is_none() => bin = Some(data),
            _ => {}
        }
        at += 8 + len;
    }
    Ok((json.ok_or("GLB has no JSON chunk")?, bin))
}

/// Decodes glTF JSON or GLB bytes; `dir` resolves external buffer files (none when `None`).
pub fn decode_gltf(bytes: &[u8], dir: Option<&Path>) -> Result<Splats, String> {
    let (text, glb_bin) =
        if bytes.len() >= 4 && u32::from_le_bytes(bytes[..4].try_into().unwrap()) == GLB_MAGIC { split_glb(bytes)? } else { (bytes, None) };
    let doc: Value = serde_json::from_slice(text).map_err(|e| format!("JSON: {e}"))?;
    let version = doc["asset"]["version"].as_str().ok_or("no `asset.version`")?;
    if !version.starts_with("2.") {
        return Err(format!("glTF version {version} (2.x expected)"));
    }
    let buffers = load_buffers(&doc, glb_bin, dir)?;
    let mut parts = Vec::new();
    for (mesh, m) in splat_meshes(&doc)? {
        let prims = doc["meshes"][mesh]["primitives"].as_array().ok_or_else(|| format!("mesh {mesh} has no `primitives`"))?;
        for (p, prim) in prims.iter().enumerate() {
            if prim["extensions"].get(EXT).is_some() {
                parts.push(read_primitive(&doc, &buffers, prim, &m).map_err(|e| format!("mesh {mesh} primitive {p}: {e}"))?);
            }
        }
    }
    if parts.is_empty() {
        return Err(format!("no mesh primitive with the {EXT} extension"));
    }
    let degree = parts.iter().map(|s| s.sh_degree).min().unwrap();
    let mut out = Splats::new(degree);
    for s in parts {
        let s = s.with_sh_degree(degree);
        for i in 0..s.len() {
            out.push(s.positions[i], s.log_scales[i], s.rotations[i], s.opacity_logits[i], s.sh_dc[i], s.rest_of(i));
        }
    }
    out.validate().map_err(|e| format!("invalid scene: {e}"))?;
    Ok(out)
}

fn load_buffers(doc: &Value, glb_bin: Option<&[u8]>, dir: Option<&Path>) -> Result<Vec<Vec<u8>>, String> {
    let Some(list) = doc.get("buffers") else { return Ok(Vec::new()) };
    let list = list.as_array().ok_or("`buffers` is not an array")?;
    list.iter()
        .enumerate()
        .map(|(i, b)| {
            let len = b["byteLength"].as_u64().ok_or_else(|| format!("buffer {i} has no `byteLength`"))? as usize;
            let data = match b.get("uri").and_then(Value::as_str) {
                None if i == 0 => glb_bin.ok_or("buffer 0 has no `uri` and there is no GLB BIN chunk")?.to_vec(),
                None => return Err(format!("buffer {i} has no `uri`")),
                Some(uri) if uri.starts_with("data:") => {
                    let b64 = uri
                        .split_once(";base64,")
                        .map(|(_, d)| d)
                        .ok_or_else(|| format!("buffer {i}: only base64 data URIs are supported"))?;
                    base64::engine::general_purpose::STANDARD.decode(b64).map_err(|e| format!("buffer {i}: bad base64: {e}"))?
                }
                Some(uri) => {
                    let rel = Path::new(uri);
                    let dir = dir.ok_or_else(|| format!("buffer {i}: external file `{uri}` cannot be resolved"))?;
                    if uri.contains(':') || !rel.components().all(|c| matches!(c, Component::Normal(_))) {
                        return Err(format!("buffer {i}: `{uri}` is not a file beside the glTF"));
                    }
                    std::fs::read(dir.join(rel)).map_err(|e| format!("buffer {i} (`{uri}`): {e}"))?
                }
            };
            if data.len() < len {
                return Err(format!("truncated: buffer {i} holds {} bytes, `byteLength` says {len}", data.len()));
            }
            Ok(data)
        })
        .collect()
}

/// `(mesh index, node-to-world matrix)` of every mesh instance in the default scene; every mesh
/// with the identity when the document has no nodes.
fn splat_meshes(doc: &Value) -> Result<Vec<(usize, Mat4)>, String> {
    let nodes = doc["nodes"].as_array().map(Vec::as_slice).unwrap_or_default();
    if nodes.is_empty() {
        let count = doc["meshes"].as_array().map_or(0, Vec::len);
        return Ok((0..count).map(|m| (m, Mat4::IDENTITY)).collect());
    }
    let roots: Vec<usize> = match doc["scenes"].as_array() {
        Some(scenes) if !scenes.is_empty() => {
            let s = doc["scene"].as_u64().unwrap_or(0) as usize;
            let scene = scenes.get(s).ok_or_else(|| format!("`scene` {s} does not exist"))?;
            scene["nodes"].as_array().map(|a| a.iter().filter_map(Value::as_u64).map(|v| v as usize).collect()).unwrap_or_default()
        }
        _ => {
            let children: Vec<u64> =
                nodes.iter().flat_map(|n| n["children"].as_array().cloned().unwrap_or_default()).filter_map(|v| v.as_u64()).collect();
            (0..nodes.len()).filter(|i| !children.contains(&(*i as u64))).collect()
        }
    };
    let mut out = Vec::new();
    let mut stack: Vec<(usize, Mat4, usize)> = roots.into_iter().map(|r| (r, Mat4::IDENTITY, 0)).collect();
    let mut visits = 0;
    while let Some((i, parent, depth)) = stack.pop() {
        visits += 1;
        if visits > MAX_NODE_VISITS {
            return Err(format!("more than {MAX_NODE_VISITS} node instances"));
        }
        if depth > MAX_DEPTH {
            return Err("node hierarchy deeper than 64 levels (a cycle?)".into());
        }
        let node = nodes.get(i).ok_or_else(|| format!("node {i} does not exist"))?;
        let m = parent * local_matrix(node).map_err(|e| format!("node {i}: {e}"))?;
        if let Some(mesh) = node["mesh"].as_u64() {
            out.push((mesh as usize, m));
        }
        for c in node["children"].as_array().map(Vec::as_slice).unwrap_or_default() {
            stack.push((c.as_u64().ok_or_else(|| format!("node {i}: bad child index"))? as usize, m, depth + 1));
        }
    }
    Ok(out)
}

fn floats<const N: usize>(v: &Value) -> Option<[f32; N]> {
    let a = v.as_array()?;
    (a.len() == N).then_some(())?;
    let mut out = [0.0; N];
    for (o, x) in out.iter_mut().zip(a) {
        *o = x.as_f64()? as f32;
    }
    Some(out)
}

fn local_matrix(node: &Value) -> Result<Mat4, String> {
    if let Some(m) = node.get("matrix") {
        return floats::<16>(m).map(|a| Mat4::from_cols_array(&a)).ok_or_else(|| "bad `matrix`".into());
    }
    let t = node.get("translation").map_or(Some([0.0; 3]), floats::<3>).ok_or("bad `translation`")?;
    let r = node.get("rotation").map_or(Some([0.0, 0.0, 0.0, 1.0]), floats::<4>).ok_or("bad `rotation`")?;
    let s = node.get("scale").map_or(Some([1.0; 3]), floats::<3>).ok_or("bad `scale`")?;
    Ok(Mat4::from_scale_rotation_translation(Vec3::from(s), Quat::from_array(r), Vec3::from(t)))
}

/// Reads one accessor as `count × components` floats (normalized integers mapped to [−1, 1] or
/// [0, 1] per the glTF rules), checking its type and component type.
fn accessor(doc: &Value, buffers: &[Vec<u8>], idx: &Value, ty: &str, allowed: &[(u64, bool)]) -> Result<(usize, Vec<f32>), String> {
    let i = idx.as_u64().ok_or("attribute is not an accessor index")? as usize;
    let a = doc["accessors"].get(i).ok_or_else(|| format!("accessor {i} does not exist"))?;
    let bad = |m: String| format!("accessor {i}: {m}");
    if a["type"].as_str() != Some(ty) {
        return Err(bad(format!("type {} ({ty} expected)", a["type"])));
    }
    let comps = match ty {
        "SCALAR" => 1,
        "VEC3" => 3,
        _ => 4,
    };
    let ct = a["componentType"].as_u64().ok_or_else(|| bad("no `componentType`".into()))?;
    let normalized = a["normalized"].as_bool().unwrap_or(false);
    if !allowed.contains(&(ct, normalized)) {
        return Err(bad(format!("componentType {ct}{} is not allowed here", if normalized { " normalized" } else { "" })));
    }
    if a.get("sparse").is_some() {
        return Err(bad("sparse accessors are not supported".into()));
    }
    let count = a["count"].as_u64().ok_or_else(|| bad("no `count`".into()))? as usize;
    let size = match ct {
        BYTE | UNSIGNED_BYTE => 1,
        SHORT | UNSIGNED_SHORT => 2,
        _ => 4,
    };
    let Some(view) = a.get("bufferView") else {
        // No buffer view: all zeros (glTF 2.0 §3.6.2.3), but never more than the data can justify.
        return Ok((count, vec![0.0; count.checked_mul(comps).filter(|&v| v < 1 << 28).ok_or_else(|| bad("huge count".into()))?]));
    };
    let vi = view.as_u64().ok_or_else(|| bad("bad `bufferView`".into()))? as usize;
    let v = doc["bufferViews"].get(vi).ok_or_else(|| bad(format!("bufferView {vi} does not exist")))?;
    let buf =
        buffers.get(v["buffer"].as_u64().unwrap_or(u64::MAX) as usize).ok_or_else(|| bad(format!("bufferView {vi} names no buffer")))?;
    let (voff, vlen) =
        (v["byteOffset"].as_u64().unwrap_or(0) as usize, v["byteLength"].as_u64().ok_or_else(|| bad("no byteLength".into()))? as usize);
    let view = buf
        .get(voff..voff.checked_add(vlen).ok_or_else(|| bad("bufferView overflows".into()))?)
        .ok_or_else(|| bad(format!("bufferView {vi} lies outside its buffer")))?;
    let elem = size * comps;
    let stride = v["byteStride"].as_u64().map_or(elem, |s| s as usize);
    if stride < elem {
        return Err(bad(format!("byteStride {stride} is smaller than an element ({elem} bytes)")));
    }
    let off = a["byteOffset"].as_u64().unwrap_or(0) as usize;
    let need = if count == 0 {
        Some(0)
    } else {
        (count - 1).checked_mul(stride).and_then(|x| x.checked_add(off)).and_then(|x| x.checked_add(elem))
    }
    .ok_or_else(|| bad(format!("{count} elements overflow")))?;
    if need > view.len() {
        return Err(bad(format!("{count} elements need {need} bytes, bufferView {vi} has {}", view.len())));
    }
    let mut out = Vec::with_capacity(count * comps);
    for e in 0..count {
        let at = off + e * stride;
        for c in 0..comps {
            let b = &view[at + c * size..at + (c + 1) * size];
            out.push(match (ct, normalized) {
                (FLOAT, _) => f32::from_le_bytes(b.try_into().unwrap()),
                (BYTE, true) => (b[0] as i8 as f32 / 127.0).max(-1.0),
                (SHORT, true) => (i16::from_le_bytes(b.try_into().unwrap()) as f32 / 32767.0).max(-1.0),
                (UNSIGNED_BYTE, true) => b[0] as f32 / 255.0,
                (UNSIGNED_SHORT, true) => u16::from_le_bytes(b.try_into().unwrap()) as f32 / 65535.0,
                (UNSIGNED_BYTE, false) => b[0] as f32,
                (UNSIGNED_SHORT, false) => u16::from_le_bytes(b.try_into().unwrap()) as f32,
                _ => unreachable!("checked against `allowed`"),
            });
        }
    }
    Ok((count, out))
}

fn read_primitive(doc: &Value, buffers: &[Vec<u8>], prim: &Value, m: &Mat4) -> Result<Splats, String> {
    let ext = &prim["extensions"][EXT];
    if let Some(kernel) = ext.get("kernel") {
        if kernel.as_str() != Some("ellipse") {
            return Err(format!("kernel {kernel} is not supported (\"ellipse\" is)"));
        }
    }
    let mode = prim["mode"].as_u64().unwrap_or(4);
    if mode != 0 {
        return Err(format!("mode {mode}: splat primitives must be POINTS (0)"));
    }
    let attrs = &prim["attributes"];
    let get = |name: &str, ty: &str, allowed: &[(u64, bool)]| -> Result<(usize, Vec<f32>), String> {
        let idx = attrs.get(name).ok_or_else(|| format!("attribute `{name}` is missing"))?;
        accessor(doc, buffers, idx, ty, allowed).map_err(|e| format!("`{name}`: {e}"))
    };
    let f = [(FLOAT, false)];
    let (n, pos) = get("POSITION", "VEC3", &[(FLOAT, false), (BYTE, true), (SHORT, true), (UNSIGNED_BYTE, true), (UNSIGNED_SHORT, true)])?;
    let (n_rot, rot) = get(&format!("{EXT}:ROTATION"), "VEC4", &[(FLOAT, false), (BYTE, true), (SHORT, true)])?;
    let scale_types = [(FLOAT, false), (UNSIGNED_BYTE, false), (UNSIGNED_BYTE, true), (UNSIGNED_SHORT, false), (UNSIGNED_SHORT, true)];
    let (n_scale, scale) = get(&format!("{EXT}:SCALE"), "VEC3", &scale_types)?;
    let (n_op, opacity) = get(&format!("{EXT}:OPACITY"), "SCALAR", &[(FLOAT, false), (UNSIGNED_BYTE, true), (UNSIGNED_SHORT, true)])?;
    let (n_dc, dc) = get(&format!("{EXT}:SH_DEGREE_0_COEF_0"), "VEC3", &f)?;
    // Higher SH degrees: all coefficients of a degree or none, and no gaps.
    let mut degree = 0u8;
    let mut rest: Vec<Vec<f32>> = Vec::new();
    for l in 1..=4usize {
        let names: Vec<String> = (0..=2 * l).map(|c| format!("{EXT}:SH_DEGREE_{l}_COEF_{c}")).collect();
        let present = names.iter().filter(|nm| attrs.get(nm.as_str()).is_some()).count();
        if present == 0 {
            break;
        }
        if l == 4 {
            return Err("SH degree 4 is not supported (0 to 3 are)".into());
        }
        if present != names.len() {
            return Err(format!("SH degree {l} is partially defined ({present} of {} coefficients)", names.len()));
        }
        for nm in &names {
            let (c, v) = get(nm, "VEC3", &f)?;
            if c != n {
                return Err(format!("`{nm}` has {c} elements, POSITION has {n}"));
            }
            rest.push(v);
        }
        degree = l as u8;
    }
    for (name, c) in [("ROTATION", n_rot), ("SCALE", n_scale), ("OPACITY", n_op), ("SH_DEGREE_0_COEF_0", n_dc)] {
        if c != n {
            return Err(format!("`{EXT}:{name}` has {c} elements, POSITION has {n}"));
        }
    }
    // Node transform: translation and uniform positive scale only.
    let (s3, r, _) = m.to_scale_rotation_translation();
    let uniform = (s3.x - s3.y).abs() <= 1e-6 * s3.x.abs() && (s3.x - s3.z).abs() <= 1e-6 * s3.x.abs() && s3.x > 0.0;
    if !uniform || r.angle_between(Quat::IDENTITY) > 1e-6 || !m.is_finite() {
        return Err("node transforms with rotation, non-uniform or negative scale are not supported".into());
    }
    let ln_s = s3.x.ln();
    let k = sh_rest_coeffs(degree);
    let mut s = Splats::new(degree);
    let mut coeffs = vec![0.0f32; 3 * k];
    for i in 0..n {
        let p = m.transform_point3(Vec3::from_slice(&pos[3 * i..3 * i + 3])).to_array();
        let [x, y, z, w] = [rot[4 * i], rot[4 * i + 1], rot[4 * i + 2], rot[4 * i + 3]];
        let sc: [f32; 3] = std::array::from_fn(|a| scale[3 * i + a]);
        if sc.iter().any(|&v| !(v >= 0.0) || !v.is_finite()) {
            return Err(format!("Gaussian {i}: scale {sc:?} is negative or not finite"));
        }
        let o = opacity[i];
        if !(0.0..=1.0).contains(&o) {
            return Err(format!("Gaussian {i}: opacity {o} is outside [0, 1]"));
        }
        let o = o.clamp(1e-7, 1.0 - f32::EPSILON / 2.0);
        for (kk, c) in coeffs.chunks_exact_mut(3).enumerate() {
            for (ch, v) in c.iter_mut().enumerate() {
                *v = flip_sh(kk, rest[kk][3 * i + ch]);
            }
        }
        s.push(
            flip_position(p),
            sc.map(|v| v.max(1e-30).ln() + ln_s),
            flip_rotation([w, x, y, z]),
            (o / (1.0 - o)).ln(),
            [dc[3 * i], dc[3 * i + 1], dc[3 * i + 2]],
            &coeffs,
        );
    }
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Mat3;
    use gscodec_decoder::math::{quat_to_mat3, sh_color_unclamped};

    #[test]
    fn sh_index_maps_to_degree_and_order() {
        let lm: Vec<(usize, i32)> = (0..15).map(sh_lm).collect();
        assert_eq!(&lm[..3], &[(1, -1), (1, 0), (1, 1)]);
        assert_eq!(&lm[3..8], &[(2, -2), (2, -1), (2, 0), (2, 1), (2, 2)]);
        assert_eq!(lm[8], (3, -3));
        assert_eq!(lm[14], (3, 3));
    }

    /// The frame change is one rigid turn: positions, covariance axes and SH colour all follow it.
    #[test]
    fn frame_flip_is_a_rotation_of_positions_quaternions_and_sh() {
        let turn = Mat3::from_diagonal(Vec3::new(-1.0, -1.0, 1.0));
        let q = normalize_quat([0.3, -0.5, 0.7, 0.1]);
        let want = turn * quat_to_mat3(q);
        let got = quat_to_mat3(flip_rotation(q));
        assert!(want.abs_diff_eq(got, 1e-6), "{want} vs {got}");
        let rest: Vec<f32> = (0..45).map(|i| ((i * 37 % 11) as f32 - 5.0) / 7.0).collect();
        let flipped: Vec<f32> = (0..45).map(|j| flip_sh(j / 3, rest[j])).collect();
        for dir in [Vec3::new(0.3, -0.4, 0.866), Vec3::new(-0.9, 0.1, 0.42), Vec3::Z] {
            let dir = dir.normalize();
            let a = sh_color_unclamped(3, [0.1, 0.2, 0.3], &rest, dir);
            let b = sh_color_unclamped(3, [0.1, 0.2, 0.3], &flipped, turn * dir);
            for c in 0..3 {
                assert!((a[c] - b[c]).abs() < 1e-5, "{dir}: {a:?} vs {b:?}");
            }
        }
    }
}
