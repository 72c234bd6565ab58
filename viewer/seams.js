// Seams between displayed nodes of adjacent levels (format-spec/selection.md §8), as strata's
// stream::seams finds them: where a node borders displayed nodes one level finer, the slivers of
// background between its simplified border and theirs are filled. Positions match across nodes
// exactly (a grid point decodes to the same f32 in every node), compared by their bits.
//
//   border(level, error, geometry)  a node's open border, kept while the node is displayed
//   takingPart(drawn, neighbors)    which drawn nodes' borders the seams need: { sealing, near }
//   seams(sealing, shown)           the fill of a front's seams: { local, normals, indices }
//
// Plain typed arrays and open-addressing tables throughout: this runs on the page's thread, once
// per kept node and again whenever the nodes taking part change.

/** The bits of a position's coordinate as matched: −0 as +0, a NaN quiet (as `x + 0` leaves them). */
const plus = (u) => (u === 0x80000000 ? 0 : (u & 0x7f800000) === 0x7f800000 && u & 0x7fffff ? (u | 0x400000) >>> 0 : u);

/** Spread the high bits of `h` over the low ones, which index the tables (grid positions' low bits are often zeros). */
const mix = (h) => {
  h ^= h >>> 16;
  h = Math.imul(h, 0x7feb352d);
  return h ^ (h >>> 15);
};

/** A hash of three u32. */
const hash3 = (x, y, z) => mix(Math.imul(x, 0x9e3779b1) ^ Math.imul(y, 0x85ebca77) ^ Math.imul(z, 0xc2b2ae3d));

/** A hash of two ints. */
const hash2 = (a, b) => mix(Math.imul(a, 0x9e3779b1) ^ Math.imul(b, 0x85ebca77));

/** The least power of two ≥ 2n (and ≥ 16): a table of n entries at most half full. */
const tableSize = (n) => {
  let m = 16;
  while (m < 2 * n) m *= 2;
  return m;
};

/** Lexicographic order of the 3-u32 keys at `a[i..]` and `b[j..]`. */
function compareKeys(a, i, b, j) {
  return a[i] - b[j] || a[i + 1] - b[j + 1] || a[i + 2] - b[j + 2];
}

/**
 * Distinct positions as small integers: ids in order of first use, the keys (3 u32 each) in
 * `keys`. `id(k, o)` interns the key at `k[o..o+3]`, `find(k, o)` looks it up (−1 if absent).
 */
class Positions {
  constructor(n) {
    this.mask = tableSize(n) - 1;
    this.slots = new Int32Array(this.mask + 1).fill(-1);
    this.keys = new Uint32Array(3 * n);
    this.count = 0;
  }

  find(k, o) {
    const keys = this.keys, slots = this.slots, mask = this.mask;
    for (let h = hash3(k[o], k[o + 1], k[o + 2]) & mask; ; h = (h + 1) & mask) {
      const id = slots[h];
      if (id < 0) return -1;
      if (keys[3 * id] === k[o] && keys[3 * id + 1] === k[o + 1] && keys[3 * id + 2] === k[o + 2]) return id;
    }
  }

  id(k, o) {
    const keys = this.keys, slots = this.slots, mask = this.mask;
    let h = hash3(k[o], k[o + 1], k[o + 2]) & mask;
    for (; ; h = (h + 1) & mask) {
      const id = slots[h];
      if (id < 0) break;
      if (keys[3 * id] === k[o] && keys[3 * id + 1] === k[o + 1] && keys[3 * id + 2] === k[o + 2]) return id;
    }
    const id = this.count++;
    slots[h] = id;
    keys[3 * id] = k[o];
    keys[3 * id + 1] = k[o + 1];
    keys[3 * id + 2] = k[o + 2];
    return id;
  }
}

/**
 * Directed edges between ids: `add(a, b)` returns the edge's index (new ones numbered in order),
 * `find(a, b)` its index or −1.
 */
class Edges {
  constructor(n) {
    this.mask = tableSize(n) - 1;
    this.slots = new Int32Array(this.mask + 1).fill(-1);
    this.from = new Int32Array(n);
    this.to = new Int32Array(n);
    this.count = 0;
  }

  find(a, b) {
    const slots = this.slots, mask = this.mask;
    for (let h = hash2(a, b) & mask; ; h = (h + 1) & mask) {
      const e = slots[h];
      if (e < 0) return -1;
      if (this.from[e] === a && this.to[e] === b) return e;
    }
  }

  add(a, b) {
    const slots = this.slots, mask = this.mask;
    let h = hash2(a, b) & mask;
    for (; ; h = (h + 1) & mask) {
      const e = slots[h];
      if (e < 0) break;
      if (this.from[e] === a && this.to[e] === b) return e;
    }
    const e = this.count++;
    slots[h] = e;
    this.from[e] = a;
    this.to[e] = b;
    return e;
  }
}

