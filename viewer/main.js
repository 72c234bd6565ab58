// The viewer page: opens a chunk file (?file=URL, a dropped or chosen file), streams it with
// stream.js, draws with render.js, and gives orbit, pan, zoom, fit, picking and measuring. Tests
// drive it through `window.strata` (bottom of this file). Nodes below the top level are decoded in
// Workers (decoder.js): `?workers=N` sets how many, 0 decodes on the main thread.

import { Camera, add, cross, dot, length, scale, sub, unit } from './camera.js';
import { Selector } from './select.js';
import { FileSource, HttpSource } from './source.js';
import { Streamer } from './stream.js';
import { DecoderPool } from './decoder.js';
import { Renderer } from './render.js';

const $ = (id) => document.getElementById(id);
const canvas = $('view');
const VIEW_DIR = [0.3, 0.4, 1.0];
/** Terrain (a file with GEOR, y up) is seen from the south, 50° above the horizon, as `strata render` does. */
const TERRAIN_VIEW_DIR = [0, 1, 0.8];
const FOV = (45 * Math.PI) / 180;

let renderer = null;
let streamer = null;
let camera = null;
/** Near and far follow the model unless a caller set the camera exactly. */
let autoClip = true;
let colorMode = 'material';
let dirty = true;
let frameMs = 0;
/** Time from the page's start (first model) or from the open (later ones) to the first frame. */
let firstFrameMs = null;
let openStart = 0;
let opens = 0;
let firstFrameRequests = null;
let firstFrameBytes = null;
/** The first frame drawn with an image level: time from the open, bytes read, texture bytes read. */
let firstTextured = null;
let picks = [];
let measuring = false;
/** The last click in measure mode (time and place), to tell a double-click from two clicks. */
let lastClick = null;
let opened = null;
let idleWaiters = [];
/** The uploaded seams between levels and the streamer's count of their changes they are from. */
let seamHandle = null;
let seamsVersion = 0;
let drawSeams = true;

function fmtBytes(n) {
  if (n < 1024) return `${n} B`;
  if (n < 1024 ** 2) return `${(n / 1024).toFixed(1)} KB`;
  if (n < 1024 ** 3) return `${(n / 1024 ** 2).toFixed(1)} MB`;
  return `${(n / 1024 ** 3).toFixed(2)} GB`;
}

function showMessage(text) {
  const m = $('message');
  m.textContent = text;
  m.hidden = !text;
}

function showWarning(text) {
  const w = $('warning');
  w.textContent = text ?? '';
  w.hidden = !text;
}

function fail(e) {
  console.error(e);
  showMessage(e instanceof Error ? e.message : String(e));
  for (const w of idleWaiters) w.reject(e);
  idleWaiters = [];
}

function modelSphere() {
  const h = streamer.skeleton.header;
  const center = h.min.map((m, k) => (m + h.max[k]) / 2);
  return { center, radius: Math.max(length(sub(h.max, h.min)) / 2, Number.MIN_VALUE) };
}

function resize() {
  const dpr = window.devicePixelRatio || 1;
  const w = Math.max(1, Math.round(canvas.clientWidth * dpr));
  const h = Math.max(1, Math.round(canvas.clientHeight * dpr));
  if (canvas.width !== w || canvas.height !== h) {
    canvas.width = w;
    canvas.height = h;
  }
  if (camera) {
    camera.width = w;
    camera.height = h;
  }
  dirty = true;
}

function fit() {
  const { center, radius } = modelSphere();
  const dir = streamer.skeleton.georef ? TERRAIN_VIEW_DIR : VIEW_DIR;
  camera = Camera.framing(center, radius, dir, FOV, canvas.width, canvas.height);
  autoClip = true;
  dirty = true;
}

function clip() {
  if (!autoClip) return;
  const { center, radius } = modelSphere();
  const d = length(sub(camera.eye, center));
  camera.far = d + radius;
  camera.near = Math.max(d - radius, 1e-4 * (d + radius));
}

