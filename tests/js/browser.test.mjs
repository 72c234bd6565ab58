// The viewer in a real browser: headless Chromium (Debian's, WebGL2 in software by SwiftShader)
// driven by playwright-core, the page served by `strata serve`. Skips, saying what is missing,
// where Chromium or playwright-core is absent.

import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import { spawn, execFileSync } from 'node:child_process';
import { createServer } from 'node:http';
import { existsSync, readFileSync, writeFileSync, mkdirSync } from 'node:fs';
import { createRequire } from 'node:module';
import { extname } from 'node:path';
import { root, scratch, strataBin, converted, run } from './helpers.mjs';
import { crc32 } from '../../viewer/format.js';
import { Camera } from '../../viewer/camera.js';

const CHROMIUM = [process.env.CHROMIUM, '/usr/bin/chromium', '/usr/bin/chromium-browser', '/usr/bin/google-chrome'].find((p) => p && existsSync(p));
let playwright = null;
try {
  playwright = createRequire(import.meta.url)('playwright-core');
} catch {
  playwright = null;
}
const missing = !CHROMIUM
  ? 'skipping: Chromium not found (apt install chromium, or set CHROMIUM=/path/to/chrome)'
  : !playwright
    ? 'skipping: playwright-core not installed (npm ci --prefix tests/js)'
    : null;
const CT_HEAD = `${root}/../shared/meshes/large/cthead_skin_native.ply`;
const W = 480, H = 360;

let browser, server, base, dir;
const models = {};

function serve(folder) {
  return new Promise((resolve, reject) => {
    const child = spawn(strataBin(), ['serve', folder, '--port', '0'], { stdio: ['ignore', 'pipe', 'inherit'] });
    let out = '';
    child.stdout.on('data', (d) => {
      out += d;
      const m = /http:\/\/[^\s/]+/.exec(out);
      if (m) resolve({ child, base: m[0] });
    });
    child.on('exit', (code) => reject(new Error(`strata serve exited (${code}): ${out}`)));
  });
}

before(async () => {
  if (missing) return;
  dir = `${scratch()}/served`;
  mkdirSync(dir, { recursive: true });
  const copy = (name, file) => {
    writeFileSync(`${dir}/${name}.strata`, readFileSync(file));
    models[name] = `${dir}/${name}.strata`;
  };
  copy('sphere', converted('noisy_sphere', `${root}/fixtures/noisy_sphere.ply`, []));
  copy('ico', converted('icosphere', `${root}/fixtures/icosphere.obj`, ['--leaf-faces', '16', '--cluster-faces', '4', '--top-groups', '2']));
  if (existsSync(CT_HEAD)) copy('cthead', converted('cthead', CT_HEAD, []));
  // Far from the origin, as georeferenced scans are: the noisy sphere moved by (500 000, 4 000 000, 300).
  const ply = readFileSync(`${root}/fixtures/noisy_sphere.ply`);
  const far = `${scratch()}/far_sphere.obj`;
  if (!existsSync(far)) {
    const obj = run(strataBin(), ['extract', models.sphere, '--level', '0', '-o', `${scratch()}/sphere0.obj`]) && readFileSync(`${scratch()}/sphere0.obj`, 'utf8');
    writeFileSync(far, obj.replace(/^v (\S+) (\S+) (\S+)/gm, (_, x, y, z) => `v ${+x + 500000} ${+y + 4000000} ${+z + 300}`));
  }
  copy('far', converted('far_sphere', far, []));
  assert.ok(ply.length > 0);
  ({ child: server, base } = await serve(dir));
  browser = await playwright.chromium.launch({
    executablePath: CHROMIUM,
    headless: true,
    args: ['--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist', '--disable-background-networking',
      '--disable-component-update', '--disable-sync', '--no-first-run', '--disable-quic'],
  });
});

after(async () => {
  await browser?.close();
  server?.kill();
});

/** A page on `url` with every request it makes recorded. */
async function page(url) {
  const p = await browser.newPage({ viewport: { width: W, height: H }, deviceScaleFactor: 1 });
  const requests = [];
  p.on('request', (r) => requests.push({ url: r.url(), range: r.headers().range }));
  const errors = [];
  p.on('pageerror', (e) => errors.push(e.message));
  await p.goto(url);
  return { p, requests, errors };
}

const viewer = (name) => `${base}/viewer/?file=/${name}.strata`;
const timeout = (ms, what) => new Promise((_, reject) => setTimeout(() => reject(new Error(`${what}: no answer in ${ms} ms`)), ms));
const within = (promise, ms, what) => Promise.race([promise, timeout(ms, what)]);

