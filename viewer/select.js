// Front selection: which nodes of a strata file to display for one camera, by the rule of
// format-spec/selection.md (strata's twin: src/stream/refine.rs). It needs the skeleton only.
// Computed in f64; the golden fronts and `strata stream --print-front` are the same rule in f32,
// which agree wherever no decision lies within f32 rounding of its threshold.

import { angle, dot, length, sub, unit } from './camera.js';
import { isComplete } from './format.js';

export const OFF = 0, SHOWN = 1, CULLED = 2, REFINED = 3;
const NO_PARENT = 0xffffffff;
const FACING_MARGIN = 1e-5;

/** Decoded bytes of node i's geometry (selection.md §2), the unit of the byte budget. */
export function recordBytes(skeleton, i) {
  const a = skeleton.header.attributes;
  const perVertex = 12 + (a.normals ? 12 : 0) + (a.uvs ? 8 : 0) + (a.colors ? 4 : 0);
  return skeleton.vertices[i] * perVertex + 12 * skeleton.faces[i];
}

const vec = (array, i) => [array[3 * i], array[3 * i + 1], array[3 * i + 2]];

/** Whether node i can show anything: not back-facing by its cone, and its sphere meets the frustum. */
export function sees(skeleton, i, camera, planes = camera.frustum()) {
  const o = vec(skeleton.center, i);
  const r = skeleton.radius[i];
  const c = skeleton.coneHalfAngle[i];
  const axis = unit(vec(skeleton.coneAxis, i));
  if (axis) {
    let back = false;
    if (camera.perspective) {
      const toEye = sub(camera.eye, o);
      const d = length(toEye);
      if (r >= 0 && d > r && Number.isFinite(d)) back = angle(axis, toEye) - c - Math.asin(r / d) > Math.PI / 2 + FACING_MARGIN;
    } else {
      const toViewer = sub([0, 0, 0], camera.forward());
      back = angle(axis, toViewer) - c > Math.PI / 2 + FACING_MARGIN;
    }
    if (back) return false;
  }
  return planes.every((p) => p[0] * o[0] + p[1] * o[1] + p[2] * o[2] + p[3] >= -r);
}

/** The silhouette priority f(n) of selection.md §2. */
export function silhouette(skeleton, i, camera) {
  const o = vec(skeleton.center, i);
  const e = camera.perspective ? unit(sub(camera.eye, o)) ?? [0, 0, 0] : sub([0, 0, 0], camera.forward());
  const axis = unit(vec(skeleton.coneAxis, i)) ?? [0, 0, 0];
  const a = Math.acos(Math.min(Math.max(dot(e, axis), -1), 1)) + skeleton.coneHalfAngle[i];
  return a < Math.PI ? (1 - Math.cos(a)) / 2 : 1;
}

/** Pixels node i's geometric error spans for `camera`. */
export function projectedError(skeleton, i, camera) {
  return camera.projectedError(skeleton.error[i], vec(skeleton.center, i), skeleton.radius[i]);
}

/**
 * Selection with its per-node marks kept between frames (each frame resets only what the last
 * one touched), so a frame costs what its front costs, not what the file holds.
 */
export class Selector {
  constructor(skeleton) {
    this.skeleton = skeleton;
    this.marks = new Uint8Array(skeleton.nodeCount);
    this.touched = [];
  }

  set(i, m) {
    if (this.marks[i] === OFF) this.touched.push(i);
    this.marks[i] = m;
  }

  /** Whether the nearest marked node at or above m is shown and coarser than m. */
  shownCoarser(m) {
    const s = this.skeleton;
    let j = m;
    for (;;) {
      const k = this.marks[j];
      if (k === SHOWN) return j !== m;
      if (k !== OFF) return false;
      j = s.parent[j];
      if (j === NO_PARENT) return false;
    }
  }

  /**
   * The front for `camera` under `limits` `{pixelError, maxFaces?, maxBytes?, priority: 'error' |
   * 'silhouette' | 'breadth'}`; nodes in `held` (a Set) are not refined.
   * Returns `{shown, culled, faces, bytes}`, shown and culled ascending.
   */
  select(camera, limits, held = new Set()) {
    const s = this.skeleton;
    for (const t of this.touched) this.marks[t] = OFF;
    this.touched = [];
    const planes = camera.frustum();
    const maxFaces = limits.maxFaces ?? Infinity;
    const maxBytes = limits.maxBytes ?? Infinity;
    let faces = 0, bytes = 0;
    let shown = [];
    const [top0, top1] = s.levelNodes(s.top());
    for (let i = top0; i < top1; i++) {
      if (sees(s, i, camera, planes)) {
        this.set(i, SHOWN);
        faces += s.faces[i];
        bytes += recordBytes(s, i);
        shown.push(i);
      } else {
        this.set(i, CULLED);
      }
    }
    // A skeleton decoded in part (decodeSkeleton's topFirst) shows its top level alone.
    const complete = isComplete(s);
    for (let level = s.top(); level >= 1 && complete; level--) {
      const candidates = [];
      for (const i of shown) {
        if (s.childCount[i] === 0 || held.has(i)) continue;
        const pixels = projectedError(s, i, camera);
        if (!(pixels >= limits.pixelError)) continue;
        const key = limits.priority === 'silhouette' ? silhouette(s, i, camera) : limits.priority === 'breadth' ? 0 : pixels;
        candidates.push([Math.fround(key), i]);
      }
      candidates.sort((a, b) => b[0] - a[0] || a[1] - b[1]);
      const next = [];
      for (const [, i] of candidates) {
        let coarser = false;
        for (const m of s.neighbors(i)) {
          if (this.shownCoarser(m)) {
            coarser = true;
            break;
          }
        }
        if (coarser) continue;
        const [c0, c1] = s.children(i);
        const visible = [];
        let f = faces - s.faces[i], b = bytes - recordBytes(s, i);
        for (let c = c0; c < c1; c++) {
          const v = sees(s, c, camera, planes);
          visible.push(v);
          if (v) {
            f += s.faces[c];
            b += recordBytes(s, c);
          }
        }
        if (f > maxFaces || b > maxBytes) continue;
        faces = f;
        bytes = b;
        this.set(i, REFINED);
        for (let c = c0; c < c1; c++) {
          const v = visible[c - c0];
          this.set(c, v ? SHOWN : CULLED);
          if (v) next.push(c);
        }
      }
      shown = next;
    }
    const front = [], culled = [];
    for (const t of this.touched) {
      if (this.marks[t] === SHOWN) front.push(t);
      else if (this.marks[t] === CULLED) culled.push(t);
    }
    front.sort((a, b) => a - b);
    culled.sort((a, b) => a - b);
    return { shown: front, culled, faces, bytes };
  }
}