function frame() {
  requestAnimationFrame(frame);
  if (!streamer) return;
  if (streamer.error) {
    if (!$('message').textContent) fail(streamer.error);
    return;
  }
  if (!dirty) return;
  dirty = false;
  const t0 = performance.now();
  const before = { requests: streamer.source.requests, bytes: streamer.source.bytes };
  clip();
  streamer.update(camera);
  const s = streamer.skeleton;
  const images = (image) => streamer.imageHandle(image);
  // Front to back, so that the depth test rejects what lies behind before it is shaded.
  const drawn = streamer.drawOrder.map((id) => ({ id, handle: streamer.handle(id), level: s.level[id] }));
  // The seams between levels, last: they fill slivers behind nothing.
  if (seamsVersion !== streamer.seamsVersion) {
    renderer.release(seamHandle);
    const f = streamer.seams;
    seamHandle = f && f.faces > 0 ? renderer.upload({ local: f.local, normals: f.normals, indices: f.indices, materialRanges: [[0, 0, f.indices.length]] }) : null;
    seamsVersion = streamer.seamsVersion;
  }
  if (seamHandle && drawSeams) drawn.push({ id: -1, handle: seamHandle, level: 0, seam: true });
  renderer.draw(camera, streamer.localOrigin, drawn, colorMode, s.materials, images);
  frameMs = performance.now() - t0;
  if (firstTextured === null && streamer.textureLevels().some(([, , level]) => level !== null)) {
    const { textureBytesRead, textureRequests } = streamer;
    firstTextured = { ms: performance.now() - openStart, bytesRead: streamer.source.bytes, textureBytesRead, textureRequests };
  }
  if (firstFrameMs === null) {
    firstFrameMs = performance.now() - openStart;
    firstFrameRequests = before.requests;
    firstFrameBytes = before.bytes;
  }
  stats();
  if (streamer.idle()) {
    for (const w of idleWaiters) w.resolve();
    idleWaiters = [];
  }
}

function stats() {
  const s = streamer.skeleton;
  const levels = new Array(s.levels.length).fill(0);
  let faces = 0;
  for (const i of streamer.drawn) {
    levels[s.level[i]]++;
    faces += s.faces[i];
  }
  $('s-faces').textContent = faces.toLocaleString();
  $('s-nodes').textContent = `${streamer.drawn.length} / ${streamer.front.length}`;
  $('s-levels').textContent = levels.join(' ');
  $('s-read').textContent = `${fmtBytes(streamer.source.bytes)} of ${fmtBytes(streamer.source.length ?? 0)}`;
  $('s-requests').textContent = `${streamer.source.requests} (${streamer.inFlight})`;
  $('s-resident').textContent = `${fmtBytes(streamer.residentBytes)} (${fmtBytes(streamer.peakResidentBytes)}) / ${fmtBytes(streamer.budget)}`;
  $('r-textures').hidden = $('r-textures-resident').hidden = streamer.usedImages.length === 0;
  $('s-textures').textContent = `${fmtBytes(streamer.textureBytesRead)} (${streamer.textureRequests})`;
  $('s-textures-resident').textContent = fmtBytes(streamer.textureResidentBytes);
  // An image level the browser cannot decode is left out (a coarser one stands in), and said so.
  // So is a damaged table of separating planes: the model is drawn in the nearest-box order.
  if (streamer.imageErrors.size > 0 || streamer.planesError) {
    showWarning([streamer.source.warning, streamer.planesError, ...streamer.imageErrors.values()].filter(Boolean).join(' '));
  }
  $('s-frame').textContent = `${frameMs.toFixed(1)} ms`;
  $('s-decoding').textContent = decoding();
  $('s-first').textContent = firstFrameMs === null ? '–' : `${firstFrameMs.toFixed(0)} ms, ${firstFrameRequests} requests, ${fmtBytes(firstFrameBytes)}`;
}

