// Seams between displayed nodes of adjacent levels (format-spec/selection.md §8), as strata's
// stream::seams finds them: where a node borders displayed nodes one level finer, the slivers of
// background between its simplified border and theirs are filled. Positions match across nodes
// exactly (a grid point decodes to the same f32 in every node), compared by their bits.
//
//   border(level, error, geometry)  a node's open border, kept while the node is displayed
//   seams(sealing, shown)           the fill of a front's seams: { local, normals, indices }

const F = new Float32Array(1);
const U = new Uint32Array(F.buffer);
/** The bits of f32 `x`, −0 as +0. */
function bits(x) {
  F[0] = x + 0;
  return U[0];
}

/** Lexicographic order of two keys (arrays of u32). */
function compare(a, b) {
  for (let k = 0; k < a.length; k++) if (a[k] !== b[k]) return a[k] - b[k];
  return 0;
}

/**
 * The open border of a node of `level` with geometric error `error`, from its decoded `geometry`:
 * the directed edges of its faces that no other face of the node has the other way round, each
 * with the position (local, as drawn) and normal of its first end, in the order of their ends'
 * bits as strata orders them.
 */
export function border(level, error, geometry) {
  const p = geometry.positions, local = geometry.local ?? geometry.positions, n = geometry.normals, t = geometry.indices;
  const nv = p.length / 3;
  // Vertices welded by position: ids in order of first use, each with its key.
  const ids = new Map(), weld = new Int32Array(nv), keys = [];
  for (let v = 0; v < nv; v++) {
    const key = [bits(p[3 * v]), bits(p[3 * v + 1]), bits(p[3 * v + 2])];
    const s = key.join(',');
    let id = ids.get(s);
    if (id === undefined) {
      id = keys.length;
      ids.set(s, id);
      keys.push(key);
    }
    weld[v] = id;
  }
  const M = keys.length;
  const count = new Map();
  for (let f = 0; f < t.length; f += 3) {
    for (let k = 0; k < 3; k++) {
      const i = t[f + k], j = t[f + ((k + 1) % 3)];
      const a = weld[i], b = weld[j];
      if (a === b) continue;
      const e = a * M + b;
      const c = count.get(e);
      if (c === undefined) count.set(e, [1, i]);
      else c[0]++;
    }
  }
  const edges = [];
  for (const [e, [c, v]] of count) {
    const a = Math.floor(e / M), b = e - a * M;
    if (c !== 1 || count.has(b * M + a)) continue;
    edges.push({
      from: keys[a], to: keys[b], fromKey: keys[a].join(','), toKey: keys[b].join(','),
      at: [local[3 * v], local[3 * v + 1], local[3 * v + 2]],
      normal: n ? [n[3 * v], n[3 * v + 1], n[3 * v + 2]] : null,
    });
  }
  edges.sort((x, y) => compare(x.from, y.from) || compare(x.to, y.to));
  return { level, error, edges };
}

/**
 * The triangles that fill the seams of a front: `sealing` holds the borders of the displayed nodes
 * with a neighbour of their level not displayed, ascending by node; `shown` the borders of every
 * displayed node an edge of theirs could meet (those nodes and their displayed neighbours). Loops
 * of open edges with edges of two levels, no wider on average than their nodes' largest error,
 * are each filled by a fan from the lowest vertex, wound against the loop. Returns `{ local,
 * normals, indices, faces }` (`normals` null when the borders carry none).
 */
