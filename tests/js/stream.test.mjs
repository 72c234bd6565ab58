// The viewer's streaming (viewer/stream.js) over an in-memory source with a delay: round trips to
// the first frame, reads inside the file and capped in flight, coarse before fine, the memory
// budget, and a long session that keeps converging to the selected front; for textured files
// (format 2.2), the image levels of selection.md §4: which level each image wants, the first
// textured frame's one read of the coarsest levels, and image levels within the budget.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import { existsSync, readFileSync } from 'node:fs';
import { Streamer, levelBytes, neededLevel, usedImages, wantedLevels } from '../../viewer/stream.js';
import { Camera } from '../../viewer/camera.js';
import { FormatError, IMAGE_MIME, crc32, decodeNode, decodeSkeleton, imageSize, planesOffset } from '../../viewer/format.js';
import { root, converted, cameraFrom } from './helpers.mjs';

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
    /** Round trips: reads started while none was in flight. */
    this.rounds = 0;
  }

  async read(start, end) {
    assert.ok(Number.isInteger(start) && start >= 0 && start < end && start < this.length, `read ${start}..${end} of ${this.length}`);
    this.requests++;
    if (this.inFlight === 0) this.rounds++;
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
  const a = (2 * Math.PI * k) / n;
  return cameraFrom(s, [Math.sin(a), 0.3 * Math.cos(3 * a), Math.cos(a)], distance);
}

// Format 3 (strata-v3.md): the same fixtures with compressed node geometry; format 4
// (strata-v4.md): the node table as a DAG.
const V3 = ['--format-version', '3'];
const DAG = ['--dag'];