/** Open `source`, replacing what is shown; a later open wins over an earlier one still loading. */
async function open(source) {
  const generation = ++opens;
  streamer?.close();
  streamer = null;
  renderer?.release(seamHandle);
  seamHandle = null;
  seamsVersion = 0;
  openStart = generation === 1 ? 0 : performance.now();
  showMessage('');
  showWarning(null);
  picks = [];
  $('picked').textContent = '';
  $('name').textContent = source.name;
  firstFrameMs = null;
  firstTextured = null;
  const decoder = DecoderPool.create(workerCount);
  try {
    // The first read goes out before WebGL starts up, which takes a while in a software renderer.
    const opening = Streamer.open(source, {
      budget: budgetBytes(),
      pixelError: pixelError(),
      decoder,
      onLoad: (i, g) => renderer.upload(g),
      onEvict: (i, handle) => renderer.release(handle),
      onImage: (image, level, bytes, mime) => renderer.uploadImage(bytes, mime),
      onImageEvict: (image, level, handle) => renderer.releaseImage(handle),
      onChange: () => {
        dirty = true;
      },
    });
    opening.catch(() => {});
    renderer ??= new Renderer(canvas);
    const next = await opening;
    if (generation !== opens) {
      next.close();
      return;
    }
    streamer = next;
    showWarning(source.warning);
    showPlace(next.skeleton.georef);
    resize();
    fit();
  } catch (e) {
    decoder?.close();
    if (generation === opens) fail(e);
    throw e;
  }
}

/** Where terrain sits on Earth (GEOR, format-spec §5.2), in the panel; hidden for other models. */
function showPlace(g) {
  $('r-place').hidden = !g;
  if (!g) return;
  const crs = g.crs ? ` (${g.crs})` : '';
  $('s-place').textContent =
    g.frame === 'local_tangent' ? `${g.origin[1].toFixed(5)}°, ${g.origin[0].toFixed(5)}°${crs}`
      : g.frame === 'projected' ? `${g.origin[0].toFixed(1)}, ${g.origin[1].toFixed(1)}${crs}`
        : 'terrain, place unknown';
}

const pixelError = () => 2 ** Number($('error').value);
const budgetBytes = () => Math.round(2 ** Number($('budget').value) * 2 ** 20);

function settings() {
  $('o-error').textContent = pixelError().toFixed(pixelError() < 1 ? 2 : 1);
  $('o-budget').textContent = (budgetBytes() / 2 ** 20).toFixed(0);
  colorMode = $('color').value;
  if (streamer) {
    streamer.pixelError = pixelError();
    streamer.budget = budgetBytes();
  }
  dirty = true;
}

// Camera motion: orbit about the target around the camera's up axis and its right axis.
function rotate(v, axis, a) {
  const k = unit(axis);
  if (!k) return v;
  const c = Math.cos(a), s = Math.sin(a);
  return add(add(scale(v, c), scale(cross(k, v), s)), scale(k, dot(k, v) * (1 - c)));
}

/** Turn about the up axis by dx, and tilt by dy with the elevation kept within ±89°. */
function orbit(dx, dy) {
  const offset = sub(camera.eye, camera.target);
  const up = unit(camera.up) ?? [0, 1, 0];
  const right = unit(cross(up, offset)) ?? [1, 0, 0];
  const o = rotate(offset, up, -dx * 0.008);
  const elevation = Math.asin(Math.max(-1, Math.min(1, dot(unit(o) ?? up, up))));
  const limit = (89 * Math.PI) / 180;
  const next = Math.max(-limit, Math.min(limit, elevation + dy * 0.008));
  camera.eye = add(camera.target, rotate(o, right, elevation - next));
  autoClip = true;
  dirty = true;
}

function pan(dx, dy) {
  const d = length(sub(camera.eye, camera.target));
  const per = (2 * d * Math.tan(FOV / 2)) / canvas.height;
  const f = camera.forward();
  const right = unit(cross(f, camera.up)) ?? [1, 0, 0];
  const up = cross(right, f);
  const move = add(scale(right, -dx * per * devicePixelRatio), scale(up, dy * per * devicePixelRatio));
  camera.eye = add(camera.eye, move);
  camera.target = add(camera.target, move);
  autoClip = true;
  dirty = true;
}

function zoom(factor) {
  const offset = sub(camera.eye, camera.target);
  const { radius } = modelSphere();
  const d = Math.min(Math.max(length(offset) * factor, radius * 1e-3), radius * 1e4);
  camera.eye = add(camera.target, scale(unit(offset) ?? [0, 0, 1], d));
  autoClip = true;
  dirty = true;
}

