// The viewer's seams between levels (viewer/seams.js, format-spec/selection.md §8) on hand-made
// nodes, and against strata's Streamer (`strata stream --print-front`, its `seam_faces` and
// `seam_area`) on the fronts of an orbit over the converted noisy sphere fixture: the same fronts
// get as many fill triangles, of the same area, in both readers.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { decodeSkeleton, decodeNode } from '../../viewer/format.js';
import { border, seams, takingPart } from '../../viewer/seams.js';
import { root, strataBin, converted, run } from './helpers.mjs';

const geometry = (positions, indices) => ({ positions: new Float32Array(positions.flat()), indices: new Uint32Array(indices), normals: null });

/** A coarse triangle over a finer pair whose shared vertex lies `dip` below the coarse edge. */
function pair(dip) {
  const coarse = geometry([[0, 0, 0], [2, 0, 0], [1, 1, 0]], [0, 1, 2]);
  const fine = geometry([[0, 0, 0], [1, -dip, 0], [2, 0, 0], [1, -1, 0]], [0, 3, 1, 1, 3, 2]);
  return [coarse, fine];
}

test('a sliver between levels is filled, wound as the faces around it', () => {
  const [coarse, fine] = pair(0.05);
  const s = seams([border(1, 0.1, coarse), border(0, 0, fine)]);
  assert.equal(s.faces, 1);
  const p = (k) => Array.from(s.local.subarray(3 * s.indices[k], 3 * s.indices[k] + 3));
  const [a, b, c] = [p(0), p(1), p(2)];
  assert.ok((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]) > 0);
  assert.ok([a, b, c].some((v) => v[0] === 1 && v[1] === Math.fround(-0.05)));
});

test('one level, a gap wider than the error, a shared border: no seam', () => {
  let [coarse, fine] = pair(0.05);
  assert.equal(seams([border(1, 0.1, coarse), border(1, 0.1, fine)]).faces, 0);
  [coarse, fine] = pair(0.5);
  assert.equal(seams([border(1, 0.1, coarse), border(0, 0, fine)]).faces, 0);
  [, fine] = pair(0);
  const straight = geometry([[0, 0, 0], [1, 0, 0], [2, 0, 0], [1, 1, 0]], [0, 1, 3, 1, 2, 3]);
  assert.equal(seams([border(1, 0.1, straight), border(0, 0, fine)]).faces, 0);
});

test('many slivers meeting at one vertex are each filled once', () => {
  // 48 coarse triangles and 48 finer pairs around the origin, each pair one sliver: 96 open
  // edges leave the origin, two levels there.
  const K = 48, turn = (k, [x, y]) => {
    const a = (2 * Math.PI * k) / K;
    return [x * Math.cos(a) - y * Math.sin(a), x * Math.sin(a) + y * Math.cos(a), 0];
  };
  const coarse = [], fine = [], ci = [], fi = [];
  for (let k = 0; k < K; k++) {
    const c = coarse.length, f = fine.length;
    coarse.push([0, 0, 0], turn(k, [2, 0]), turn(k, [1, 1]));
    ci.push(c, c + 1, c + 2);
    fine.push([0, 0, 0], turn(k, [1, -0.05]), turn(k, [2, 0]), turn(k, [1, -1]));
    fi.push(f, f + 3, f + 1, f + 1, f + 3, f + 2);
  }
  const s = seams([border(1, 0.1, geometry(coarse, ci)), border(0, 0, geometry(fine, fi))]);
  assert.equal(s.faces, K);
});

/** The fill's area, from its local positions. */
function area(f) {
  let sum = 0;
  for (let k = 0; k < f.indices.length; k += 3) {
    const [a, b, c] = [0, 1, 2].map((j) => f.local.subarray(3 * f.indices[k + j], 3 * f.indices[k + j] + 3));
    const u = [0, 1, 2].map((j) => b[j] - a[j]), v = [0, 1, 2].map((j) => c[j] - a[j]);
    sum += 0.5 * Math.hypot(u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]);
  }
  return sum;
}

test('the seams of strata stream on a converted fixture', (t) => {
  const file = converted('noisy_sphere', `${root}/fixtures/noisy_sphere.ply`, []);
  const out = run(strataBin(), ['stream', file, '--json', '--print-front', '--orbit', '32']);
  const frames = out.trim().split('\n').map((l) => JSON.parse(l));
  const bytes = new Uint8Array(readFileSync(file));
  const s = decodeSkeleton(bytes, bytes.length);
  // As the viewer decodes: positions relative to the model's centre too, drawn from those.
  const h = s.header;
  const localOrigin = h.min.map((m, k) => (m + h.max[k]) / 2);
  const borders = new Map();
  const borderOf = (i) => {
    if (!borders.has(i)) {
      const g = decodeNode(s, i, bytes.subarray(s.offset[i], s.offset[i] + s.size[i]), { localOrigin });
      borders.set(i, border(s.level[i], s.error[i], g));
    }
    return borders.get(i);
  };
  let filled = 0;
  for (const f of frames) {
    const { sealing, near } = takingPart(f.front, (i) => s.neighbors(i));
    const fill = seams(sealing.map(borderOf), near.map(borderOf));
    assert.equal(fill.faces, f.seam_faces, `frame ${f.frame}: seam faces`);
    const a = area(fill);
    assert.ok(Math.abs(a - f.seam_area) <= 1e-4 * f.seam_area + 1e-9, `frame ${f.frame}: seam area ${a} against ${f.seam_area}`);
    filled += fill.faces;
  }
  assert.ok(filled > 0, 'the orbit shows seams');
  t.diagnostic(`${frames.length} fronts, ${filled} seam faces of the same area as strata stream's`);
});