export function seams(sealing, shown = []) {
  // Vertices as integers for this front, so that edges compare as numbers.
  const ids = new Map();
  const idOf = (key) => {
    let v = ids.get(key);
    if (v === undefined) {
      v = ids.size;
      ids.set(key, v);
    }
    return v;
  };
  const all = [];
  for (const b of sealing) for (const e of b.edges) all.push({ e, level: b.level, error: b.error, a: idOf(e.fromKey), b: idOf(e.toKey) });
  // Per vertex, where the border edges from it lead (small integers as keys stay cheap to hash).
  const present = new Map();
  const add = (a, b) => {
    const l = present.get(a);
    if (l) l.push(b);
    else present.set(a, [b]);
  };
  for (const x of all) add(x.a, x.b);
  for (const b of shown) {
    for (const e of b.edges) {
      const from = ids.get(e.fromKey);
      if (from === undefined) continue;
      const to = ids.get(e.toKey);
      if (to !== undefined) add(from, to);
    }
  }
  const open = all.filter((x) => !present.get(x.b)?.includes(x.a));
  // Per vertex, the open edges leaving it, a queue per level in their order: taking the next one
  // costs the number of levels there, however many edges meet at the vertex.
  const leaving = new Map();
  open.forEach((o, i) => {
    let queues = leaving.get(o.a);
    if (!queues) leaving.set(o.a, (queues = []));
    let q = queues.find((x) => x.level === o.level);
    if (!q) queues.push((q = { level: o.level, edges: [], at: 0 }));
    q.edges.push(i);
  });
  const used = new Uint8Array(open.length);
  /** The first unused edge leaving vertex `v` (by index) of a level other than `level`, else of `level`. */
  const next = (v, level) => {
    let best = -1, same = true;
    for (const q of leaving.get(v) ?? []) {
      while (q.at < q.edges.length && used[q.edges[q.at]]) q.at++;
      if (q.at === q.edges.length) continue;
      const x = q.edges[q.at], s = q.level === level;
      if (best < 0 || (s === same ? x < best : !s)) [best, same] = [x, s];
    }
    return best;
  };
  const withNormals = sealing.some((b) => b.edges.some((e) => e.normal));
  const positions = [], normals = [], indices = [];
  const ring = [];
  for (let start = 0; start < open.length; start++) {
    if (used[start]) continue;
    ring.length = 0;
    let e = start, closed = false;
    for (;;) {
      used[e] = 1;
      ring.push(e);
      const { b: to, level } = open[e];
      if (to === open[start].a) {
        closed = true;
        break;
      }
      // Where loops touch, a loop turns from one level's run to the other's.
      const x = next(to, level);
      if (x < 0) break;
      e = x;
    }
    if (closed) fill(open, ring, withNormals, positions, normals, indices);
  }
  return {
    local: new Float32Array(positions),
    normals: withNormals ? new Float32Array(normals) : null,
    indices: new Uint32Array(indices),
    faces: indices.length / 3,
  };
}

function fill(open, ring, withNormals, positions, normals, indices) {
  const n = ring.length;
  let lo = Infinity, hi = -Infinity, error = 0;
  for (const i of ring) {
    lo = Math.min(lo, open[i].level);
    hi = Math.max(hi, open[i].level);
    error = Math.max(error, open[i].error);
  }
  if (n < 3 || lo === hi) return;
  const at = ring.map((i) => open[i].e.at);
  const p0 = at[0];
  let ax = 0, ay = 0, az = 0, perimeter = 0;
  for (let k = 0; k < n; k++) {
    const a = at[k], b = at[(k + 1) % n];
    const ux = a[0] - p0[0], uy = a[1] - p0[1], uz = a[2] - p0[2];
    const vx = b[0] - p0[0], vy = b[1] - p0[1], vz = b[2] - p0[2];
    ax += uy * vz - uz * vy;
    ay += uz * vx - ux * vz;
    az += ux * vy - uy * vx;
    perimeter += Math.hypot(b[0] - a[0], b[1] - a[1], b[2] - a[2]);
  }
  // Mean width, the area over half the perimeter, at most the error; not filled where the sums are
  // not finite.
  if (!(0.5 * Math.hypot(ax, ay, az) <= error * 0.5 * perimeter)) return;
  let first = 0;
  for (let k = 1; k < n; k++) if (compare(open[ring[k]].e.from, open[ring[first]].e.from) < 0) first = k;
  const base = positions.length / 3;
  for (let k = 0; k < n; k++) {
    const e = open[ring[(first + k) % n]].e;
    positions.push(e.at[0], e.at[1], e.at[2]);
    if (withNormals) normals.push(...(e.normal ?? [0, 0, 0]));
  }
  for (let k = 1; k < n - 1; k++) indices.push(base, base + k + 1, base + k);
}
