// A front from front to back by the file's separating planes (format-spec/selection.md §5), as
// strata's stream::order computes it: a depth-first walk from the virtual root, each parent's
// children in the order its planes decide for the eye, the nearest box first where none does.
// Format 4's nodes have no parents and no planes: its fronts go nearest box first.
// Numbers are f64 as in the spec; the camera's eye and view direction are first rounded to f32,
// as strata's camera holds them.

import { octaDecode } from './format.js';
import { Heap } from './heap.js';

const fr = Math.fround;
const OFF = 0, SHOWN = 1, ABOVE = 2;

/** Children ordered by a plain scan rather than a heap, up to this many (as in Rust; the order is the same). */
const SMALL = 32;

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
    if (s.dag) {
      const view = this.view(camera);
      const keyed = front.filter((n) => n < s.nodeCount).map((n) => [this.key(view, n), n]);
      return keyed.sort((a, b) => a[0] - b[0] || a[1] - b[1]).map((k) => k[1]);
    }
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
    const view = this.view(camera);
    const out = [];
    // An explicit stack (a file may have any number of levels): per parent with two or more live
    // children on the way down, its children in order and the next one to take.
    const stack = [];
    const enter = (parent, [k0, k1]) => {
      for (;;) {
        const live = [];
        for (let c = k0; c < k1 && live.length < 2; c++) if (state[c] !== OFF) live.push(c);
        if (live.length === 0) return;
        if (live.length === 1) {
          const c = live[0];
          if (state[c] === SHOWN) return void out.push(c);
          parent = c;
          [k0, k1] = s.children(c);
          continue;
        }
        const all = [];
        for (let c = k0; c < k1; c++) if (state[c] !== OFF) all.push(c);
        this.arrange(view, parent, k0, all);
        stack.push({ live: all, next: 0 });
        return;
      }
    };
    enter(-1, s.levelNodes(s.top()));
    while (stack.length > 0) {
      const f = stack[stack.length - 1];
      if (f.next === f.live.length) {
        stack.pop();
        continue;
      }
      const c = f.live[f.next++];
      if (state[c] === SHOWN) out.push(c);
      else enter(c, s.children(c));
    }
    for (const n of touched) state[n] = OFF;
    return out;
  }

  /** What the keys and planes need of `camera`: the eye in f32, in grid units, and the view direction (orthographic). */
  view(camera) {
    const eye = camera.eye.map(fr);
    const ortho = camera.projection.orthographic !== undefined;
    const grid = this.skeleton.header.grid;
    return { ortho, eye, gridEye: eye.map((e, k) => (e - grid.origin[k]) / grid.step), dir: ortho ? forwardF32(camera) : null };
  }

  key(view, c) {
    const s = this.skeleton, lo = s.boxMin, hi = s.boxMax;
    if (view.ortho) {
      const f = view.dir;
      const m = (k) => Math.min(f[k] * lo[3 * c + k], f[k] * hi[3 * c + k]);
      // + 0 makes a −0 key +0, as in Rust, so that ties do not hang on zeros' signs.
      return m(0) + m(1) + m(2) + 0;
    }
    const d = [0, 1, 2].map((k) => Math.max(Math.max(lo[3 * c + k] - view.eye[k], 0), view.eye[k] - hi[3 * c + k]));
    return d[0] * d[0] + d[1] * d[1] + d[2] * d[2] + 0;
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
    const less = (x, y) => keys[x] < keys[y] || (keys[x] === keys[y] && live[x] < live[y]);
    const done = new Uint8Array(n);
    const order = [];
    if (n > SMALL) {
      // Kahn's rule with heaps: the ready child with the least key; on a cycle, the least key left.
      const ready = new Heap(less), any = new Heap(less);
      for (let k = 0; k < n; k++) {
        any.push(k);
        if (predecessors[k] === 0) ready.push(k);
      }
      while (order.length < n) {
        let k = ready.pop();
        while (k !== undefined && done[k]) k = ready.pop();
        if (k === undefined) {
          do k = any.pop();
          while (done[k]);
        }
        done[k] = 1;
        for (const b of successors[k]) {
          if (predecessors[b] > 0 && --predecessors[b] === 0 && !done[b]) ready.push(b);
        }
        order.push(live[k]);
      }
      for (let k = 0; k < n; k++) live[k] = order[k];
      return;
    }
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
