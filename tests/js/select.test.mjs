// The viewer's front selection (viewer/select.js) against the rule's golden fronts
// (format-spec/vectors/fronts.json) and against strata's Streamer (`strata stream --print-front`)
// on converted fixtures and, when present, the 568k-face CT head of ../shared/meshes/large.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync, existsSync } from 'node:fs';
import { decodeSkeleton, decodePlanes, planesOffset } from '../../viewer/format.js';
import { Orderer } from '../../viewer/order.js';
import { Camera } from '../../viewer/camera.js';
import { Selector } from '../../viewer/select.js';
import { root, strataBin, converted, run } from './helpers.mjs';

const vectors = `${root}/format-spec/vectors`;

function skeletonOf(path) {
  const bytes = new Uint8Array(readFileSync(path));
  return decodeSkeleton(bytes, bytes.length);
}

/** The drawing orderer of the file at `path` (its skeleton `s`), from its ORDR chunk. */
function ordererOf(path, s) {
  const bytes = new Uint8Array(readFileSync(path));
  return new Orderer(s, decodePlanes(s, bytes.subarray(planesOffset(s))));
}

test('every golden front of fronts.json', () => {
  const fronts = JSON.parse(readFileSync(`${vectors}/fronts.json`, 'utf8'));
  assert.ok(fronts.length >= 10);
  const skeletons = new Map(), orderers = new Map();
  for (const [k, f] of fronts.entries()) {
    if (!skeletons.has(f.file)) {
      skeletons.set(f.file, skeletonOf(`${vectors}/${f.file}`));
      orderers.set(f.file, ordererOf(`${vectors}/${f.file}`, skeletons.get(f.file)));
    }
    const s = skeletons.get(f.file);
    const l = f.limits;
    const limits = { pixelError: l.pixel_error, maxFaces: l.max_faces ?? undefined, maxBytes: l.max_bytes ?? undefined, priority: l.priority };
    const cut = new Selector(s).select(new Camera(f.camera), limits, new Set(f.held));
    assert.deepEqual(cut.shown, f.front, `front ${k}`);
    assert.deepEqual(cut.culled, f.culled, `culled roots ${k}`);
    assert.deepEqual(orderers.get(f.file).order(cut.shown, new Camera(f.camera)), f.order, `drawing order ${k}`);
  }
});

/** Play `strata stream --print-front` on `file` and select the same fronts in JavaScript, frame by frame. */
function agreesWithStreamer(t, file, args, limits) {
  const out = run(strataBin(), ['stream', file, '--json', '--print-front', ...args]);
  const frames = out.trim().split('\n').map((l) => JSON.parse(l));
  const s = skeletonOf(file);
  const selector = new Selector(s);
  const orderer = ordererOf(file, s);
  // A first frame of the top level alone is drawn before the planes are read, nearest box first
  // (selection.md §6), by the Streamer as by the viewer.
  const unread = new Orderer(s, { starts: [], entries: [] });
  const [topStart, topEnd] = s.levelNodes(s.top());
  // strata stream's first frame shows the top level, as if H held it (selection.md §6): the rest
  // of the node table is decoded for the second.
  const top = new Set(Array.from({ length: topEnd - topStart }, (_, k) => topStart + k));
  let nodes = 0;
  for (const f of frames) {
    const cut = selector.select(new Camera(f.camera), limits, f.frame === 0 ? top : new Set());
    assert.deepEqual(cut.shown, f.front, `${file} frame ${f.frame}: front`);
    const early = f.frame === 0 && cut.shown.every((i) => i >= topStart && i < topEnd);
    assert.deepEqual((early ? unread : orderer).order(cut.shown, new Camera(f.camera)), f.order, `${file} frame ${f.frame}: drawing order`);
    assert.deepEqual(cut.culled, f.culled_roots, `${file} frame ${f.frame}: culled roots`);
    assert.equal(cut.faces, f.faces);
    nodes += cut.shown.length;
  }
  t.diagnostic(`${frames.length} fronts and drawing orders equal (${nodes} displayed nodes in all), ${args.join(' ')}`);
  return frames;
}

test('the fronts of strata stream on a converted fixture', (t) => {
  const file = converted('icosphere', `${root}/fixtures/icosphere.obj`, ['--leaf-faces', '16', '--cluster-faces', '4', '--top-groups', '2']);
  const frames = agreesWithStreamer(t, file, ['--orbit', '24'], { pixelError: 1, priority: 'error' });
  assert.equal(frames.length, 24);
  const levels = new Set(frames.flatMap((f) => f.levels.flatMap((n, l) => (n > 0 ? [l] : []))));
  assert.ok(levels.size >= 2, `the orbit shows several levels: ${[...levels]}`);
  agreesWithStreamer(t, file, ['--orbit', '20', '--pixel-error', '0.25', '--budget-faces', '1200'], { pixelError: 0.25, maxFaces: 1200, priority: 'error' });
  agreesWithStreamer(t, file, ['--orbit', '20', '--pixel-error', '0.25', '--budget-bytes', '60000', '--priority', 'silhouette'], {
    pixelError: 0.25, maxBytes: 60000, priority: 'silhouette',
  });
});

test('the fronts of strata stream on the 568k-face CT head', (t) => {
  const mesh = `${root}/../shared/meshes/large/cthead_skin_native.ply`;
  if (!existsSync(mesh)) {
    t.skip(`skipping: ${mesh} not found`);
    return;
  }
  const file = converted('cthead', mesh, []);
  agreesWithStreamer(t, file, ['--orbit', '24'], { pixelError: 1, priority: 'error' });
  agreesWithStreamer(t, file, ['--orbit', '20', '--pixel-error', '2', '--budget-faces', '150000'], { pixelError: 2, maxFaces: 150000, priority: 'error' });
});
