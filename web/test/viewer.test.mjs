// The viewer in a real browser (Debian's chromium, headless, software WebGL2 through SwiftShader):
//
// 1. the WASM package decodes the bundled sample in the browser to exactly what the Rust decoder
//    writes (`gscodec decode` .ply), `info` agrees with `gscodec info --json`, the streaming
//    decoder gives the same scene, bad input throws classified errors;
// 2. the viewer's frames from fixed cameras match the CPU renderer's PNGs (`gscodec render`, same
//    intrinsics and poses): PSNR printed, >= 50 dB asserted.
//
// Needs wasm/pkg (`npm test` builds it first with wasm/build.sh), chromium (CHROMIUM, default
// /usr/bin/chromium) and the gscodec CLI (GSCODEC_BIN, default: `cargo build --bin gscodec`).
// Screenshots and reference images are left in web/test-output/.

import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import { execFileSync } from 'node:child_process';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import puppeteer from 'puppeteer-core';
import { serve, repoRoot } from '../serve.mjs';
import { readPng, psnr } from './png.mjs';
import { nerfCamera } from '../src/camera.js';
import { CHROMIUM, CHROMIUM_FLAGS } from './chromium.mjs';

const SIZE = 256; // the sample's 64×64 views, rendered at 4× for a meaningful image comparison
const FRAMES = [0, 5, 11];
// Measured 74–76 dB (the images differ by a few 8-bit roundings). The issue asks for >= 30 dB; the
// bar is higher because drawing only SH bands 0–1 of this sample already gives 41–44 dB.
const MIN_PSNR = 50;

const out = path.join(repoRoot, 'web', 'test-output');
let tmp, server, browser, page, base;
const pageErrors = [];

function gscodec(...args) {
  let bin = process.env.GSCODEC_BIN;
  if (!bin) {
    execFileSync('cargo', ['build', '--quiet', '--bin', 'gscodec'], { cwd: repoRoot, stdio: 'inherit' });
    bin = 'target/debug/gscodec';
  }
  return execFileSync(path.resolve(repoRoot, bin), args, { cwd: repoRoot, encoding: 'utf8' });
}

/** The float32 vertex records of an INRIA .ply written by `gscodec decode`. */
function readPly(file) {
  const buf = fs.readFileSync(file);
  const end = buf.indexOf('end_header\n') + 'end_header\n'.length;
  const header = buf.toString('latin1', 0, end);
  const count = Number(/element vertex (\d+)/.exec(header)[1]);
  const names = [...header.matchAll(/property float (\S+)/g)].map((m) => m[1]);
  const rows = [];
  for (let i = 0; i < count; i++) {
    const row = {};
    names.forEach((n, k) => (row[n] = buf.readFloatLE(end + (i * names.length + k) * 4)));
    rows.push(row);
  }
  return { rows, rest: names.filter((n) => n.startsWith('f_rest_')).length / 3 };
}

before(async () => {
  fs.mkdirSync(out, { recursive: true });
  tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'gscodec-web-'));
  // The bundled sample, coded, decoded and rendered by the CLI.
  gscodec('encode', 'samples/tiny/truth.ply', '-o', path.join(tmp, 'tiny.gsc'), '--quiet');
  gscodec('decode', path.join(tmp, 'tiny.gsc'), '-o', path.join(tmp, 'tiny.ply'), '--quiet');
  fs.writeFileSync(path.join(tmp, 'info.json'), gscodec('info', path.join(tmp, 'tiny.gsc'), '--json'));
  gscodec('render', path.join(tmp, 'tiny.gsc'), '--orbit', '1', '--size', `${SIZE}x${SIZE}`, '-o', path.join(tmp, 'orbit'), '--quiet');
  gscodec('render', path.join(tmp, 'tiny.gsc'), '--cameras', 'samples/tiny', '--split', 'all', '--size', `${SIZE}x${SIZE}`, '--background', '1,1,1', '-o', path.join(tmp, 'ref'), '--quiet');

  server = await serve({ mounts: { '/test-data/': tmp } });
  base = `http://127.0.0.1:${server.address().port}`;
  browser = await puppeteer.launch({ executablePath: CHROMIUM, headless: true, args: CHROMIUM_FLAGS });
  page = await browser.newPage();
  page.on('pageerror', (e) => pageErrors.push(e.message));
  page.on('console', (m) => m.type() === 'error' && pageErrors.push(m.text()));
  await page.setViewport({ width: 800, height: 600, deviceScaleFactor: 1 });
  await page.goto(`${base}/web/?url=/test-data/tiny.gsc&bg=1,1,1&bare=1`);
  const stats = await page.evaluate(() => window.viewer.loaded);
  console.log(`viewer: ${stats.count} Gaussians, SH ${stats.shDegree}, ${stats.fileBytes} B, decode ${stats.decodeMs.toFixed(2)} ms in the worker, ${stats.target} accumulation`);
});

