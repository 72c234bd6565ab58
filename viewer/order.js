// A front from front to back by the file's separating planes (format-spec/selection.md §5), as
// strata's stream::order computes it: a depth-first walk from the virtual root, each parent's
// children in the order its planes decide for the eye, the nearest box first where none does.
// Numbers are f64 as in the spec; the camera's eye and view direction are first rounded to f32,
// as strata's camera holds them.

import { octaDecode } from './format.js';

const fr = Math.fround;
const OFF = 0, SHOWN = 1, ABOVE = 2;

/** f64 order with -0 before +0, as Rust's total_cmp on finite numbers. */
function compareKeys(a, b) {
  if (a < b) return -1;
  if (a > b) return 1;
  if (a === 0 && b === 0) return Object.is(a, -0) === Object.is(b, -0) ? 0 : Object.is(a, -0) ? -1 : 1;
  return 0;
}

/** The view direction of `camera` in f32 (glam's try_normalize of target − eye), or null. */
function forwardF32(camera) {
  const d = [0, 1, 2].map((k) => fr(fr(camera.target[k]) - fr(camera.eye[k])));
  const len = fr(Math.sqrt(fr(fr(fr(d[0] * d[0]) + fr(d[1] * d[1])) + fr(d[2] * d[2]))));
  const r = fr(1 / len);
  if (!(Number.isFinite(r) && r > 0)) return [0, 0, -1];
  return d.map((x) => fr(x * r));
}

export class Orderer {
  /** An orderer for `skeleton` (format.js) by `planes` (decodePlanes; `{ starts: [], entries: [] }` for none). */
  constructor(skeleton, planes) {
    this.skeleton = skeleton;
    this.planes = planes;
    this.normals = new Float64Array(3 * planes.entries.length);
    planes.entries.forEach((e, k) => octaDecode(e.normal[0], e.normal[1], this.normals, 3 * k));
    this.state = new Uint8Array(skeleton.nodeCount);
  }

  /** `front` (node ids, any order) from front to back for `camera` (camera.js). */
  order(front, camera) {
    const s = this.skeleton, state = this.state, touched = [];
    for (const n of front) {
      if (n < s.nodeCount) {
        state[n] = SHOWN;
        touched.push(n);
      }
    }
    for (const n of front) {
      for (let p = n < s.nodeCount ? s.parent[n] : -1; p >= 0 && p < s.nodeCount && state[p] === OFF; p = s.parent[p]) {
        state[p] = ABOVE;
        touched.push(p);
      }
    }
    const eye = camera.eye.map(fr);
    const ortho = camera.projection.orthographic !== undefined;
    const grid = s.header.grid;
    const view = {
      ortho,
      eye,
      gridEye: eye.map((e, k) => (e - grid.origin[k]) / grid.step),
      dir: ortho ? forwardF32(camera) : null,
    };
    const out = [];
    this.walk(view, -1, s.levelNodes(s.top()), out);
    for (const n of touched) state[n] = OFF;
    return out;
  }

  walk(view, parent, [k0, k1], out) {
    const s = this.skeleton, state = this.state;
    const live = [];
    for (let c = k0; c < k1; c++) if (state[c] !== OFF) live.push(c);
    if (live.length > 1) this.arrange(view, parent, k0, live);
    for (const c of live) {
      if (state[c] === SHOWN) out.push(c);
      else this.walk(view, c, s.children(c), out);
    }
  }

  key(view, c) {
    const s = this.skeleton, lo = s.boxMin, hi = s.boxMax;
    if (view.ortho) {
      const f = view.dir;
      const m = (k) => Math.min(f[k] * lo[3 * c + k], f[k] * hi[3 * c + k]);
      return m(0) + m(1) + m(2);
    }
    const d = [0, 1, 2].map((k) => Math.max(Math.max(lo[3 * c + k] - view.eye[k], 0), view.eye[k] - hi[3 * c + k]));
    return d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
  }

  /** Put `live` (two or more children of `parent`, -1 the virtual root, first child `k0`) in drawing order. */
  arrange(view, parent, k0, live) {
    const n = live.length;
    const local = new Map(live.map((c, k) => [c - k0, k]));
    const successors = live.map(() => []);
    const predecessors = new Uint32Array(n);
    const p = parent + 1;
    const { starts, entries } = this.planes;
    const N = this.normals;
    for (let k = starts[p] ?? 0; k < (starts[p + 1] ?? 0); k++) {
      const e = entries[k];
      const a = local.get(e.first), b = local.get(e.second);
      if (a === undefined || b === undefined) continue;
      let t;
      if (view.ortho) {
        const d = view.dir;
        t = N[3 * k] * d[0] + N[3 * k + 1] * d[1] + N[3 * k + 2] * d[2];
      } else {
        const g = view.gridEye;
        t = N[3 * k] * g[0] + N[3 * k + 1] * g[1] + N[3 * k + 2] * g[2];
      }
      let edge = null;
      if (view.ortho) edge = t > 0 ? [a, b] : t < 0 ? [b, a] : null;
      else edge = t < e.secondMin ? [a, b] : t > e.firstMax ? [b, a] : null;
      if (!edge) continue;
      successors[edge[0]].push(edge[1]);
      predecessors[edge[1]]++;
    }
    const keys = live.map((c) => this.key(view, c));
    const less = (x, y) => {
      const c = compareKeys(keys[x], keys[y]);
      return c < 0 || (c === 0 && live[x] < live[y]);
    };
    const done = new Uint8Array(n);
    const order = [];
    for (let taken = 0; taken < n; taken++) {
      let ready = -1, any = -1;
      for (let k = 0; k < n; k++) {
        if (done[k]) continue;
        if (any < 0 || less(k, any)) any = k;
        if (predecessors[k] === 0 && (ready < 0 || less(k, ready))) ready = k;
      }
      // On a cycle the nearest child left goes next, its predecessors left ignored.
      const k = ready >= 0 ? ready : any;
      done[k] = 1;
      for (const b of successors[k]) if (predecessors[b] > 0) predecessors[b]--;
      order.push(live[k]);
    }
    for (let k = 0; k < n; k++) live[k] = order[k];
  }
}
