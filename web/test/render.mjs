// Renders scenes in headless Chromium with the reference renderer and writes
// the read-backs for the Rust test (tests/browser.rs) to compare.
//
//   node web/test/render.mjs SCENES.json OUTDIR
//
// SCENES.json: { "scenes": [{ name, file (absolute .svpk path), width, height,
// eye, target, up, fovy, near, light, ground }] }. Writes per scene
// OUTDIR/<name>.rgba (readPixels bytes, bottom-up), <name>.mult (Int8 per
// record: caps then buckets, per mesh), <name>.png, <name>-mask.png, and
// OUTDIR/results.json. Serves the repository root on 127.0.0.1 so the page
// loads web/*.js and format-spec/shaders/* exactly as a deployment would.
// Chromium: $SVPACK_CHROMIUM or /usr/bin/chromium (never downloaded).

import http from 'node:http';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

const [scenesPath, outDir] = process.argv.slice(2);
if (!scenesPath || !outDir) {
  console.error('usage: node web/test/render.mjs SCENES.json OUTDIR');
  process.exit(2);
}
const root = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '../..');
const { scenes } = JSON.parse(fs.readFileSync(scenesPath, 'utf8'));
fs.mkdirSync(outDir, { recursive: true });

const TYPES = { '.html': 'text/html', '.js': 'text/javascript', '.mjs': 'text/javascript', '.glsl': 'text/plain', '.vert': 'text/plain', '.svpk': 'application/octet-stream' };

// Static server: the repository root, plus /__scene/<i> for each scene's file.
const server = http.createServer((req, res) => {
  const url = new URL(req.url, 'http://localhost');
  let file;
  const m = url.pathname.match(/^\/__scene\/(\d+)$/);
  if (m && scenes[Number(m[1])]) {
    file = scenes[Number(m[1])].file;
  } else {
    file = path.join(root, decodeURIComponent(url.pathname));
    if (!file.startsWith(root + path.sep)) { res.writeHead(403).end(); return; }
  }
  fs.readFile(file, (err, data) => {
    if (err) { res.writeHead(404).end(String(err)); return; }
    res.writeHead(200, { 'content-type': TYPES[path.extname(file)] || 'application/octet-stream', 'cache-control': 'no-store' });
    res.end(data);
  });
});
await new Promise((resolve) => server.listen(0, '127.0.0.1', resolve));
const base = `http://127.0.0.1:${server.address().port}`;

const userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), 'svpack-chromium-'));
let context;
let failed = false;
try {
  context = await chromium.launchPersistentContext(userDataDir, {
    executablePath: process.env.SVPACK_CHROMIUM || '/usr/bin/chromium',
    headless: true,
    args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
      '--disable-background-networking', '--disable-component-update', '--disable-sync',
      '--use-angle=swiftshader', '--enable-unsafe-swiftshader'],
  });
  const page = await context.newPage();
  page.on('console', (msg) => console.error(`[page ${msg.type()}] ${msg.text()}`));
  page.on('pageerror', (err) => console.error(`[page error] ${err.message}`));
  await page.goto(`${base}/web/test/harness.html`);
  await page.waitForFunction(() => window.harnessReady === true, null, { timeout: 30000 });
  const results = [];
  for (const [i, scene] of scenes.entries()) {
    const t0 = Date.now();
    const r = await page.evaluate((s) => window.harness.run(s), { ...scene, url: `/__scene/${i}` });
    fs.writeFileSync(path.join(outDir, `${scene.name}.rgba`), Buffer.from(r.rgba, 'base64'));
    fs.writeFileSync(path.join(outDir, `${scene.name}.mult`), Buffer.from(r.mult, 'base64'));
    fs.writeFileSync(path.join(outDir, `${scene.name}.png`), Buffer.from(r.png.split(',')[1], 'base64'));
    fs.writeFileSync(path.join(outDir, `${scene.name}-mask.png`), Buffer.from(r.maskPng.split(',')[1], 'base64'));
    results.push({ name: scene.name, ms: Date.now() - t0, ...r.info });
  }
  fs.writeFileSync(path.join(outDir, 'results.json'), JSON.stringify({ scenes: results }, null, 2));
} catch (e) {
  console.error(`render.mjs: ${e.stack || e}`);
  failed = true;
} finally {
  await context?.close();
  server.close();
  fs.rmSync(userDataDir, { recursive: true, force: true });
}
process.exit(failed ? 1 : 0);
