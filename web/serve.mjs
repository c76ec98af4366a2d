// A static file server for the viewer: serves the repository root (so /web/ and /wasm/pkg/ are
// both reachable), plus optional extra folders under given URL prefixes. No dependencies.
//
//   node web/serve.mjs [PORT]      then open http://localhost:PORT/web/?url=/path/to/scene.gsc

import http from 'node:http';
import fs from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';

const TYPES = {
  '.html': 'text/html; charset=utf-8',
  '.js': 'text/javascript; charset=utf-8',
  '.mjs': 'text/javascript; charset=utf-8',
  '.json': 'application/json',
  '.wasm': 'application/wasm',
  '.png': 'image/png',
  '.css': 'text/css',
  '.ts': 'text/plain; charset=utf-8',
};

export const repoRoot = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '..');

/** Starts a server on 127.0.0.1 (port 0 = any free one); `mounts` maps URL prefixes to folders. */
export function serve({ port = 0, root = repoRoot, mounts = {} } = {}) {
  const server = http.createServer((req, res) => {
    const url = new URL(req.url, 'http://localhost');
    let pathname = decodeURIComponent(url.pathname);
    let base = root;
    for (const [prefix, dir] of Object.entries(mounts)) {
      if (pathname.startsWith(prefix)) {
        base = dir;
        pathname = pathname.slice(prefix.length - 1);
        break;
      }
    }
    let file = path.join(base, path.normalize(pathname));
    if (!file.startsWith(base)) return void res.writeHead(403).end();
    fs.stat(file, (err, st) => {
      if (!err && st.isDirectory()) file = path.join(file, 'index.html');
      fs.readFile(file, (err2, data) => {
        if (err2) return void res.writeHead(404, { 'content-type': 'text/plain' }).end('not found');
        res.writeHead(200, { 'content-type': TYPES[path.extname(file)] ?? 'application/octet-stream', 'content-length': data.length, 'cache-control': 'no-store' });
        res.end(data);
      });
    });
  });
  return new Promise((resolve) => server.listen(port, '127.0.0.1', () => resolve(server)));
}

if (process.argv[1] === fileURLToPath(import.meta.url)) {
  const server = await serve({ port: Number(process.argv[2] ?? process.env.PORT ?? 8080) });
  console.log(`serving ${repoRoot} at http://localhost:${server.address().port}/web/`);
}