/** The page's canvas against `strata render` of the same file and camera: coverage and shade. */
async function compareWithRender(p, file, camera, t) {
  const png = `${scratch()}/render-${Date.now()}.png`;
  const c = camera.toJSON();
  run(strataBin(), ['render', file, '-o', png, '--width', String(W), '--height', String(H), '--fov', String((c.projection.perspective.fov_y * 180) / Math.PI),
    '--camera', `${c.eye.join(',')}:${c.target.join(',')}`]);
  const reference = `data:image/png;base64,${readFileSync(png).toString('base64')}`;
  return p.evaluate(async (reference) => {
    const img = new Image();
    img.src = reference;
    await img.decode();
    const grab = (source) => {
      const c = document.createElement('canvas');
      c.width = source.width;
      c.height = source.height;
      const g = c.getContext('2d');
      g.drawImage(source, 0, 0);
      return g.getImageData(0, 0, c.width, c.height).data;
    };
    const a = grab(document.getElementById('view'));
    const b = grab(img);
    const bg = (d, i) => Math.abs(d[i] - 28) + Math.abs(d[i + 1] - 30) + Math.abs(d[i + 2] - 36) <= 3;
    let both = 0, either = 0, diff = 0, far = 0;
    for (let i = 0; i < a.length; i += 4) {
      const ia = !bg(a, i), ib = !bg(b, i);
      if (ia || ib) either++;
      if (ia && ib) {
        both++;
        const d = Math.max(Math.abs(a[i] - b[i]), Math.abs(a[i + 1] - b[i + 1]), Math.abs(a[i + 2] - b[i + 2]));
        diff += d;
        if (d > 24) far++;
      }
    }
    return { iou: both / Math.max(either, 1), meanDiff: diff / Math.max(both, 1), farShare: far / Math.max(both, 1), covered: both };
  }, reference);
}

test('the viewer in headless Chromium', { skip: missing ?? false, timeout: 600000 }, async (t) => {
  await t.test('opens in two round trips, reads only ranges inside the file, and draws what strata render draws', async (t) => {
    const { p, requests, errors } = await page(viewer('sphere'));
    await within(p.evaluate(() => window.strata.ready()), 60000, 'first frame');
    const s = await p.evaluate(() => window.strata.state());
    const length = readFileSync(models.sphere).length;
    t.diagnostic(`sphere: first frame ${s.firstFrameMs.toFixed(0)} ms after page load (open ${s.openMs.toFixed(0)} ms), ${s.firstFrameRequests} round trips, ${s.firstFrameBytes} bytes (skeleton ${s.skeletonEnd}, top level ends at ${s.topEnd}, file ${length})`);
    assert.ok(s.firstFrameRequests <= 2, `${s.firstFrameRequests} requests before the first frame`);
    assert.ok(s.firstFrameBytes <= Math.max(s.topEnd, Math.min(16384, length)), `${s.firstFrameBytes} bytes before the first frame`);
    // Refine to full detail at 0.5 px and compare with strata render of level 0.
    const h = JSON.parse(run(strataBin(), ['inspect', models.sphere, '--json'])).header;
    const center = h.min.map((m, k) => (m + h.max[k]) / 2);
    const radius = Math.hypot(...h.max.map((m, k) => m - h.min[k])) / 2;
    const cam = Camera.framing(center, radius, [0.3, 0.4, 1.0], (45 * Math.PI) / 180, W, H);
    const d = Math.hypot(...cam.eye.map((e, k) => e - center[k]));
    cam.near = Math.max(d - radius, 1e-4 * (d + radius));
    cam.far = d + radius;
    await p.evaluate(([c]) => {
      window.strata.setColor('plain');
      window.strata.setLimits({ pixelError: 0.5 });
      window.strata.setCamera(c);
    }, [cam.toJSON()]);
    await within(p.evaluate(() => window.strata.idle()), 120000, 'full detail');
    const full = await p.evaluate(() => window.strata.state());
    t.diagnostic(`sphere: to full detail at 0.5 px: ${full.requests} requests, ${full.bytesRead} bytes of ${length}; peak resident ${full.peakResidentBytes} bytes (budget ${full.budget})`);
    const m = await compareWithRender(p, models.sphere, cam, t);
    t.diagnostic(`sphere vs strata render: silhouette IoU ${m.iou.toFixed(4)}, mean shade difference ${m.meanDiff.toFixed(2)}/255, pixels differing by more than 24: ${(m.farShare * 100).toFixed(2)} % of ${m.covered}`);
    assert.ok(m.iou >= 0.98, `silhouette IoU ${m.iou}`);
    assert.ok(m.meanDiff <= 6, `mean shade difference ${m.meanDiff}`);
    assert.ok(m.farShare <= 0.02, `share of very different pixels ${m.farShare}`);
    for (const r of requests.filter((r) => r.url.includes('.strata'))) {
      const range = /^bytes=(\d+)-(\d+)$/.exec(r.range ?? '');
      assert.ok(range, `a request without a closed range: ${r.url} ${r.range}`);
      assert.ok(+range[1] <= +range[2] && +range[2] < length, `range ${r.range} outside the file of ${length} bytes`);
    }
    assert.deepEqual(errors, []);
    await p.close();
  });
});