/**
 * The open border of a node of `level` with geometric error `error`, from its decoded `geometry`:
 * the directed edges of its faces that no other face of the node has the other way round (edges
 * of zero length, and edges its faces use twice the same way, left out), in the order of their
 * ends' bits as strata orders them. Returns `{ level, error, count, keys, at, normals }`: per
 * edge the bits of its two ends (6 u32 in `keys`), and the position (local, as drawn) and normal
 * of its first end (3 each; `normals` null when the node has none).
 */
export function border(level, error, geometry) {
  const local = geometry.local ?? geometry.positions, n = geometry.normals, t = geometry.indices;
  // Matched on the f32 bits of the positions, whatever array they come in.
  const p = geometry.positions instanceof Float32Array ? geometry.positions : Float32Array.from(geometry.positions);
  const nv = p.length / 3;
  const raw = new Uint32Array(p.buffer, p.byteOffset, p.length);
  const bitsOf = new Uint32Array(3 * nv);
  for (let k = 0; k < 3 * nv; k++) bitsOf[k] = plus(raw[k]);
  // Vertices welded by position.
  const weld = new Int32Array(nv), welded = new Positions(nv);
  for (let v = 0; v < nv; v++) weld[v] = welded.id(bitsOf, 3 * v);
  // Each directed edge once, with how often the faces use it and the first corner it starts at.
  const edges = new Edges(t.length), uses = new Int32Array(t.length), corner = new Int32Array(t.length);
  for (let f = 0; f < t.length; f += 3) {
    for (let k = 0; k < 3; k++) {
      const i = t[f + k], a = weld[i], b = weld[t[f + (k === 2 ? 0 : k + 1)]];
      if (a === b) continue;
      const e = edges.add(a, b);
      if (uses[e]++ === 0) corner[e] = i;
    }
  }
  const open = [];
  for (let e = 0; e < edges.count; e++) if (uses[e] === 1 && edges.find(edges.to[e], edges.from[e]) < 0) open.push(e);
  const K = welded.keys;
  open.sort((x, y) => compareKeys(K, 3 * edges.from[x], K, 3 * edges.from[y]) || compareKeys(K, 3 * edges.to[x], K, 3 * edges.to[y]));
  const count = open.length;
  const keys = new Uint32Array(6 * count), at = new Float32Array(3 * count), normals = n ? new Float32Array(3 * count) : null;
  for (let j = 0; j < count; j++) {
    const e = open[j], a = edges.from[e], b = edges.to[e], v = corner[e];
    for (let c = 0; c < 3; c++) {
      keys[6 * j + c] = K[3 * a + c];
      keys[6 * j + 3 + c] = K[3 * b + c];
      at[3 * j + c] = local[3 * v + c];
      if (normals) normals[3 * j + c] = n[3 * v + c];
    }
  }
  return { level, error, count, keys, at, normals };
}

/**
 * The nodes of the drawn front `drawn` whose borders the seams need: `sealing`, those with a
 * neighbour of their level not drawn, ascending; `near`, their drawn neighbours, ascending (an
 * edge of theirs can only meet theirs or those). `neighbors(i)` lists node i's same-level
 * neighbours; only nodes for which `has(i)` holds (resident) are counted.
 */