/** The surface point under canvas pixel (x, y) on the drawn geometry, in model units, or null. */
function pick(x, y) {
  if (!streamer) return null;
  const o = streamer.localOrigin;
  const f = camera.forward();
  const right = unit(cross(f, camera.up)) ?? [1, 0, 0];
  const up = cross(right, f);
  // The ray through the pixel's centre: from the eye (perspective), or parallel to the view
  // direction from the pixel's place on the view plane (orthographic).
  const sx = (x + 0.5) / camera.width - 0.5, sy = 0.5 - (y + 0.5) / camera.height;
  let dir, eye;
  if (camera.projection.orthographic) {
    const h = camera.projection.orthographic.height;
    dir = unit(f);
    eye = sub(add(camera.eye, add(scale(right, sx * h * camera.aspect()), scale(up, sy * h))), o);
  } else {
    const h = 2 * Math.tan(camera.projection.perspective.fov_y / 2);
    dir = unit(add(f, add(scale(right, sx * h * camera.aspect()), scale(up, sy * h))));
    eye = sub(camera.eye, o);
  }
  let best = Infinity;
  let hit = null;
  for (const i of streamer.drawn) {
    const g = streamer.geometry(i);
    const s = streamer.skeleton;
    const c = sub([s.center[3 * i], s.center[3 * i + 1], s.center[3 * i + 2]], o);
    const toC = sub(c, eye);
    const along = dot(toC, dir);
    if (dot(toC, toC) - along * along > s.radius[i] ** 2 || along + s.radius[i] < 0) continue;
    const p = g.local ?? g.positions;
    const ix = g.indices;
    for (let t = 0; t < ix.length; t += 3) {
      const a = 3 * ix[t], b = 3 * ix[t + 1], cc = 3 * ix[t + 2];
      const e1 = [p[b] - p[a], p[b + 1] - p[a + 1], p[b + 2] - p[a + 2]];
      const e2 = [p[cc] - p[a], p[cc + 1] - p[a + 1], p[cc + 2] - p[a + 2]];
      const q = cross(dir, e2);
      const det = dot(e1, q);
      if (Math.abs(det) < 1e-30) continue;
      const sv = [eye[0] - p[a], eye[1] - p[a + 1], eye[2] - p[a + 2]];
      const u = dot(sv, q) / det;
      if (u < 0 || u > 1) continue;
      const r = cross(sv, e1);
      const v = dot(dir, r) / det;
      if (v < 0 || u + v > 1) continue;
      const d = dot(e2, r) / det;
      if (d >= camera.near && d < best) {
        best = d;
        hit = { node: i, level: s.level[i] };
      }
    }
  }
  if (!hit) return null;
  return { ...hit, point: add(add(eye, scale(dir, best)), o), distance: best };
}

function describePicks() {
  const units = streamer.skeleton.header.metresPerUnit;
  const fmt = (p) => p.point.map((v) => v.toPrecision(7)).join(', ');
  const lines = picks.map((p, k) => `${'AB'[k]}: ${fmt(p)} (level ${p.level})`);
  if (picks.length === 2) {
    const d = length(sub(picks[0].point, picks[1].point));
    lines.push(`distance ${d.toPrecision(6)} units${units > 0 ? ` = ${(d * units).toPrecision(6)} m` : ''}`);
  }
  $('picked').textContent = lines.join('\n');
}

