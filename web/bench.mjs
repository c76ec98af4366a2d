// Decode figures of the WASM package in headless Chromium, for docs/decoder.md:
//
//   node web/bench.mjs FILE.gsc [FILE.gsc …]     (after wasm/build.sh and `npm ci` in web/)
//
// Per file: the best of 5 `decode()` calls on the page's main thread, the viewer's decode in its
// worker, and a streamed load (the viewer's ?url=, 64 KiB pieces): when the first coarse scene
// arrived and with which SH degree. Chromium runs as in the test (software WebGL, no GPU).

import fs from 'node:fs';
import path from 'node:path';
import puppeteer from 'puppeteer-core';
import { serve } from './serve.mjs';
import { CHROMIUM, CHROMIUM_FLAGS } from './test/chromium.mjs';

const files = process.argv.slice(2);
if (files.length === 0) {
  console.error('usage: node web/bench.mjs FILE.gsc [FILE.gsc …]');
  process.exit(2);
}
const dir = path.dirname(path.resolve(files[0]));
const server = await serve({ mounts: { '/bench/': dir } });
const base = `http://127.0.0.1:${server.address().port}`;
const browser = await puppeteer.launch({ executablePath: CHROMIUM, headless: true, args: CHROMIUM_FLAGS });
try {
  for (const file of files) {
    if (path.dirname(path.resolve(file)) !== dir) throw new Error('give files from one folder');
    const url = `/bench/${path.basename(file)}`;
    const page = await browser.newPage();
    await page.goto(`${base}/web/?bare=1`);
    const main = await page.evaluate(async (u) => {
      const wasm = await import('/wasm/pkg/gscodec_wasm.js');
      await wasm.default();
      const bytes = new Uint8Array(await (await fetch(u)).arrayBuffer());
      let best = Infinity;
      let scene;
      for (let k = 0; k < 5; k++) {
        const t = performance.now();
        scene = wasm.decode(bytes);
        best = Math.min(best, performance.now() - t);
      }
      // Streaming in 64 KiB pieces: bytes received when the first coarse scene came out.
      const stream = new wasm.StreamDecoder();
      const coarse = [];
      for (let at = 0; at < bytes.length; at += 65536) {
        const s = stream.push(bytes.subarray(at, at + 65536));
        if (s) coarse.push(`SH ${s.shDegree} at ${Math.round((100 * stream.bytesReceived) / bytes.length)} %`);
      }
      stream.finish();
      return { bytes: bytes.length, count: scene.count, shDegree: scene.shDegree, best, coarse };
    }, url);
    const worker = await page.evaluate((u) => window.viewer.load(u), url);
    console.log(
      `${path.basename(file)}: ${main.count} Gaussians, SH ${main.shDegree}, ${main.bytes} B; decode ${main.best.toFixed(1)} ms ` +
        `(main thread, best of 5), ${worker.decodeMs.toFixed(1)} ms in the viewer's worker; coarse scenes: ${main.coarse.join(', ') || 'none'}`,
    );
    await page.close();
  }
} finally {
  await browser.close();
  server.close();
}