export function takingPart(drawn, neighbors, has = () => true) {
  const shown = new Set(drawn);
  const sealing = drawn.filter((i) => has(i) && Array.from(neighbors(i)).some((m) => !shown.has(m))).sort((a, b) => a - b);
  const near = new Set();
  for (const i of sealing) for (const m of neighbors(i)) if (shown.has(m) && has(m)) near.add(m);
  return { sealing, near: [...near].sort((a, b) => a - b) };
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
  let total = 0, known = 0;
  for (const b of sealing) total += b.count;
  for (const b of shown) known += b.count;
  // The sealing edges, their ends as ids for this front: per edge its ends, border and place there.
  const ids = new Positions(2 * total);
  const A = new Int32Array(total), B = new Int32Array(total), owner = new Int32Array(total), at = new Int32Array(total);
  let m = 0;
  sealing.forEach((b, o) => {
    for (let j = 0; j < b.count; j++, m++) {
      A[m] = ids.id(b.keys, 6 * j);
      B[m] = ids.id(b.keys, 6 * j + 3);
      owner[m] = o;
      at[m] = j;
    }
  });
  // Every displayed edge between those vertices; a sealing edge is open if none runs the other way.
  const present = new Edges(total + known);
  for (let i = 0; i < total; i++) present.add(A[i], B[i]);
  for (const b of shown) {
    for (let j = 0; j < b.count; j++) {
      const from = ids.find(b.keys, 6 * j);
      if (from < 0) continue;
      const to = ids.find(b.keys, 6 * j + 3);
      if (to >= 0) present.add(from, to);
    }
  }
  const open = [];
  for (let i = 0; i < total; i++) if (present.find(B[i], A[i]) < 0) open.push(i);
  const n = open.length;
  const level = (x) => sealing[owner[open[x]]].level;
  // Per vertex, the open edges leaving it, a queue per level in their order (runs of `order`
  // sorted by vertex, level, index): taking the next one costs the number of levels there,
  // however many edges meet at the vertex.
  const first = new Int32Array(ids.count + 1);
  for (let x = 0; x < n; x++) first[A[open[x]] + 1]++;
  for (let v = 0; v < ids.count; v++) first[v + 1] += first[v];
  const order = new Int32Array(n), fillAt = first.slice();
  for (let x = 0; x < n; x++) order[fillAt[A[open[x]]]++] = x;
  // Within a vertex, by level, stable: by insertion where few edges meet.
  for (let v = 0; v < ids.count; v++) {
    if (first[v + 1] - first[v] > 32) {
      order.subarray(first[v], first[v + 1]).sort((x, y) => level(x) - level(y) || x - y);
      continue;
    }
    for (let k = first[v] + 1; k < first[v + 1]; k++) {
      const x = order[k], l = level(x);
      let j = k;
      for (; j > first[v] && level(order[j - 1]) > l; j--) order[j] = order[j - 1];
      order[j] = x;
    }
  }
  const queueOf = new Int32Array(ids.count + 1).fill(-1);
  const qStart = [], qAt = [], qLevel = [];
  for (let k = 0; k < n; k++) {
    const x = order[k];
    if (k === 0 || A[open[x]] !== A[open[order[k - 1]]] || level(x) !== level(order[k - 1])) {
      if (k === 0 || A[open[x]] !== A[open[order[k - 1]]]) queueOf[A[open[x]]] = qStart.length;
      qStart.push(k);
      qAt.push(k);
      qLevel.push(level(x));
    }
  }
  qStart.push(n);
  const used = new Uint8Array(n);
  /** The first unused edge leaving vertex `v` (by index) of a level other than `l`, else of `l`. */
  const next = (v, l) => {
    let best = -1, same = true;
    const q0 = queueOf[v];
    if (q0 < 0) return -1;
    for (let q = q0; q < qLevel.length && A[open[order[qStart[q]]]] === v; q++) {
      let c = qAt[q];
      while (c < qStart[q + 1] && used[order[c]]) c++;
      qAt[q] = c;
      if (c === qStart[q + 1]) continue;
      const x = order[c], s = qLevel[q] === l;
      if (best < 0 || (s === same ? x < best : !s)) (best = x), (same = s);
    }
    return best;
  };
  const withNormals = sealing.some((b) => b.normals && b.count > 0);
  const out = { positions: [], normals: [], indices: [] };
  const ring = [];
  for (let start = 0; start < n; start++) {
    if (used[start]) continue;
    ring.length = 0;
    let e = start, closed = false;
    for (;;) {
      used[e] = 1;
      ring.push(e);
      const to = B[open[e]];
      if (to === A[open[start]]) {
        closed = true;
        break;
      }
      // Where loops touch, a loop turns from one level's run to the other's.
      const x = next(to, level(e));
      if (x < 0) break;
      e = x;
    }
    if (closed) fill(ring.map((x) => open[x]), sealing, owner, at, withNormals, out);
  }
  return {
    local: new Float32Array(out.positions),
    normals: withNormals ? new Float32Array(out.normals) : null,
    indices: new Uint32Array(out.indices),
    faces: out.indices.length / 3,
  };
}

/**
 * Fill a loop of sealing edges (indices into `owner`, `at`) when it joins two levels and is thin:
 * a fan from its lowest vertex, wound against the loop.
 */
function fill(ring, sealing, owner, at, withNormals, out) {
  const n = ring.length;
  let lo = Infinity, hi = -Infinity, error = 0;
  for (const i of ring) {
    const b = sealing[owner[i]];
    lo = Math.min(lo, b.level);
    hi = Math.max(hi, b.level);
    error = Math.max(error, b.error);
  }
  if (n < 3 || lo === hi) return;
  const point = (k) => {
    const i = ring[k % n], o = 3 * at[i], p = sealing[owner[i]].at;
    return [p[o], p[o + 1], p[o + 2]];
  };
  const p0 = point(0);
  let ax = 0, ay = 0, az = 0, perimeter = 0;
  for (let k = 0; k < n; k++) {
    const a = point(k), b = point(k + 1);
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
  const keyOf = (k) => [sealing[owner[ring[k]]].keys, 6 * at[ring[k]]];
  let first = 0;
  for (let k = 1; k < n; k++) if (compareKeys(...keyOf(k), ...keyOf(first)) < 0) first = k;
  const base = out.positions.length / 3;
  for (let k = 0; k < n; k++) {
    const i = ring[(first + k) % n], o = 3 * at[i], b = sealing[owner[i]];
    out.positions.push(b.at[o], b.at[o + 1], b.at[o + 2]);
    if (withNormals) {
      if (b.normals) out.normals.push(b.normals[o], b.normals[o + 1], b.normals[o + 2]);
      else out.normals.push(0, 0, 0);
    }
  }
  for (let k = 1; k < n - 1; k++) out.indices.push(base, base + k + 1, base + k);
}