function controls() {
  let drag = null;
  canvas.addEventListener('contextmenu', (e) => e.preventDefault());
  canvas.addEventListener('webglcontextlost', (e) => {
    e.preventDefault();
    fail(new Error('The WebGL context was lost (the graphics driver was reset or ran out of memory): reload the page.'));
  });
  canvas.addEventListener('pointerdown', (e) => {
    canvas.setPointerCapture(e.pointerId);
    drag = { x: e.clientX, y: e.clientY, moved: 0, panning: e.button === 2 || e.shiftKey };
  });
  canvas.addEventListener('pointermove', (e) => {
    if (!drag || !camera) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag.moved += Math.abs(dx) + Math.abs(dy);
    drag.x = e.clientX;
    drag.y = e.clientY;
    if (drag.panning) pan(dx, dy);
    else orbit(dx, dy);
  });
  canvas.addEventListener('pointerup', (e) => {
    const click = drag && drag.moved < 4;
    drag = null;
    if (!click || !measuring || !streamer) return;
    // The second click of a double-click is not a second point.
    const now = performance.now();
    const again = lastClick && now - lastClick.t < 500 && Math.abs(e.clientX - lastClick.x) + Math.abs(e.clientY - lastClick.y) < 6;
    lastClick = { t: now, x: e.clientX, y: e.clientY };
    if (again) return;
    const dpr = devicePixelRatio || 1;
    const p = pick(Math.floor(e.offsetX * dpr), Math.floor(e.offsetY * dpr));
    if (!p) return;
    picks = picks.length >= 2 ? [p] : [...picks, p];
    describePicks();
  });
  canvas.addEventListener('dblclick', (e) => {
    // Measuring takes clicks as points; re-centring would move what is being measured.
    if (measuring) return;
    const dpr = devicePixelRatio || 1;
    const p = camera && pick(Math.floor(e.offsetX * dpr), Math.floor(e.offsetY * dpr));
    if (!p) return;
    const move = sub(p.point, camera.target);
    camera.target = p.point;
    camera.eye = add(camera.eye, move);
    dirty = true;
  });
  canvas.addEventListener('wheel', (e) => {
    e.preventDefault();
    if (camera) zoom(Math.exp(e.deltaY * 0.0015));
  }, { passive: false });
  $('fit').addEventListener('click', () => streamer && fit());
  $('measure').addEventListener('click', () => {
    measuring = !measuring;
    $('measure').setAttribute('aria-pressed', String(measuring));
    picks = [];
    $('picked').textContent = measuring ? 'click two points on the model' : '';
  });
  for (const id of ['error', 'budget', 'color']) $(id).addEventListener('input', settings);
  $('open').addEventListener('change', (e) => {
    const f = e.target.files[0];
    if (f) opened = open(new FileSource(f)).catch(() => {});
  });
  let depth = 0;
  window.addEventListener('dragenter', (e) => {
    e.preventDefault();
    depth++;
    $('drop').hidden = false;
  });
  window.addEventListener('dragleave', () => {
    if (--depth <= 0) $('drop').hidden = true;
  });
  window.addEventListener('dragover', (e) => e.preventDefault());
  window.addEventListener('drop', (e) => {
    e.preventDefault();
    depth = 0;
    $('drop').hidden = true;
    const f = e.dataTransfer.files[0];
    if (f) opened = open(new FileSource(f)).catch(() => {});
  });
  window.addEventListener('resize', resize);
}

controls();
settings();
resize();
requestAnimationFrame(frame);
const params = new URLSearchParams(location.search);
/** Decoding workers: one per core beyond the page's own, at least one, at most four. */
const workerCount = params.has('workers') ? Number(params.get('workers')) : Math.min(4, Math.max(1, (navigator.hardwareConcurrency ?? 2) - 1));
const decoding = () =>
  streamer?.decoder ? `${streamer.decoder.size} worker${streamer.decoder.size > 1 ? 's' : ''}, ${streamer.decoder.decoded} nodes`
    : streamer?.decoderError ? `main thread (${streamer.decoderError})`
      : DecoderPool.unavailable && workerCount > 0 ? `main thread (no workers: ${DecoderPool.unavailable})` : 'main thread';
const file = params.get('file');
if (file) opened = open(new HttpSource(new URL(file, location.href).href)).catch(() => {});
else showWarning('No model yet: add ?file=URL to the address, or drop a .strata file here.');