test('opening takes two round trips and reads no more than the skeleton and the top level', async () => {
  for (const [name, mesh, args] of [['noisy_sphere', 'noisy_sphere.ply', []], ['icosphere', 'icosphere.obj', []], ['noisy_sphere_v3', 'noisy_sphere.ply', V3], ['icosphere_v3', 'icosphere.obj', V3],
    ['noisy_sphere_dag', 'noisy_sphere.ply', DAG]]) {
    const bytes = new Uint8Array(readFileSync(converted(name, `${root}/fixtures/${mesh}`, args)));
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

test('a format-3 file opens from its top pages: two round trips, a small share of the file, the rest of the skeleton after the first frame', async (t) => {
  const mesh = `${root}/../shared/meshes/large/cthead_skin_native.ply`;
  if (!existsSync(mesh)) {
    t.skip(`skipping: ${mesh} not found`);
    return;
  }
  const bytes = new Uint8Array(readFileSync(converted('cthead', mesh, [])));
  const src = new SlowSource(bytes);
  const st = await Streamer.open(src);
  const s = st.skeleton;
  const [t0, t1] = s.levelNodes(s.top());
  const top = s.offset[t1 - 1] + s.size[t1 - 1] - s.offset[t0];
  t.diagnostic(`cthead: ${src.rounds} round trips, ${src.requests} reads, ${src.bytes} bytes (top level ${top}, skeleton ${s.skeletonEnd}, file ${bytes.length})`);
  assert.equal(s.major, 3);
  assert.ok(src.rounds <= 2, `${src.rounds} round trips`);
  assert.ok(src.bytes <= 16384 + top + 64 && src.bytes < 0.02 * bytes.length, `${src.bytes} bytes before the first frame`);
  assert.ok(s.decoded < s.nodeCount && st.cache.size === t1 - t0);
  // The first update shows the top level and asks for the rest of SKEL; a later one decodes it.
  const camera = orbitCamera(s, 0, 8, 1);
  await settle(st, camera);
  assert.equal(s.decoded, s.nodeCount);
  assert.ok(st.front.some((i) => s.level[i] < s.top()), 'the front refines below the top level');
});

for (const [name, args, n] of [['noisy_sphere', [], 240], ['noisy_sphere_v3', V3, 80], ['noisy_sphere_dag', DAG, 80]]) test(`a long orbit under a small budget keeps converging, within the cap on reads in flight (${name})`, async (t) => {
  const bytes = new Uint8Array(readFileSync(converted(name, `${root}/fixtures/noisy_sphere.ply`, args)));
  const src = new SlowSource(bytes, 0);
  const budget = 1_500_000;
  const st = await Streamer.open(src, { budget, pixelError: 0.5, maxInFlight: 3 });
  let peakIdle = 0;
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

// Format 3 with sliceMs 0: every node of a range waits for its own task, frames drawn between them.
for (const [name, args, opts] of [['noisy_sphere', [], {}], ['noisy_sphere_v3', V3, { sliceMs: 0 }], ['noisy_sphere_dag', DAG, {}]]) test(`what is drawn while loading is resident and a front: coarser where data is missing, nothing drawn twice (${name})`, async () => {
  const bytes = new Uint8Array(readFileSync(converted(name, `${root}/fixtures/noisy_sphere.ply`, args)));
  const st = await Streamer.open(new SlowSource(bytes, 2), { pixelError: 0.5, ...opts });
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
      // No drawn node lies under another drawn node (format 4: under an output of a group above it).
      const set = new Set(drawn);
      for (const i of drawn) for (const a of above(s, i)) assert.ok(!set.has(a), `${i} and its ancestor ${a} both drawn`);
      if (st.idle()) break;
      await new Promise((r) => setTimeout(r, 1));
    }
    if (k === 0) assert.ok(frames > 1, 'refining took more than one frame');
  }
});

/** The nodes above node i: its ancestors, or in format 4 the outputs of its consumer and of theirs, up to the top. */
function above(s, i) {
  const out = [];
  if (!s.dag) {
    for (let a = s.parent[i]; a !== 0xffffffff; a = s.parent[a]) out.push(a);
    return out;
  }
  const d = s.dag, seen = new Set();
  for (const stack = [d.consumer[i]]; stack.length > 0; ) {
    const g = stack.pop();
    if (g === 0xffffffff || seen.has(g)) continue;
    seen.add(g);
    const [o0, o1] = d.outputsOf(g);
    for (let o = o0; o < o1; o++) {
      out.push(o);
      stack.push(d.consumer[o]);
    }
  }
  return out;
}

test('format 4 streams as a DAG: drawn fronts are cuts of it, no seams, nearest box first, an ORDR chunk refused', async (t) => {
  const bytes = new Uint8Array(readFileSync(converted('noisy_sphere_dag', `${root}/fixtures/noisy_sphere.ply`, DAG)));
  const st = await Streamer.open(new SlowSource(bytes, 1), { pixelError: 1 });
  const s = st.skeleton;
  assert.ok(s.dag);
  let mixed = 0;
  for (let k = 0; k < 12; k++) {
    const camera = orbitCamera(s, k, 12, 0.35 + 0.3 * (k % 3));
    await settle(st, camera);
    assert.deepEqual(st.drawn, st.front);
    assert.equal(st.seams, null);
    assert.equal(st.planes, 'none');
    // Nearest box first: drawing keys never decrease.
    const key = (i) => {
      const e = camera.eye.map(Math.fround);
      let d2 = 0;
      for (let c = 0; c < 3; c++) d2 += Math.max(s.boxMin[3 * i + c] - e[c], 0, e[c] - s.boxMax[3 * i + c]) ** 2;
      return d2;
    };
    for (let j = 1; j < st.drawOrder.length; j++) assert.ok(key(st.drawOrder[j - 1]) <= key(st.drawOrder[j]));
    assert.deepEqual([...st.drawOrder].sort((a, b) => a - b), st.drawn);
    if (new Set(st.drawn.map((i) => s.level[i])).size > 1) mixed++;
  }
  t.diagnostic(`12 cameras: ${mixed} fronts of several levels`);
  assert.ok(mixed > 0);
  st.close();
  // The same file with an ORDR chunk after its geometry: refused once the streamer looks there.
  const payload = new Uint8Array(4 * (s.nodeCount + 1));
  const ordr = new Uint8Array(24 + payload.length);
  ordr.set([0x4f, 0x52, 0x44, 0x52]);
  const dv = new DataView(ordr.buffer);
  dv.setUint32(4, 2, true);
  dv.setBigUint64(8, BigInt(payload.length), true);
  dv.setUint32(16 + payload.length, crc32(payload), true);
  const withPlanes = new Uint8Array(bytes.length + ordr.length);
  withPlanes.set(bytes);
  withPlanes.set(ordr, bytes.length);
  const head = new DataView(withPlanes.buffer);
  head.setBigUint64(32, BigInt(withPlanes.length), true);
  const headSize = Number(head.getBigUint64(24, true));
  head.setUint32(32 + headSize, crc32(withPlanes, 32, 32 + headSize), true);
  const bad = await Streamer.open(new SlowSource(withPlanes, 1), { pixelError: 1 });
  await assert.rejects(() => settle(bad, orbitCamera(s, 0, 12, 1)), (e) => e instanceof FormatError && /ORDR chunk in a format-4 file/.test(e.message));
  bad.close();
});

// ---------------------------------------------------------------------------------------------
// Image levels (selection.md §4).

const TEXTURED_VECTOR = `${root}/format-spec/vectors/textured.strata`;
const TEXTURED_VECTOR_V3 = `${root}/format-spec/vectors/textured-v3.strata`;
const globe = () => converted('textured_globe', `${root}/fixtures/textured_globe.glb`, []);
const globeV3 = () => converted('textured_globe_v3', `${root}/fixtures/textured_globe.glb`, V3);

function openWhole(path) {
  const bytes = new Uint8Array(readFileSync(path));
  const sk = decodeSkeleton(bytes, bytes.length);
  const geometry = (i) => decodeNode(sk, i, bytes.subarray(sk.offset[i], sk.offset[i] + sk.size[i]));
  return { bytes, sk, geometry };
}

/** A camera at `eye` looking at the origin, 100 pixels high: perspective with a 90° field of view, or orthographic `ortho` units high. */
function lookAtOrigin(eye, ortho) {
  const projection = ortho ? { orthographic: { height: ortho } } : { perspective: { fov_y: Math.PI / 2 } };
  return new Camera({ eye, target: [0, 0, 0], up: [0, 1, 0], projection, width: 100, height: 100, near: 0.01, far: 100 });
}

test('wanted image levels of the textured vector, computed by hand', () => {
  const { sk } = openWhole(TEXTURED_VECTOR);
  // Two nodes, spheres at (0, ±0.5, 0) of radius 1.1181640625, UV density 0.2610684335231781;
  // one image, level 0 128 × 64 (geometric mean 90.51 texels), level 1 64 × 32 (45.25).
  assert.equal(sk.nodeCount, 2);
  assert.deepEqual([...sk.textures.uvDensity], [0.2610684335231781, 0.2610684335231781]);
  assert.deepEqual(sk.textures.images[0].levels.map((e) => [sk.textures.levels[e].width, sk.textures.levels[e].height]), [[128, 64], [64, 32]]);
  // At (0, 0, D), tan(45°) = 1: s = 100 / (2 (sqrt(0.25 + D²) − r)) pixels per unit, t = s / d texels per UV unit.
  //   D = 3:   s = 100 / (2 · 1.92322) = 25.998, t = 99.58 > 45.25: level 0 (even 90.51 is short of it)
  //   D = 5.3: s = 100 / (2 · 4.20537) = 11.890, t = 45.54 > 45.25: level 0
  //   D = 5.4: s = 100 / (2 · 4.30493) = 11.615, t = 44.49 ≤ 45.25: level 1
  //   D = 10:  s = 100 / (2 · 8.89433) = 5.622,  t = 21.53: level 1
  // Orthographic 4 units high: s = 25, t = 95.76: level 0; 10 units high: s = 10, t = 38.30: level 1.
  const materialsOf = () => [0];
  for (const [eye, ortho, level] of [[[0, 0, 3], undefined, 0], [[0, 0, 5.3], undefined, 0], [[0, 0, 5.4], undefined, 1], [[0, 0, 10], undefined, 1], [[0, 0, 20], 4, 0], [[0, 0, 20], 10, 1]]) {
    const camera = lookAtOrigin(eye, ortho);
    assert.deepEqual([...wantedLevels(sk, [0, 1], materialsOf, camera)], [[0, level]], `eye ${eye}, ${ortho ? `orthographic ${ortho}` : 'perspective'}`);
    assert.deepEqual([...wantedLevels(sk, [1], materialsOf, camera)], [[0, level]]);
  }
  // The finest over the nodes: one near, one far (the camera on the y axis, node 0 nearer).
  const above = lookAtOrigin([0, 5.9, 0.001]);
  // Node 0: |eye − o| = 5.4, s = 100 / (2 · 4.28184) = 11.677, t = 44.73: level 1; node 1 (6.4 away): t = 36.26, level 1.
  assert.deepEqual([...wantedLevels(sk, [0, 1], materialsOf, above)], [[0, 1]]);
  const below = lookAtOrigin([0, 4.2, 0.001]);
  // Node 0: |eye − o| = 3.7, s = 19.366, t = 74.18: level 0; node 1 (4.7 away): s = 13.959, t = 53.47: level 0.
  assert.deepEqual([...wantedLevels(sk, [0, 1], materialsOf, below)], [[0, 0]]);
  assert.equal(neededLevel(sk, 0, 11.6146, 0.2610684335231781), 1);
  assert.equal(neededLevel(sk, 0, 11.8896, 0.2610684335231781), 0);
  // No geometry known yet, no mapped slot of the kinds asked, or a density of 0: nothing wanted.
  const camera = lookAtOrigin([0, 0, 3]);
  assert.equal(wantedLevels(sk, [0, 1], () => null, camera).size, 0);
  assert.equal(wantedLevels(sk, [0, 1], materialsOf, camera, ['normal', 'emissive']).size, 0);
  const flat = { ...sk, textures: { ...sk.textures, uvDensity: new Float32Array(2) } };
  assert.equal(wantedLevels(flat, [0, 1], materialsOf, camera).size, 0);
  assert.deepEqual(usedImages(sk), [0]);
  assert.deepEqual(usedImages(sk, ['normal']), []);
});

test('wanted image levels of the converted globe follow the rule over orbits near and far', () => {
  const { sk, geometry } = openWhole(globe());
  const t = sk.textures;
  assert.equal(t.images.length, 1);
  const ranges = Array.from({ length: sk.nodeCount }, (_, i) => geometry(i).materialRanges.map((r) => r[0]));
  // The rule written out again, node by node: s from the nearest point of the sphere, t = s / d,
  // the largest level whose sqrt(w · h) reaches t.
  const byHand = (nodes, cam) => {
    let best = Infinity;
    for (const i of nodes) {
      if (!(t.uvDensity[i] > 0) || !ranges[i].some((m) => sk.materials[m].maps.baseColor)) continue;
      const o = [0, 1, 2].map((k) => sk.center[3 * i + k]);
      const z = Math.max(Math.hypot(...o.map((v, k) => cam.eye[k] - v)) - sk.radius[i], 0);
      const s = cam.height / (2 * Math.tan(cam.projection.perspective.fov_y / 2) * Math.max(z, cam.near));
      const sides = t.images[0].levels.map((e) => Math.sqrt(t.levels[e].width * t.levels[e].height));
      let l = sides.length - 1;
      while (l > 0 && sides[l] < s / t.uvDensity[i]) l--;
      best = Math.min(best, sides[l] >= s / t.uvDensity[i] ? l : 0);
    }
    return best === Infinity ? [] : [[0, best]];
  };
  const seen = new Set();
  for (let k = 0; k < 48; k++) {
    const cam = orbitCamera(sk, k, 12, 0.25 + 16 * (k / 47) ** 2);
    // Each level's nodes as a front.
    for (let level = 0; level < sk.levels.length; level++) {
      const [n0, n1] = sk.levelNodes(level);
      const nodes = Array.from({ length: n1 - n0 }, (_, j) => n0 + j);
      const got = [...wantedLevels(sk, nodes, (i) => ranges[i], cam)];
      assert.deepEqual(got, byHand(nodes, cam), `camera ${k}, level ${level}`);
      for (const [, l] of got) seen.add(l);
    }
  }
  // The orbits reach every level of the image, from the full 512 × 256 to the coarsest 64 × 32.
  assert.deepEqual([...seen].sort(), [0, 1, 2, 3]);
});

/** Level entries of `sk` as [image, level] pairs. */
const entryOf = (sk, e) => [sk.textures.levels[e].image, sk.textures.levels[e].level];

/** The bytes of the coarsest levels of `images`, as one range over their TEXL chunks (padding between them). */
function coarsestBytes(sk, images) {
  const t = sk.textures;
  const entries = images.map((i) => t.images[i].levels.at(-1)).sort((a, b) => a - b);
  return entries.reduce((sum, e, k) => sum + (k === entries.length - 1 ? t.levels[e].size : Math.ceil(t.levels[e].size / 8) * 8), 0);
}

for (const [name, path] of [['the textured vector', () => TEXTURED_VECTOR], ['the converted globe', globe], ['the textured vector, format 3', () => TEXTURED_VECTOR_V3], ['the converted globe, format 3', globeV3]]) {
  test(`${name}: the first textured frame reads the coarsest levels in one range, then the wanted levels, within the budget`, async (t) => {
    const bytes = new Uint8Array(readFileSync(path()));
    const src = new SlowSource(bytes, 2);
    const live = new Map();
    const decoded = [];
    const st = await Streamer.open(src, {
      pixelError: 0.5,
      onImage: async (image, level, file, mime) => {
        await new Promise((r) => setTimeout(r, 1)); // the browser decodes asynchronously
        decoded.push({ image, level, file: file.slice(), mime });
        const handle = { image, level };
        live.set(handle, true);
        return handle;
      },
      onImageEvict: (image, level, handle) => {
        assert.ok(live.delete(handle), `image ${image} level ${level} released twice or never handed out`);
      },
    });
    const s = st.skeleton;
    const tex = s.textures;
    const used = usedImages(s, ['baseColor']);
    assert.ok(used.length > 0);
    const coarse = coarsestBytes(s, used);
    const opened = src.log.length;
    const camera = orbitCamera(s, 1, 8, 0.6);
    // Frames until one draws an image level.
    let first = null;
    for (let k = 0; k < 10000 && !first; k++) {
      st.update(camera);
      if (st.error) throw st.error;
      if (st.textureLevels().some(([, , l]) => l !== null)) first = { frame: k, textureBytesRead: st.textureBytesRead, reads: src.log.slice(opened) };
      else await new Promise((r) => setTimeout(r, 1));
    }
    assert.ok(first, 'no frame drew an image level');
    const texl = tex.levels.reduce((lo, l) => Math.min(lo, l.offset), Infinity);
    // Image reads start within the images; the separating planes (read once idle) follow them.
    const ordr = planesOffset(s);
    const isImageRead = ([a]) => a >= texl && a < ordr;
    const imageReads = first.reads.filter(isImageRead);
    t.diagnostic(`${name}: first textured frame after ${first.frame} updates: ${first.textureBytesRead} texture bytes read in ${imageReads.length} range(s); the coarsest levels of the ${used.length} image(s) used: ${coarse} bytes`);
    assert.ok(first.textureBytesRead <= coarse, `${first.textureBytesRead} texture bytes before the first textured frame, the coarsest levels are ${coarse}`);
    assert.equal(imageReads.length, 1, 'one range for the coarsest levels');
    assert.deepEqual(decoded.map((d) => [d.image, d.level]), used.map((i) => [i, tex.images[i].levels.length - 1]));
    // Then to rest: every image drawn at the level the rule wants, each level handed over as its
    // file (the codec's signature and the entry's size) with the right media type.
    await settle(st, camera);
    const materialsOf = (i) => st.geometry(i).materialRanges.map((r) => r[0]);
    const wanted = [...wantedLevels(s, st.drawn, materialsOf, camera, ['baseColor'])];
    assert.deepEqual(st.textureLevels(), wanted.map(([i, l]) => [i, l, l]));
    for (const d of decoded) {
      const lv = tex.levels[tex.images[d.image].levels[d.level]];
      assert.equal(d.mime, IMAGE_MIME[tex.images[d.image].codec]);
      assert.deepEqual(imageSize(tex.images[d.image].codec, d.file), [lv.width, lv.height]);
    }
    const held = [...st.levelCache.keys()];
    assert.equal(st.textureResidentBytes, held.reduce((sum, e) => sum + levelBytes(tex.levels[e]), 0));
    assert.equal(live.size, held.length);
    assert.equal(st.textureRequests, src.log.slice(opened).filter(isImageRead).length);
    t.diagnostic(`${name}: at rest ${JSON.stringify(st.textureLevels())} ([image, wanted, drawn]), held ${JSON.stringify(held.map((e) => entryOf(s, e)))}, ${st.textureBytesRead} texture bytes read in ${st.textureRequests} requests, ${st.textureResidentBytes} resident`);
    st.close();
    assert.equal(live.size, 0, 'close releases every image level');
  });
}

test('the converted globe under small budgets: image levels and geometry stay within it, coarser levels stand in', async (t) => {
  const bytes = new Uint8Array(readFileSync(globe()));
  const probe = await Streamer.open(new SlowSource(bytes, 0), { pixelError: 0.5 });
  const s = probe.skeleton;
  const tex = s.textures;
  const [e0, e1] = [0, 1].map((l) => tex.levels[tex.images[0].levels[l]]);
  // With room for the geometry and level 1 but not level 0, level 1 stands in near the globe
  // however long the view stays; with more, level 0 is read, and dropped again when the budget
  // shrinks under it. Orbits near and far stay within the budget at rest.
  const near = orbitCamera(s, 0, 12, 0.3);
  await settle(probe, near);
  const [top0, top1] = s.levelNodes(s.top());
  let geometry = probe.topBytes;
  for (const i of probe.front) if (i < top0 || i >= top1) geometry += probe.cache.get(i).bytes;
  const pinned = probe.pinnedBytes;
  assert.deepEqual(probe.textureLevels(), [[0, 0, 0]]);
  const runs = [];
  for (const budget of [geometry + pinned + levelBytes(e1) + 1000, geometry + pinned + levelBytes(e0) + levelBytes(e1) / 2]) {
    const live = new Set();
    const src = new SlowSource(bytes, 0);
    const st = await Streamer.open(src, {
      budget,
      pixelError: 0.5,
      onImage: (image, level) => {
        const h = { image, level };
        live.add(h);
        return h;
      },
      onImageEvict: (image, level, h) => live.delete(h),
    });
    await settle(st, near);
    const atNear = st.textureLevels();
    let over = 0, peak = 0, coarser = 0;
    const wants = [0, 0, 0, 0];
    for (let k = 0; k < 120; k++) {
      const cam = orbitCamera(s, k, 30, 0.3 + 8 * Math.sin(k / 9) ** 2);
      await settle(st, cam);
      if (st.residentBytes > budget) over++;
      peak = Math.max(peak, st.residentBytes);
      for (const [image, want, drawn] of st.textureLevels()) {
        assert.ok(drawn !== null && drawn >= want, `frame ${k}: image ${image} wants ${want}, drawn ${drawn}`);
        if (drawn > want) coarser++;
        wants[want]++;
      }
      assert.ok(st.levelCache.has(tex.images[0].levels.at(-1)), `frame ${k}: the coarsest level stays resident`);
      assert.equal(live.size, st.levelCache.size);
    }
    runs.push({ budget, atNear, over, peak, coarser, wants, reads: st.textureRequests, read: st.textureBytesRead });
    assert.equal(over, 0, `budget ${budget}: over it ${over} times at rest`);
    if (runs.length === 2) {
      await settle(st, near);
      assert.ok(st.levelCache.has(tex.images[0].levels[0]));
      st.budget = runs[0].budget;
      await settle(st, near);
      assert.deepEqual(st.textureLevels(), [[0, 0, 1]], 'level 1 drawn once level 0 no longer fits');
      assert.ok(!st.levelCache.has(tex.images[0].levels[0]), 'level 0 evicted');
      assert.ok(st.residentBytes <= st.budget && live.size === st.levelCache.size);
    }
    st.close();
    assert.equal(live.size, 0);
  }
  t.diagnostic(`globe: geometry near ${geometry}, coarsest level ${pinned}, level 1 ${levelBytes(e1)}, level 0 ${levelBytes(e0)} bytes; ${runs.map((r) => `budget ${r.budget}: near ${JSON.stringify(r.atNear)}, at rest at most ${r.peak}, wanted levels 0-3 in ${r.wants.join('/')} frames, ${r.coarser} of them drew a coarser one, ${r.reads} texture reads (${r.read} bytes)`).join('; ')}`);
  assert.deepEqual(runs[0].atNear, [[0, 0, 1]], 'level 1 stands in where level 0 does not fit');
  assert.deepEqual(runs[1].atNear, [[0, 0, 0]]);
});

test('an image level the renderer cannot take is left out: a coarser level stands in, and the session comes to rest', async () => {
  const bytes = new Uint8Array(readFileSync(globe()));
  // The browser fails to decode level 0: level 1 is what the budget leaves next, and is drawn.
  const st = await Streamer.open(new SlowSource(bytes, 0), {
    pixelError: 0.5,
    onImage: (image, level) => {
      if (level === 0) throw new Error('cannot decode');
      return { image, level };
    },
  });
  const tex = st.skeleton.textures;
  const near = orbitCamera(st.skeleton, 0, 12, 0.3);
  await settle(st, near);
  assert.deepEqual(st.textureLevels(), [[0, 0, 1]]);
  assert.deepEqual([...st.imageErrors.keys()], [tex.images[0].levels[0]]);
  assert.match([...st.imageErrors.values()][0], /^image 0 \(.+\) level 0: cannot decode$/);
});

test('opening with a short first read steps over sub-chunks larger than it in one read each', async () => {
  const bytes = new Uint8Array(readFileSync(converted('noisy_sphere_v3', `${root}/fixtures/noisy_sphere.ply`, V3)));
  const whole = await Streamer.open(new SlowSource(bytes, 0));
  const s = whole.skeleton;
  // SKEL's sub-chunks through the second page: each may cost a read for its frame, none more.
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const skel = bytes.findIndex((_, k) => String.fromCharCode(...bytes.subarray(k, k + 4)) === 'SKEL');
  let at = skel + 16, subs = 0, pages = 0;
  while (pages < 2) {
    const id = String.fromCharCode(...bytes.subarray(at, at + 4));
    pages += id === 'NODL';
    subs++;
    at += 16 + Number(dv.getBigUint64(at + 8, true)) + 4;
    at += (8 - (at % 8)) % 8;
  }
  const src = new SlowSource(bytes, 0);
  const st = await Streamer.open(src, { prefix: 256 });
  assert.ok(src.requests <= 2 + subs, `${src.requests} reads for ${subs} sub-chunks`);
  assert.deepEqual([...st.skeleton.offset.subarray(0, st.skeleton.decoded)], [...s.offset.subarray(0, s.decoded)]);
});
