// The viewer's streaming (viewer/stream.js) over an in-memory source with a delay: round trips to
// the first frame, reads inside the file and capped in flight, coarse before fine, the memory
// budget, and a long session that keeps converging to the selected front.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { Streamer } from '../../viewer/stream.js';
import { Camera } from '../../viewer/camera.js';
import { root, converted } from './helpers.mjs';

/** The bytes of a file served with a delay per read; records reads and the most in flight. */
class SlowSource {
  constructor(bytes, ms = 1) {
    this.bytesOf = bytes;
    this.name = 'memory';
    this.length = bytes.length;
    this.ms = ms;
    this.requests = 0;
    this.bytes = 0;
    this.log = [];
    this.inFlight = 0;
    this.maxInFlight = 0;
  }

  async read(start, end) {
    assert.ok(Number.isInteger(start) && start >= 0 && start < end && start < this.length, `read ${start}..${end} of ${this.length}`);
    this.requests++;
    this.inFlight++;
    this.maxInFlight = Math.max(this.maxInFlight, this.inFlight);
    await new Promise((r) => setTimeout(r, this.ms));
    this.inFlight--;
    const body = this.bytesOf.subarray(start, Math.min(end, this.length));
    this.bytes += body.length;
    this.log.push([start, end]);
    return body;
  }
}

async function settle(streamer, camera) {
  for (let k = 0; k < 10000; k++) {
    streamer.update(camera);
    if (streamer.error) throw streamer.error;
    if (streamer.idle()) return k;
    await new Promise((r) => setTimeout(r, 0));
  }
  throw new Error('the front never became resident');
}

function orbitCamera(s, k, n, distance) {
  const h = s.header;
  const center = h.min.map((m, i) => (m + h.max[i]) / 2);
  const radius = Math.hypot(...h.max.map((m, i) => m - h.min[i])) / 2;
  const a = (2 * Math.PI * k) / n;
  const cam = Camera.framing(center, radius, [Math.sin(a), 0.3 * Math.cos(3 * a), Math.cos(a)], 1.0, 640, 480);
  const dir = cam.eye.map((e, i) => e - center[i]);
  cam.eye = center.map((c, i) => c + dir[i] * distance);
  const d = Math.hypot(...dir) * distance;
  cam.near = Math.max(d - radius, d * 1e-3);
  cam.far = d + radius;
  return cam;
}

test('opening takes two round trips and reads no more than the skeleton and the top level', async () => {
  for (const [name, mesh] of [['noisy_sphere', 'noisy_sphere.ply'], ['icosphere', 'icosphere.obj']]) {
    const bytes = new Uint8Array(readFileSync(converted(name, `${root}/fixtures/${mesh}`, [])));
    const src = new SlowSource(bytes);
    const st = await Streamer.open(src);
    const s = st.skeleton;
    const [, t1] = s.levelNodes(s.top());
    const topEnd = Math.ceil((s.offset[t1 - 1] + s.size[t1 - 1]) / 8) * 8;
    assert.ok(src.requests <= 2, `${name}: ${src.requests} reads`);
    assert.ok(src.bytes <= Math.max(topEnd, Math.min(16384, bytes.length)), `${name}: ${src.bytes} bytes, top level ends at ${topEnd}`);
    assert.equal(st.cache.size, t1);
  }
});

test('a long orbit under a small budget keeps converging, within the cap on reads in flight', async (t) => {
  const bytes = new Uint8Array(readFileSync(converted('noisy_sphere', `${root}/fixtures/noisy_sphere.ply`, [])));
  const src = new SlowSource(bytes, 0);
  const budget = 1_500_000;
  const st = await Streamer.open(src, { budget, pixelError: 0.5, maxInFlight: 3 });
  let peakIdle = 0;
  const n = 240;
  for (let k = 0; k < n; k++) {
    const camera = orbitCamera(st.skeleton, k, 60, 0.4 + 0.6 * Math.abs(Math.sin(k / 17)));
    await settle(st, camera);
    assert.deepEqual(st.drawn, st.front, `frame ${k}: drawn = selected front once resident`);
    peakIdle = Math.max(peakIdle, st.residentBytes);
    assert.ok(st.residentBytes <= budget, `frame ${k}: ${st.residentBytes} resident over ${budget}`);
  }
  assert.ok(src.maxInFlight <= 3, `${src.maxInFlight} reads in flight`);
  t.diagnostic(`${n} cameras: ${src.requests} reads, ${src.bytes} bytes of ${bytes.length}; resident when idle at most ${peakIdle}, peak while loading ${st.peakResidentBytes} (budget ${budget})`);
});

test('what is drawn while loading is resident and a front: coarser where data is missing, nothing drawn twice', async () => {
  const bytes = new Uint8Array(readFileSync(converted('noisy_sphere', `${root}/fixtures/noisy_sphere.ply`, [])));
  const st = await Streamer.open(new SlowSource(bytes, 2), { pixelError: 0.5 });
  const s = st.skeleton;
  const near = orbitCamera(s, 0, 8, 0.35);
  const far = orbitCamera(s, 0, 8, 3);
  for (const [k, camera] of [near, far, near].entries()) {
    let frames = 0;
    for (;;) {
      const drawn = st.update(camera);
      frames++;
      if (st.error) throw st.error;
      for (const i of drawn) assert.ok(st.geometry(i), `node ${i} drawn without geometry`);
      // No drawn node lies under another drawn node.
      const set = new Set(drawn);
      for (const i of drawn) for (let a = s.parent[i]; a !== 0xffffffff; a = s.parent[a]) assert.ok(!set.has(a), `${i} and its ancestor ${a} both drawn`);
      if (st.idle()) break;
      await new Promise((r) => setTimeout(r, 1));
    }
    if (k === 0) assert.ok(frames > 1, 'refining took more than one frame');
  }
});