/** What tests (and the console) can ask of the page. */
window.strata = {
  /** Resolves once the model is open and its top level drawn; rejects with the page's message. */
  async ready() {
    await opened;
    if (!streamer) throw new Error($('message').textContent || 'no model');
    await this.idle(false);
  },
  /** Resolves when the front is fully resident and drawn (or, with `full` false, after one frame). */
  idle(full = true) {
    return new Promise((resolve, reject) => {
      if (streamer?.error) return reject(streamer.error);
      dirty = true;
      if (!full) return requestAnimationFrame(() => requestAnimationFrame(resolve));
      idleWaiters.push({ resolve, reject });
    });
  },
  setCamera(json) {
    camera = new Camera(json);
    autoClip = false;
    dirty = true;
  },
  camera: () => camera?.toJSON(),
  setLimits({ pixelError, budget, maxFaces, priority } = {}) {
    if (pixelError !== undefined) {
      streamer.pixelError = pixelError;
      if (pixelError > 0) $('error').value = String(Math.log2(pixelError));
      $('o-error').textContent = String(pixelError);
    }
    if (budget !== undefined) {
      streamer.budget = budget;
      $('budget').value = String(Math.log2(budget / 2 ** 20));
      $('o-budget').textContent = (budget / 2 ** 20).toFixed(0);
    }
    if (maxFaces !== undefined) streamer.maxFaces = maxFaces;
    if (priority !== undefined) streamer.priority = priority;
    dirty = true;
  },
  setColor(mode) {
    colorMode = mode;
    dirty = true;
  },
  /** Draw the seams between levels (selection.md §8) or not, to see what they close. */
  setSeams(on) {
    drawSeams = on;
    dirty = true;
  },
  /** The front `strata stream --print-front` would print for this camera and limits (no loading);
   * `held`: node ids not refined (its first frame holds the top level, selection.md §6), or in a
   * format-4 file group numbers not opened (selection.md §9). */
  async select(json, limits, held = []) {
    await streamer.loadSkeleton();
    const cut = new Selector(streamer.skeleton).select(new Camera(json), limits, new Set(held));
    return { shown: cut.shown, culled: cut.culled, faces: cut.faces };
  },
  state() {
    return {
      camera: camera ? { eye: [...camera.eye], target: [...camera.target] } : null,
      georef: streamer?.skeleton.georef ?? null,
      place: $('r-place').hidden ? '' : $('s-place').textContent,
      front: streamer?.front ?? [],
      drawn: streamer?.drawn ?? [],
      /** The drawn nodes in the order they were drawn (front to back), and whether the planes behind it are read. */
      drawOrder: streamer?.drawOrder ?? [],
      planes: streamer?.planes,
      culled: streamer?.culled ?? [],
      residentBytes: streamer?.residentBytes,
      peakResidentBytes: streamer?.peakResidentBytes,
      textureBytesRead: streamer?.textureBytesRead,
      textureResidentBytes: streamer?.textureResidentBytes,
      textureRequests: streamer?.textureRequests,
      /** Per image drawn: [image, wanted level, level drawn or null]. */
      textureLevels: streamer?.textureLevels() ?? [],
      imagesDecoded: renderer?.decoded ?? [],
      firstTextured,
      textures: $('r-textures').hidden ? '' : `${$('s-textures').textContent}; ${$('s-textures-resident').textContent} resident`,
      budget: streamer?.budget,
      requests: streamer?.source.requests,
      bytesRead: streamer?.source.bytes,
      inFlight: streamer?.inFlight,
      fileLength: streamer?.source.length,
      skeletonEnd: streamer?.skeleton.skeletonEnd,
      topEnd: streamer && (() => {
        const s = streamer.skeleton;
        const [, t1] = s.levelNodes(s.top());
        return Math.ceil((s.offset[t1 - 1] + s.size[t1 - 1]) / 8) * 8;
      })(),
      openMs: streamer?.openMs,
      openRequests: streamer?.openRequests,
      openBytes: streamer?.openBytes,
      firstFrameMs,
      firstFrameRequests,
      firstFrameBytes,
      frameMs,
      decoding: decoding(),
      workerDecoded: streamer?.decoder?.decoded ?? 0,
      mainDecoded: streamer?.mainDecoded ?? 0,
      mainDecodeMs: streamer?.mainDecodeMs ?? 0,
      log: streamer?.source.log ?? [],
      message: $('message').textContent,
      warning: $('warning').hidden ? '' : $('warning').textContent,
    };
  },
  pick,
};