after(async () => {
  await browser?.close();
  server?.close();
  if (tmp) fs.rmSync(tmp, { recursive: true, force: true });
});

test('decode in the browser equals the Rust decode', async () => {
  const got = await page.evaluate(async () => {
    const wasm = await import('/wasm/pkg/gscodec_wasm.js');
    await wasm.default();
    const bytes = new Uint8Array(await (await fetch('/test-data/tiny.gsc')).arrayBuffer());
    const plain = (s) => Object.fromEntries(Object.entries(s).map(([k, v]) => [k, ArrayBuffer.isView(v) ? Array.from(v) : v]));
    const ply = wasm.decode(bytes, { units: 'ply' });
    // The streaming decoder, fed in 1000-byte pieces, ends with the same scene.
    const stream = new wasm.StreamDecoder({ units: 'ply' });
    const coarse = [];
    for (let at = 0; at < bytes.length; at += 1000) {
      const s = stream.push(bytes.subarray(at, at + 1000));
      if (s) coarse.push(s.shDegree);
    }
    const streamed = stream.finish();
    const same = ['positions', 'scales', 'rotations', 'opacities', 'sh'].every((k) => streamed[k].every((v, i) => Object.is(v, ply[k][i])));
    const errors = [];
    for (const [what, f] of [
      ['truncated', () => wasm.decode(bytes.subarray(0, bytes.length - 1))],
      ['not a .gsc', () => wasm.decode(new TextEncoder().encode('ply\nformat binary_little_endian 1.0\n'))],
      ['bad option', () => wasm.decode(bytes, { maxShDegree: 4 })],
      ['finished stream', () => stream.push(bytes)],
    ]) {
      try {
        f();
        errors.push([what, 'no error']);
      } catch (e) {
        errors.push([what, e.name, e.kind, e.truncated]);
      }
    }
    const v = window.viewer.scene;
    return { ply: plain(ply), viewer: plain(v), info: wasm.info(bytes), streamSame: same, coarse, errors, version: wasm.version() };
  });

  // Exactly the values of `gscodec decode`'s .ply.
  const { rows, rest } = readPly(path.join(tmp, 'tiny.ply'));
  const n = rows.length;
  const coeffs = rest + 1;
  assert.equal(got.ply.count, n);
  assert.equal(got.ply.shDegree, Math.sqrt(coeffs) - 1);
  for (let i = 0; i < n; i++) {
    const r = rows[i];
    const want = {
      positions: [r.x, r.y, r.z],
      scales: [r.scale_0, r.scale_1, r.scale_2],
      rotations: [r.rot_0, r.rot_1, r.rot_2, r.rot_3],
      opacities: [r.opacity],
      sh: [r.f_dc_0, r.f_dc_1, r.f_dc_2],
    };
    for (let k = 0; k < rest; k++) for (let c = 0; c < 3; c++) want.sh.push(r[`f_rest_${c * rest + k}`]);
    for (const [key, vals] of Object.entries(want)) {
      vals.forEach((w, j) => assert.ok(Object.is(got.ply[key][i * vals.length + j], w), `${key} of Gaussian ${i}[${j}]: ${got.ply[key][i * vals.length + j]} != ${w}`));
    }
    // The viewer's scene (decoded in its worker, linear units) is the same scene.
    const v = got.viewer;
    const close = (a, b, what) => assert.ok(Math.abs(a - b) <= 1e-6 * Math.max(1, Math.abs(b)), `${what} of Gaussian ${i}: ${a} vs ${b}`);
    want.positions.forEach((w, j) => assert.equal(v.positions[i * 3 + j], w));
    want.scales.forEach((w, j) => close(v.scales[i * 3 + j], Math.exp(w), 'scale'));
    close(v.opacities[i], 1 / (1 + Math.exp(-r.opacity)), 'opacity');
    const q = want.rotations;
    const qn = Math.hypot(...q);
    [q[1], q[2], q[3], q[0]].forEach((w, j) => close(v.rotations[i * 4 + j], w / qn, 'rotation (x, y, z, w)'));
    want.sh.forEach((w, j) => assert.equal(v.sh[i * coeffs * 3 + j], w));
  }

  // info() agrees with `gscodec info --json`.
  const cli = JSON.parse(fs.readFileSync(path.join(tmp, 'info.json'), 'utf8'));
  assert.equal(got.info.count, cli.gaussians);
  assert.equal(got.info.fileBytes, cli.bytes);
  assert.deepEqual(got.info.sections, cli.sections);
  assert.deepEqual(got.info.contextChannels, cli.context_channels);
  assert.equal(got.info.inputGaussians, cli.left_out.input_gaussians);

  assert.ok(got.streamSame, 'the streamed scene differs from decode()');
  assert.ok(got.coarse.every((d, i) => d < 3 && (i === 0 || d > got.coarse[i - 1])), `coarse scenes ${got.coarse}`);
  assert.deepEqual(got.errors, [
    ['truncated', 'GscodecError', 'format', true],
    ['not a .gsc', 'GscodecError', 'format', false],
    ['bad option', 'GscodecError', 'argument', false],
    ['finished stream', 'GscodecError', 'argument', false],
  ]);
  console.log(`browser decode (gscodec-wasm ${got.version}) equals gscodec decode: ${n} Gaussians, ${coeffs} SH coefficients each`);
});

test('the file picker loads a scene', async () => {
  const input = await page.$('#file');
  const loaded = page.evaluate(() => new Promise((resolve) => {
    const wait = () => (window.viewer.stats?.name === 'tiny.gsc' ? window.viewer.loaded.then(resolve) : setTimeout(wait, 20));
    wait();
  }));
  await input.uploadFile(path.join(tmp, 'tiny.gsc'));
  const stats = await loaded;
  assert.equal(stats.name, 'tiny.gsc');
  // As many Gaussians as `gscodec info` says the file holds (the encoder prunes some).
  const cli = JSON.parse(fs.readFileSync(path.join(tmp, 'info.json'), 'utf8'));
  assert.ok(cli.gaussians > 0);
  assert.equal(stats.count, cli.gaussians);
  assert.equal(stats.final, true);
});

/** PSNR of a screenshot against a CPU render; both kept in web/test-output/ as NAME-browser/cpu.png. */
function compare(shot, reference, name) {
  fs.writeFileSync(path.join(out, `${name}-browser.png`), shot);
  fs.copyFileSync(reference, path.join(out, `${name}-cpu.png`));
  const a = readPng(shot);
  const b = readPng(fs.readFileSync(reference));
  assert.deepEqual([a.width, a.height], [b.width, b.height]);
  return psnr(a.rgb, b.rgb);
}

test('viewer frames match the CPU renderer', async () => {
  const transforms = JSON.parse(fs.readFileSync(path.join(repoRoot, 'samples/tiny/transforms_train.json'), 'utf8'));
  // The dataset loader's near plane: 0.05 × the median distance of the camera centres to their mean.
  const centres = transforms.frames.map((f) => f.transform_matrix.slice(0, 3).map((row) => row[3]));
  const mean = [0, 1, 2].map((k) => centres.reduce((s, c) => s + c[k], 0) / centres.length);
  const dist = centres.map((c) => Math.hypot(c[0] - mean[0], c[1] - mean[1], c[2] - mean[2])).sort((a, b) => a - b);
  const znear = 0.05 * dist[dist.length >> 1];
  const canvas = await page.$('#view');
  for (const f of FRAMES) {
    const cam = nerfCamera(transforms.frames[f].transform_matrix, transforms.camera_angle_x, [64, 64], SIZE, SIZE, znear);
    await page.evaluate((c) => window.viewer.setCamera(c), cam);
    const shot = Buffer.from(await canvas.screenshot({ type: 'png' }));
    const name = String(f).padStart(3, '0');
    const db = compare(shot, path.join(tmp, 'ref', `${name}.png`), `frame-${name}`);
    console.log(`frame ${f}: PSNR(browser WebGL2, CPU renderer) = ${db.toFixed(2)} dB at ${SIZE}×${SIZE}`);
    assert.ok(db >= MIN_PSNR, `frame ${f}: ${db.toFixed(2)} dB < ${MIN_PSNR} dB`);
  }
  assert.deepEqual(pageErrors, []);
});

test("the viewer's first view is the CLI's orbit view 0", async () => {
  // A page of the render's size: the canvas fills it, the orbit frames the scene as `--orbit` does.
  const orbitPage = await browser.newPage();
  orbitPage.on('pageerror', (e) => pageErrors.push(e.message));
  await orbitPage.setViewport({ width: SIZE, height: SIZE, deviceScaleFactor: 1 });
  await orbitPage.goto(`${base}/web/?url=/test-data/tiny.gsc&bare=1`);
  await orbitPage.evaluate(async () => {
    await window.viewer.loaded;
    await window.viewer.drawn();
  });
  const shot = Buffer.from(await (await orbitPage.$('#view')).screenshot({ type: 'png' }));
  const db = compare(shot, path.join(tmp, 'orbit', '000.png'), 'orbit-000');
  console.log(`orbit view 0: PSNR(browser WebGL2, gscodec render --orbit) = ${db.toFixed(2)} dB at ${SIZE}×${SIZE}`);
  assert.ok(db >= MIN_PSNR, `${db.toFixed(2)} dB < ${MIN_PSNR} dB`);
  await orbitPage.close();
  assert.deepEqual(pageErrors, []);
});
