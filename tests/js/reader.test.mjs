// Tests of the viewer's reader of the strata format (viewer/format.js) against the spec
// (format-spec/strata-v2.md), the golden vectors (format-spec/vectors/) and, when the release binary
// is built, files strata itself converts. Run with `node --test tests/js/reader.test.mjs`.

import test from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync, readdirSync, existsSync, mkdtempSync, rmSync } from 'node:fs';
import { execFileSync } from 'node:child_process';
import { tmpdir } from 'node:os';
import { join, dirname } from 'node:path';
import { fileURLToPath } from 'node:url';
import { MAJOR, MINOR, NEWEST_MAJOR, MINOR3, MINOR4, FormatError, crc32, openingRange, completeSkeleton, skeletonNeeds, decodeSkeleton, decodeNode, decodeImageLevel, decodePlanes, planesOffset, MAP_KINDS } from '../../viewer/format.js';

const ROOT = join(dirname(fileURLToPath(import.meta.url)), '..', '..');
const VECTORS = join(ROOT, 'format-spec', 'vectors');
const fr = Math.fround;
const read = (name) => new Uint8Array(readFileSync(join(VECTORS, name)));
const vectorNames = () => readdirSync(VECTORS).filter((f) => f.endsWith('.strata')).map((f) => f.slice(0, -7)).sort();

// ---------------------------------------------------------------------------------------------
// Helpers

const nodeBytes = (sk, i, bytes) => bytes.subarray(sk.offset[i], sk.offset[i] + sk.size[i]);

/** Open a whole file in memory and decode every node and image level (throws at the first problem). */
function decodeAll(bytes, opts) {
  const sk = decodeSkeleton(bytes, bytes.length);
  const geoms = [];
  for (let i = 0; i < sk.nodeCount; i++) geoms.push(decodeNode(sk, i, nodeBytes(sk, i, bytes), opts));
  const images = sk.textures.levels.map((l, e) => decodeImageLevel(sk, e, bytes.subarray(l.offset, l.offset + l.size)));
  const planes = decodePlanes(sk, bytes.subarray(Math.min(planesOffset(sk), bytes.length)));
  return { sk, geoms, images, planes };
}

/** decodeAll with the skeleton decoded top first, as the viewer opens a file: from the prefix
 * openingRange names (format 3: SKEL up to its top pages), the top level's nodes, then
 * completeSkeleton and every other node. */
function decodeTopFirst(bytes, opts) {
  const r = openingRange(bytes, bytes.length);
  const sk = decodeSkeleton(bytes.subarray(0, r.pagesEnd ?? r.skeletonEnd), bytes.length, { topFirst: true });
  const top = sk.levelNodes(sk.top())[1];
  const geoms = [];
  for (let i = 0; i < top; i++) geoms.push(decodeNode(sk, i, nodeBytes(sk, i, bytes), opts));
  completeSkeleton(sk, bytes);
  for (let i = top; i < sk.nodeCount; i++) geoms.push(decodeNode(sk, i, nodeBytes(sk, i, bytes), opts));
  const images = sk.textures.levels.map((l, e) => decodeImageLevel(sk, e, bytes.subarray(l.offset, l.offset + l.size)));
  const planes = decodePlanes(sk, bytes.subarray(Math.min(planesOffset(sk), bytes.length)));
  return { sk, geoms, images, planes };
}

/** Whether the file is refused (true) or read (false), whole and top first alike; anything but a
 * FormatError fails the test. */
function refused(bytes, what) {
  const outcome = (decode) => {
    try {
      decode(bytes);
      return null;
    } catch (e) {
      if (!(e instanceof FormatError)) {
        assert.fail(`${what}: threw ${e && e.name}: ${e && e.message}\n${e && e.stack}`);
      }
      return e;
    }
  };
  const whole = outcome(decodeAll), topFirst = outcome(decodeTopFirst);
  assert.equal(topFirst === null, whole === null, `${what}: whole ${whole?.message}; top first ${topFirst?.message}`);
  return whole !== null;
}

/** The JSON `strata::format::inspect::dump` makes of a file (src/format/inspect.rs); `images` are
 * the image files of the level entries, for files with images. */
function dump(sk, geoms, images = [], planes = { starts: [], entries: [] }) {
  const v3 = (a, o) => [a[o], a[o + 1], a[o + 2]];
  const rows = (a, k) => Array.from({ length: a ? a.length / k : 0 }, (_, j) => Array.from(a.subarray(k * j, k * j + k)));
  const h = sk.header;
  return {
    version: `${sk.major}.${sk.minor}`,
    header: {
      file_size: h.fileSize,
      metres_per_unit: h.metresPerUnit,
      min: h.min,
      max: h.max,
      attributes: h.attributes,
      levels: h.levels,
      nodes: h.nodes,
      materials: h.materials,
      input_vertices: h.inputVertices,
      input_faces: h.inputFaces,
      clusters: h.clusters,
      params: h.params,
      grid: { origin: h.grid.origin, step: h.grid.step, bits: h.grid.bits },
      level_ratio: h.levelRatio,
      tool: h.tool,
    },
    georef: sk.georef && {
      frame: sk.georef.frame,
      origin: sk.georef.origin,
      metres_per_crs_unit: sk.georef.metresPerCrsUnit,
      z_scale: sk.georef.zScale,
      crs: sk.georef.crs,
    },
    levels: sk.levels.map((l) => ({ first_node: l.firstNode, nodes: l.nodes, faces: l.faces, vertices: l.vertices, bytes: l.bytes })),
    materials: sk.materials.map((m) => ({ name: m.name, base_color: m.baseColor, texture: m.texture })),
    nodes: geoms.map((g, i) => ({
      level: sk.level[i],
      parent: sk.parent[i] === 0xffffffff ? null : sk.parent[i],
      first_child: sk.firstChild[i],
      child_count: sk.childCount[i],
      neighbors: Array.from(sk.neighbors(i)),
      cone: { axis: v3(sk.coneAxis, 3 * i), half_angle: sk.coneHalfAngle[i] },
      center: v3(sk.center, 3 * i),
      radius: sk.radius[i],
      box: { min: v3(sk.boxMin, 3 * i), max: v3(sk.boxMax, 3 * i) },
      error: sk.error[i],
      faces: sk.faces[i],
      vertices: sk.vertices[i],
      offset: sk.offset[i],
      size: sk.size[i],
      crc: sk.crc[i],
      geometry: {
        positions: rows(g.positions, 3),
        normals: rows(g.normals, 3),
        uvs: rows(g.uvs, 2),
        colors: rows(g.colors, 4),
        indices: Array.from(g.indices),
        material_ranges: g.materialRanges,
        // Format 3 stores a cluster's faces only.
        clusters: g.clusters.map((c) =>
          sk.major >= 3
            ? { first_face: c.firstFace, face_count: c.faceCount }
            : { cone: { axis: c.axis, half_angle: c.halfAngle }, center: c.center, radius: c.radius, first_face: c.firstFace, face_count: c.faceCount },
        ),
      },
    })),
    ...(sk.code ? { code: { normal_bits: sk.code.normalBits, color_bits: sk.code.colorBits, freqs: sk.code.freqs } } : {}),
    // Format 4: the groups in file order, each node's consumer and source (null: none).
    ...(sk.dag
      ? {
          dag: {
            groups: Array.from({ length: sk.dag.groupCount }, (_, g) => ({
              level: sk.dag.groups.level[g],
              first_output: sk.dag.groups.firstOutput[g],
              outputs: sk.dag.groups.outputs[g],
              children: sk.dag.groups.children[g],
              error: sk.dag.groups.error[g],
              center: v3(sk.dag.groups.center, 3 * g),
              radius: sk.dag.groups.radius[g],
            })),
            consumer: Array.from(sk.dag.consumer, (x) => (x === 0xffffffff ? null : x)),
            source: Array.from(sk.dag.source, (x) => (x === 0xffffffff ? null : x)),
          },
        }
      : {}),
    ...(planes.starts.length
      ? {
          planes: planes.starts.slice(0, -1).flatMap((a, p) =>
            planes.entries.slice(a, planes.starts[p + 1]).map((e) => ({
              parent: p - 1,
              first: e.first,
              second: e.second,
              normal: e.normal,
              first_max: e.firstMax,
              second_min: e.secondMin,
            })),
          ),
        }
      : {}),
    ...(sk.textures.images.length
      ? {
          textures: {
            images: sk.textures.images.map((i) => ({ name: i.name, codec: i.codec, levels: i.levels })),
            levels: sk.textures.levels.map((l, e) => ({
              image: l.image,
              level: l.level,
              width: l.width,
              height: l.height,
              offset: l.offset,
              size: l.size,
              crc: l.crc,
              file_bytes: images[e].length,
              file_crc: crc32(images[e]),
            })),
            maps: sk.materials.map((m) => MAP_KINDS.map((k) => m.maps[k])),
            uv_density: Array.from(sk.textures.uvDensity),
          },
        }
      : {}),
  };
}

// Fields that are f64 in the file: compared exactly. Every other non-integer is an f32, compared as
// Math.fround of the JSON number against the decoded value, bit for bit (Object.is: -0 ≠ 0).
const F64_PATHS = [/^header\.metres_per_unit$/, /^header\.grid\.(origin\.\d|step)$/, /^georef\./];

/** The first difference between `expected` (JSON) and `actual`, as "path: what", or null. */
function difference(expected, actual, path = '') {
  if (typeof expected === 'number') {
    if (typeof actual !== 'number') return `${path}: expected ${expected}, got ${actual}`;
    if (Object.is(expected, actual)) return null;
    const f64 = F64_PATHS.some((r) => r.test(path));
    if (!f64 && !Number.isInteger(expected) && Object.is(fr(expected), actual)) return null;
    if (!f64 && Number.isInteger(expected) && Math.abs(expected) < 2 ** 24 && Object.is(fr(expected), actual)) return null;
    return `${path}: expected ${expected}, got ${actual}`;
  }
  if (expected === null || typeof expected !== 'object') {
    return Object.is(expected, actual) ? null : `${path}: expected ${JSON.stringify(expected)}, got ${JSON.stringify(actual)}`;
  }
  if (Array.isArray(expected)) {
    if (!Array.isArray(actual)) return `${path}: expected an array, got ${typeof actual}`;
    if (expected.length !== actual.length) return `${path}: expected ${expected.length} items, got ${actual.length}`;
    for (let k = 0; k < expected.length; k++) {
      const d = difference(expected[k], actual[k], `${path}.${k}`);
      if (d) return d;
    }
    return null;
  }
  if (actual === null || typeof actual !== 'object') return `${path}: expected an object, got ${actual}`;
  const ek = Object.keys(expected).sort(), ak = Object.keys(actual).sort();
  if (ek.join() !== ak.join()) return `${path}: keys ${ek} != ${ak}`;
  for (const k of ek) {
    const d = difference(expected[k], actual[k], path ? `${path}.${k}` : k);
    if (d) return d;
  }
  return null;
}

// A chunk tree, to build variants of a file: parse, edit, serialize with checksums (and, on
// request, the node table's sizes, LEVL totals and HEAD's file size) recomputed.

const le = (b) => new DataView(b.buffer, b.byteOffset, b.byteLength);
const pad8 = (n) => (8 - (n % 8)) % 8;
const ascii = (b, o) => String.fromCharCode(b[o], b[o + 1], b[o + 2], b[o + 3]);

function parseChunks(b, start, end) {
  const out = [];
  let pos = start;
  while (pos < end) {
    const size = Number(le(b).getBigUint64(pos + 8, true));
    const c = { id: ascii(b, pos), flags: le(b).getUint32(pos + 4, true), at: pos };
    const payload = b.slice(pos + 16, pos + 16 + size);
    if (c.id === 'SKEL' || c.id === 'GEOM') c.subs = parseChunks(b, pos + 16, pos + 16 + size).map((s) => ({ ...s, at: s.at }));
    else c.payload = payload;
    out.push(c);
    const e = pos + 20 + size;
    pos = e + pad8(e);
  }
  return out;
}

function parseTree(bytes) {
  const tree = { major: le(bytes).getUint16(8, true), minor: le(bytes).getUint16(10, true), chunks: parseChunks(bytes, 16, bytes.length) };
  // Format 3: the node payloads' sizes, to cut GEOS's payload into them when resealing. Format 4's
  // pages hold group records before the node records.
  const skel = find(tree.chunks, 'SKEL');
  if (skel) skel.dag = tree.major === 4;
  if (tree.major >= 3 && skel) {
    tree.payloadSizes = [];
    for (let i = 0, r; (r = recordOf(skel, i)); i++) tree.payloadSizes.push(r[0].getUint32(r[1] + 48, true));
  }
  return tree;
}

/** Where node i's record lies in SKEL: [DataView, offset] in NODE, or in its level's NODL page (formats 3 and 4); null past the last. */
function recordOf(skel, i) {
  const node = find(skel.subs, 'NODE');
  if (node) return 56 * i + 56 <= node.payload.length ? [le(node.payload), 56 * i] : null;
  const levl = find(skel.subs, 'LEVL');
  const pages = skel.subs.filter((s) => s.id === 'NODL');
  if (!levl) return null;
  const d = le(levl.payload);
  for (let r = d.byteLength - 32, k = 0; r >= 0 && k < pages.length; r -= 32, k++) {
    const first = d.getUint32(r, true), n = d.getUint32(r + 4, true);
    const base = skel.dag ? 4 + 24 * le(pages[k].payload).getUint32(0, true) : 0;
    if (i >= first && i < first + n && base + 56 * (i - first) + 56 <= pages[k].payload.length) return [le(pages[k].payload), base + 56 * (i - first)];
  }
  return null;
}

/** A SKEL's NODE and NBRS (format 2, 3.0) made format 3.1's NODL pages, one per level from the top, last in SKEL. */
function toPages(skel) {
  const node = find(skel.subs, 'NODE').payload, nbrs = find(skel.subs, 'NBRS');
  const levl = le(find(skel.subs, 'LEVL').payload);
  const width = nbrs.flags;
  const pages = [];
  let entry = 0;
  for (let r = levl.byteLength - 32; r >= 0; r -= 32) {
    const first = levl.getUint32(r, true), n = levl.getUint32(r + 4, true);
    const records = node.slice(56 * first, 56 * (first + n));
    let k = 0;
    for (let i = 0; i < n; i++) k += le(records).getUint16(56 * i + 2, true);
    pages.push({ id: 'NODL', flags: width, payload: concat([records, nbrs.payload.slice(width * entry, width * (entry + k))]) });
    entry += k;
  }
  skel.subs = [...skel.subs.filter((s) => s.id !== 'NODE' && s.id !== 'NBRS'), ...pages];
}

/** A format-3.1 SKEL's NODL pages made format 3.0's NODE and NBRS (after LEVL, as 3.0 writers put them). */
function fromPages(skel) {
  const pages = skel.subs.filter((s) => s.id === 'NODL');
  const levl = le(find(skel.subs, 'LEVL').payload);
  const records = [], entries = [];
  pages.forEach((p, k) => {
    const n = levl.getUint32(levl.byteLength - 32 * (k + 1) + 4, true);
    records.push(p.payload.slice(0, 56 * n));
    const e = p.payload.slice(56 * n);
    for (let o = 0; o < e.length; o += p.flags) {
      const x = new Uint8Array(4);
      le(x).setUint32(0, p.flags === 2 ? le(e).getUint16(o, true) : le(e).getUint32(o, true), true);
      entries.push(x);
    }
  });
  const width = pages.every((p) => p.flags === 2) ? 2 : 4;
  const rest = skel.subs.filter((s) => s.id !== 'NODL');
  const at = rest.findIndex((s) => s.id === 'LEVL') + 1;
  rest.splice(at, 0, { id: 'NODE', flags: 0, payload: concat(records) }, { id: 'NBRS', flags: width, payload: concat(entries.map((x) => x.subarray(0, width))) });
  skel.subs = rest;
}

function concat(parts) {
  const out = new Uint8Array(parts.reduce((n, p) => n + p.length, 0));
  let o = 0;
  for (const p of parts) out.set(p, (o += p.length) - p.length);
  return out;
}

function chunkBytes(id, flags, payload) {
  const out = new Uint8Array(20 + payload.length + pad8(20 + payload.length));
  for (let k = 0; k < 4; k++) out[k] = id.charCodeAt(k);
  const d = le(out);
  d.setUint32(4, flags, true);
  d.setBigUint64(8, BigInt(payload.length), true);
  out.set(payload, 16);
  d.setUint32(16 + payload.length, crc32(payload), true);
  return out;
}

const subsPayload = (subs) => concat(subs.map((s) => chunkBytes(s.id, s.flags, s.payload)));

/** GEOS's payload cut into node payloads of `sizes` bytes (what is left over, none). */
function cutPayloads(payload, sizes) {
  const out = [];
  let o = 0;
  for (const n of sizes) out.push(payload.subarray(Math.min(o, payload.length), Math.min((o += n), payload.length)));
  return out;
}
const find = (list, id) => list.find((c) => c.id === id);

/**
 * The file of `tree`: every CRC recomputed, each node's size and CRC in the node table set to its
 * GEOM chunk's (format 3: its payload's, GEOS's payload cut by the sizes the file had); with
 * `totals`, also LEVL's faces, vertices and bytes and HEAD's file size.
 */
function serialize(tree, { totals = false } = {}) {
  const geos = find(tree.chunks, 'GEOS');
  const v3 = !!(geos && tree.payloadSizes);
  const geoms = v3 ? cutPayloads(geos.payload, tree.payloadSizes) : tree.chunks.filter((c) => c.id === 'GEOM').map((c) => subsPayload(c.subs));
  const skel = find(tree.chunks, 'SKEL');
  if (skel) {
    geoms.forEach((g, i) => {
      const rec = recordOf(skel, i);
      if (!rec) return;
      rec[0].setUint32(rec[1] + 48, v3 ? g.length : 20 + g.length, true);
      rec[0].setUint32(rec[1] + 52, crc32(g), true);
    });
    const levl = find(skel.subs, 'LEVL');
    if (totals && levl) {
      const l = le(levl.payload);
      for (let r = 0; r + 32 <= levl.payload.length; r += 32) {
        const first = l.getUint32(r, true), count = l.getUint32(r + 4, true);
        let f = 0, v = 0, by = 0;
        for (let i = first, rec; i < first + count && (rec = recordOf(skel, i)); i++) {
          const [d, o] = rec;
          f += d.getUint32(o + 40, true);
          v += d.getUint32(o + 44, true);
          const s = d.getUint32(o + 48, true);
          by += v3 ? s : s + pad8(s);
        }
        l.setBigUint64(r + 8, BigInt(f), true);
        l.setBigUint64(r + 16, BigInt(v), true);
        l.setBigUint64(r + 24, BigInt(by), true);
      }
    }
  }
  let g = 0;
  const parts = tree.chunks.map((c) => chunkBytes(c.id, c.flags, c.subs ? (c.id === 'GEOM' ? geoms[g++] : subsPayload(c.subs)) : c.payload));
  const total = 16 + parts.reduce((n, p) => n + p.length, 0);
  const head = tree.chunks.findIndex((c) => c.id === 'HEAD');
  if (totals && head >= 0) {
    le(tree.chunks[head].payload).setBigUint64(0, BigInt(total), true);
    parts[head] = chunkBytes('HEAD', tree.chunks[head].flags, tree.chunks[head].payload);
  }
  const pro = new Uint8Array(16);
  pro.set([0x89, 0x53, 0x54, 0x52, 0x41, 0x54, 0x41, 0x0a]);
  le(pro).setUint16(8, tree.major, true);
  le(pro).setUint16(10, tree.minor, true);
  le(pro).setUint32(12, crc32(pro, 0, 12), true);
  return concat([pro, ...parts]);
}

const clone = (tree) => structuredClone(tree);

/** Every leaf payload of a tree (HEAD, SKEL's sub-chunks, GEOM's sub-chunks), with a name. */
function leaves(tree) {
  const out = [];
  tree.chunks.forEach((c, ci) => {
    if (c.payload) out.push({ name: c.id, get: (t) => t.chunks[ci].payload });
    else c.subs.forEach((s, si) => out.push({ name: `${c.id}@${c.at}/${s.id}`, get: (t) => t.chunks[ci].subs[si].payload }));
  });
  return out;
}

// ---------------------------------------------------------------------------------------------
// (1) CRC-32

test('crc32 is the ISO-HDLC CRC of zlib and PNG', () => {
  const ascii9 = new TextEncoder().encode('123456789');
  assert.equal(crc32(ascii9), 0xcbf43926);
  assert.equal(crc32(new Uint8Array(0)), 0);
  // Slice-by-8 agrees with the bytewise definition at every length and start.
  const data = new Uint8Array(300).map((_, k) => (k * 131 + 7) & 0xff);
  const slow = (b, s, e) => {
    let c = 0xffffffff;
    for (let i = s; i < e; i++) {
      c ^= b[i];
      for (let k = 0; k < 8; k++) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
    }
    return (c ^ 0xffffffff) >>> 0;
  };
  for (let s = 0; s < 9; s++) for (let e = s; e <= 300; e += 7) assert.equal(crc32(data, s, e), slow(data, s, e), `${s}..${e}`);
  assert.equal(crc32(ascii9, 2, 5), slow(ascii9, 2, 5));
});

// ---------------------------------------------------------------------------------------------
// (2) Golden vectors: the whole file decodes to <name>.json. (3) Refused vectors are refused.

test('every valid golden vector decodes to its JSON, bit for bit', () => {
  let valid = 0;
  for (const name of vectorNames()) {
    const expected = JSON.parse(readFileSync(join(VECTORS, `${name}.json`), 'utf8'));
    if (expected.refused) continue;
    const bytes = read(`${name}.strata`);
    const { sk, geoms, images, planes } = decodeAll(bytes);
    const d = difference(expected, dump(sk, geoms, images, planes));
    assert.equal(d, null, `${name}: ${d}`);
    const t = decodeTopFirst(bytes);
    const dt = difference(expected, dump(t.sk, t.geoms, t.images, t.planes));
    assert.equal(dt, null, `${name}, top first: ${dt}`);
    // The struct of arrays is typed as promised.
    assert.ok(sk.level instanceof Uint16Array && sk.parent instanceof Uint32Array && sk.offset instanceof Float64Array);
    assert.ok(sk.coneAxis instanceof Float32Array && sk.coneAxis.length === 3 * sk.nodeCount && sk.neighborList instanceof Uint32Array);
    assert.equal(sk.top(), sk.levels.length - 1);
    assert.deepEqual(sk.levelNodes(sk.top()), [0, sk.levels[sk.top()].nodes]);
    assert.deepEqual(sk.levelNodes(sk.levels.length), [0, 0]);
    valid++;
  }
  assert.ok(valid >= 2, `${valid} valid vectors`);
});

test('every refused golden vector is refused with a FormatError naming its node and what is wrong', () => {
  let count = 0;
  for (const name of vectorNames()) {
    const expected = JSON.parse(readFileSync(join(VECTORS, `${name}.json`), 'utf8'));
    if (!expected.refused) continue;
    const bytes = read(`${name}.strata`);
    assert.throws(
      () => decodeAll(bytes),
      (e) => {
        assert.ok(e instanceof FormatError, `${name}: ${e}`);
        for (const w of expected.refused) assert.ok(e.message.includes(w), `${name}: "${e.message}" lacks "${w}"`);
        assert.ok(/byte offset \d+/.test(e.message) && /chunk [A-Z]{4} at offset \d+/.test(e.message), e.message);
        assert.equal(typeof e.offset, 'number');
        return true;
      },
    );
    count++;
  }
  assert.ok(count >= 2);
});

// ---------------------------------------------------------------------------------------------
// (4) openingRange on every prefix

test('openingRange on every prefix: needs grow, then the true skeleton and top-level ends', () => {
  for (const name of vectorNames()) {
    const bytes = read(`${name}.strata`);
    // The true ends, from the chunk walk: SKEL's end, and the end of the top level's GEOM chunks.
    const tree = parseTree(bytes);
    const skel = tree.chunks.findIndex((c) => c.id === 'SKEL');
    const levl = le(find(tree.chunks[skel].subs, 'LEVL').payload);
    const L = levl.byteLength / 32;
    const topNodes = levl.getUint32(32 * (L - 1) + 4, true);
    const geoms = tree.chunks.filter((c) => c.id === 'GEOM');
    const geos = find(tree.chunks, 'GEOS');
    let sk, topEnd;
    if (geos) {
      // Format 3: the top level's payloads from the first byte of GEOS's payload; the pages from
      // SKEL's start to the end of the second NODL (SKEL's end if that is its last sub-chunk).
      sk = { skeletonEnd: geos.at };
      topEnd = geos.at + 16 + tree.payloadSizes.slice(0, topNodes).reduce((a, n) => a + n, 0);
      const second = tree.chunks[skel].subs.filter((c) => c.id === 'NODL')[1];
      const end = second && second.at + 20 + second.payload.length;
      sk.pagesEnd = L <= 2 || end + pad8(end) >= geos.at - 4 - pad8(geos.at) ? sk.skeletonEnd : end + pad8(end);
    } else {
      sk = { skeletonEnd: geoms[0].at };
      sk.pagesEnd = sk.skeletonEnd;
      const after = tree.chunks.find((c) => c.id !== 'GEOM' && c.at > geoms[geoms.length - 1].at);
      topEnd = topNodes < geoms.length ? geoms[topNodes].at : after ? after.at : bytes.length;
    }
    for (const fileLength of [bytes.length, undefined]) {
      let need = 0, resolvedAt = -1, topAt = -1, pagesAt = -1;
      for (let p = 0; p <= bytes.length; p++) {
        const r = openingRange(bytes.subarray(0, p), fileLength);
        if (r.need !== undefined) {
          assert.equal(resolvedAt, -1, `${name}: resolved at ${resolvedAt}, asks again at ${p}`);
          assert.ok(r.need > p && r.need >= need && r.need <= bytes.length, `${name}: prefix ${p} needs ${r.need} after ${need}`);
          need = r.need;
          continue;
        }
        if (resolvedAt < 0) resolvedAt = p;
        assert.equal(r.skeletonEnd, sk.skeletonEnd, `${name} prefix ${p}`);
        if (r.topEnd !== undefined) {
          if (topAt < 0) topAt = p;
          assert.equal(r.topEnd, topEnd, `${name} prefix ${p}`);
        } else {
          assert.equal(topAt, -1, `${name}: topEnd known at ${topAt}, lost at ${p}`);
        }
        if (r.pagesEnd !== undefined) {
          if (pagesAt < 0) pagesAt = p;
          assert.equal(r.pagesEnd, sk.pagesEnd, `${name} prefix ${p}`);
        } else {
          assert.equal(pagesAt, -1, `${name}: pagesEnd known at ${pagesAt}, lost at ${p}`);
        }
      }
      // The pages' end is known once the prefix holds them, and a top-first decode needs no more.
      assert.ok(pagesAt >= resolvedAt && pagesAt <= sk.pagesEnd, `${name}: pages known at ${pagesAt}`);
      if (fileLength !== undefined && !name.startsWith('refused')) {
        const part = decodeSkeleton(bytes.subarray(0, sk.pagesEnd), fileLength, { topFirst: true });
        const whole = decodeSkeleton(bytes, fileLength, { topFirst: true });
        assert.deepEqual(part.levelNodes(part.top()), whole.levelNodes(whole.top()));
        assert.equal(part.decoded, whole.decoded, name);
        assert.ok(sk.pagesEnd === sk.skeletonEnd || skeletonNeeds(part) === sk.skeletonEnd, name);
        completeSkeleton(part, bytes.subarray(0, sk.skeletonEnd));
        completeSkeleton(whole);
        for (const key of ['parent', 'firstChild', 'neighborFirst', 'neighborList', 'offset', 'crc', 'error', 'center']) {
          assert.deepEqual(part[key], whole[key], `${name}: ${key}`);
        }
      }
      assert.ok(resolvedAt > 0 && resolvedAt <= sk.skeletonEnd && topAt >= resolvedAt && topAt <= sk.skeletonEnd, `${name}: ${resolvedAt} ${topAt}`);
      // Following the needs from an empty prefix takes a few reads.
      let p = 0, reads = 0, r;
      while ((r = openingRange(bytes.subarray(0, p), fileLength)).need !== undefined) [p, reads] = [r.need, reads + 1];
      assert.ok(reads <= 4 && r.skeletonEnd === sk.skeletonEnd, `${name}: ${reads} reads`);
    }
  }
});

test('format 3 opened from its top pages: the rest of SKEL is checked by completeSkeleton, with the bytes it needs', () => {
  const bytes = read('sphere-v3.strata');
  const { pagesEnd, skeletonEnd } = openingRange(bytes, bytes.length);
  assert.ok(pagesEnd < skeletonEnd, `pages end at ${pagesEnd}, SKEL at ${skeletonEnd}`);
  const open = (b, end = pagesEnd) => decodeSkeleton(b.subarray(0, end), b.length, { topFirst: true });
  assert.throws(() => open(bytes, pagesEnd - 1), (e) => e instanceof FormatError && e.message.includes(`up to offset ${pagesEnd}`));
  // A byte of the third page flipped: the prefix opens; completing refuses it, and keeps refusing.
  const bad = bytes.slice();
  bad[pagesEnd + 20] ^= 1;
  const damaged = open(bad);
  assert.equal(skeletonNeeds(damaged), skeletonEnd);
  assert.throws(() => completeSkeleton(damaged, bad), (e) => e instanceof FormatError && /SKEL.*CRC/.test(e.message));
  assert.throws(() => completeSkeleton(damaged, bytes), /CRC/);
  // Without the bytes, or too few: the caller's mistake, not the file's.
  const sk = open(bytes);
  assert.throws(() => completeSkeleton(sk), (e) => !(e instanceof FormatError) && /skeletonNeeds/.test(e.message));
  assert.throws(() => completeSkeleton(sk, bytes.subarray(0, skeletonEnd - 1)), (e) => !(e instanceof FormatError));
  // The file changed between the reads: the top page read before is not the one in SKEL now.
  const tree = parseTree(bytes);
  const [d] = recordOf(find(tree.chunks, 'SKEL'), 0);
  d.setFloat32(36, d.getFloat32(36, true) * 2, true);
  const changed = serialize(tree);
  assert.equal(changed.length, bytes.length);
  assert.throws(() => completeSkeleton(open(bytes), changed), (e) => e instanceof FormatError && /changed between reads/.test(e.message));
  completeSkeleton(sk, bytes);
  assert.equal(sk.decoded, sk.nodeCount);
  assert.equal(skeletonNeeds(sk), 0);
});

test('a format-3.0 file (its node table in NODE and NBRS) reads as its 3.1 twin; each version keeps its own table', () => {
  for (const name of ['sphere-v3', 'textured-v3', 'plane-v3']) {
    const bytes = read(`${name}.strata`);
    const tree = parseTree(bytes);
    const old = clone(tree);
    old.minor = 0;
    fromPages(find(old.chunks, 'SKEL'));
    const b = serialize(old, { totals: true });
    const [a, z] = [decodeAll(bytes), decodeAll(b)];
    assert.equal(z.sk.minor, 0);
    assert.deepEqual(z.geoms, a.geoms, name);
    for (const key of ['parent', 'firstChild', 'neighborList', 'error', 'center', 'size', 'crc']) assert.deepEqual(z.sk[key], a.sk[key], `${name}: ${key}`);
    assert.deepEqual(decodeTopFirst(b).geoms, a.geoms);
    // 3.0's pages end where its SKEL does.
    const r = openingRange(b, b.length);
    assert.equal(r.pagesEnd, r.skeletonEnd);
    // The other version's table is refused.
    const swapped = clone(old);
    swapped.minor = 1;
    assert.throws(() => decodeAll(serialize(swapped)), (e) => (e instanceof FormatError && /NODE chunk: format 3 keeps nodes in NODL/.test(e.message)) || assert.fail(e.message));
    const paged = clone(tree);
    paged.minor = 0;
    assert.throws(() => decodeAll(serialize(paged)), (e) => (e instanceof FormatError && /holds a NODL page: format 3.0 keeps nodes in NODE and NBRS/.test(e.message)) || assert.fail(e.message));
  }
});

test('openingRange refuses a bad prologue, an unsupported major version and a bad HEAD frame', () => {
  const bytes = read('sphere.strata');
  const bad = (edit, words, fileLength = bytes.length) => {
    const b = bytes.slice();
    edit(b);
    assert.throws(() => openingRange(b, fileLength), (e) => e instanceof FormatError && words.every((w) => e.message.includes(w)) || assert.fail(e.message));
  };
  bad((b) => (b[0] = 0x88), ['magic']);
  bad((b) => (b[7] = 0x0d), ['magic']);
  const version = (major, minor) => (b) => {
    le(b).setUint16(8, major, true);
    le(b).setUint16(10, minor, true);
    le(b).setUint32(12, crc32(b, 0, 12), true);
  };
  bad(version(5, 0), ['5.0', 'newer', `${NEWEST_MAJOR}.${MINOR4}`]);
  bad(version(65535, 0), ['65535.0', 'newer']);
  bad(version(1, 0), ['1.0', 'not supported']);
  bad((b) => (b[12] ^= 1), ['CRC']);
  bad((b) => (b[16] = 0x68), ['HEAD']);
  bad((b) => le(b).setUint32(24, 65537, true), ['65536']);
  bad((b) => le(b).setUint32(28, 1, true), ['65536']);
  bad((b) => le(b).setUint32(24, 100, true), ['160']);
  bad(() => {}, ['too short'], 10);
  bad(() => {}, ['past the end'], 100);
  bad((b) => (b[40] ^= 1), ['CRC']); // in HEAD's payload
  bad(() => {}, ['truncated or extended'], bytes.length + 8);
  // A newer minor version opens.
  const b = bytes.slice();
  version(2, 7)(b);
  assert.equal(openingRange(b, b.length).skeletonEnd, decodeSkeleton(bytes, bytes.length).skeletonEnd);
});

// ---------------------------------------------------------------------------------------------
// (5) Byte flips

/**
 * The bytes no check of a reader covers: the flags of top-level chunks of kinds that define none
 * (ignored, §4.3; a sub-chunk's frame lies inside its parent's CRC), the padding after each GEOM
 * chunk (a node is read as its `size` bytes, padding excluded) and after ORDR; in format 3, GEOS's
 * frame, CRC and padding (a reader checks each node's payload against the node table's CRC; the
 * GEOS frame and CRC are `strata verify`'s, strata-v3.md §1).
 */
function uncheckedBytes(bytes) {
  const out = new Set();
  for (const c of parseTree(bytes).chunks) {
    if (c.id === 'GEOS') {
      const e = c.at + 16 + c.payload.length;
      for (let k = c.at; k < c.at + 16; k++) out.add(k);
      for (let k = e; k < e + 4 + pad8(e + 4); k++) out.add(k);
      continue;
    }
    if (c.id === 'ORDR') {
      // Its flags are the index width (checked); the padding after it, at the end of the file, is
      // read by no reader.
      const e = c.at + 20 + c.payload.length;
      for (let k = e; k < e + pad8(e); k++) out.add(k);
      continue;
    }
    for (let k = 4; k < 8; k++) out.add(c.at + k);
    if (c.id !== 'GEOM') continue;
    const e = c.at + 20 + c.subs.reduce((n, s) => n + 20 + s.payload.length + pad8(20 + s.payload.length), 0);
    for (let k = e; k < e + pad8(e); k++) out.add(k);
  }
  return out;
}

for (const file of ['sphere.strata', 'sphere-v3.strata', 'sphere-v4.strata'].filter((f) => existsSync(join(VECTORS, f)))) test(`every byte of ${file} flipped: refused with a FormatError, or read only where no check applies`, (t) => {
  const bytes = read(file);
  const free = uncheckedBytes(bytes);
  const original = JSON.stringify(dump(...Object.values(decodeAll(bytes))));
  const accepted = { 0xff: [], 0x01: [] };
  for (const x of [0xff, 0x01]) {
    for (let k = 0; k < bytes.length; k++) {
      const b = bytes.slice();
      b[k] ^= x;
      if (!refused(b, `byte ${k} ^ ${x}`)) {
        accepted[x].push(k);
        assert.ok(free.has(k), `byte ${k} ^ 0x${x.toString(16)} was read although a check covers it`);
        assert.equal(JSON.stringify(dump(...Object.values(decodeAll(b)))), original, `byte ${k}: read, but differently`);
      }
    }
  }
  for (const x of [0xff, 0x01]) assert.deepEqual(accepted[x], [...free].sort((p, q) => p - q), `^0x${x.toString(16)}: exactly the unchecked bytes are read`);
  t.diagnostic(`${bytes.length} bytes × 2 flips (^0xff, ^0x01): read ${accepted[0xff].length} / ${accepted[1].length} (the ${free.size} bytes no check covers: flags of HEAD, SKEL and GEOM, GEOM padding; GEOS's frame, CRC and padding); every other flip refused`);
});

for (const file of ['sphere.strata', 'terrain.strata', 'textured.strata', 'sphere-v3.strata', 'sphere-v4.strata'].filter((f) => existsSync(join(VECTORS, f)))) test(`resealed mutations of ${file} (every checksum recomputed): a FormatError or a sane decode, never another error`, (t) => {
  const bytes = read(file);
  const tree = parseTree(bytes);
  const spots = leaves(tree);
  let tried = 0, accepted = 0;
  // Each edit is made in place and undone: serialize recomputes the checksums from the payloads.
  const attempt = (edit, what) => {
    const payload = edit.spot.get(tree);
    const saved = payload.slice(edit.k, edit.k + 4);
    edit(payload);
    const b = serialize(tree);
    payload.set(saved, edit.k);
    tried++;
    if (!refused(b, what)) {
      accepted++;
      const { sk, geoms } = decodeAll(b);
      if (sk.georef) {
        const g = sk.georef;
        assert.ok(['unplaced', 'local_tangent', 'projected'].includes(g.frame) && g.origin.every(Number.isFinite) && g.zScale > 0 && g.metresPerCrsUnit > 0, what);
      }
      for (const g of geoms) {
        assert.ok(g.positions.every(Number.isFinite) && (!g.uvs || g.uvs.every(Number.isFinite)), what);
        assert.ok(g.indices.every((x) => x < g.positions.length / 3), what);
      }
    }
  };
  for (const s of spots) {
    const n = s.get(tree).length;
    const at = (k, f) => Object.assign(f, { spot: s, k });
    for (let k = 0; k < n; k++) {
      attempt(at(k, (p) => (p[k] ^= 0xff)), `${s.name}[${k}] ^ 0xff`);
    }
    for (let k = 0; k + 4 <= n; k += 4) {
      attempt(at(k, (p) => le(p).setUint32(k, 0xffffffff, true)), `${s.name}[${k}] = u32 max`);
      attempt(at(k, (p) => le(p).setUint32(k, 0x7fffffff, true)), `${s.name}[${k}] = i32 max`);
    }
  }
  t.diagnostic(`${tried} resealed variants of ${file}: ${tried - accepted} refused, ${accepted} read (values a reader cannot tell from honest ones)`);
});

test('hostile counts fail before anything is allocated with them', () => {
  const tree = parseTree(read('sphere.strata'));
  const variant = (edit, totals = true) => {
    const v = clone(tree);
    edit(v);
    return serialize(v, { totals });
  };
  const head = (v) => find(v.chunks, 'HEAD').payload;
  const sub = (v, id) => find(find(v.chunks, 'SKEL').subs, id).payload;
  const refusedWith = (b, words) =>
    assert.throws(() => decodeAll(b), (e) => (e instanceof FormatError && words.every((w) => e.message.includes(w))) || assert.fail(`${e.name}: ${e.message}`));
  refusedWith(variant((v) => le(head(v)).setUint32(48, 0xfffffffe, true)), ['LEVL', 'HEAD says 4294967294']);
  refusedWith(variant((v) => le(head(v)).setUint32(48, 0xffffffff, true)), ['HEAD', 'nodes']);
  refusedWith(variant((v) => le(head(v)).setUint32(44, 0xffffffff, true)), ['HEAD', 'levels']);
  refusedWith(variant((v) => le(head(v)).setUint32(52, 0xffffffff, true)), ['MATL', 'material 2']);
  refusedWith(variant((v) => le(head(v)).setBigUint64(56, 1n << 60n, true)), ['2^53']);
  refusedWith(variant((v) => le(head(v)).setBigUint64(0, 1n << 60n, true), false), ['HEAD says more than 2^53']);
  refusedWith(variant((v) => le(sub(v, 'LEVL')).setBigUint64(24, 1n << 60n, true), false), ['LEVL', '2^53']);
  refusedWith(variant((v) => le(head(v)).setUint32(156, 0xffffffff, true)), ['tool string']);
  refusedWith(variant((v) => le(head(v)).setUint32(156, 100, true)), ['HEAD', 'needs 100 more bytes']);
  refusedWith(variant((v) => le(sub(v, 'MATL')).setUint32(0, 0xffffffff, true)), ['MATL', 'material 0', 'name']);
  // Node 0 claims 2^32 − 1 vertices and faces (LEVL agrees): its geometry is refused by size.
  refusedWith(variant((v) => le(sub(v, 'NODE')).setUint32(44, 0xffffffff, true)), ['node 0', 'VPOS holds']);
  refusedWith(variant((v) => le(sub(v, 'NODE')).setUint32(40, 0xffffffff, true)), ['node 0', 'INDX holds']);
  refusedWith(variant((v) => le(sub(v, 'NODE')).setUint16(2, 0xffff, true)), ['node 0', 'neighbours run past']);
  refusedWith(variant((v) => le(sub(v, 'NODE')).setUint16(0, 0xffff, true)), ['node 0', 'run past level 2']);
  refusedWith(variant((v) => le(sub(v, 'NODE')).setUint32(12 + 4, 0x80000000, true)), ['node 0', 'off the 20-bit grid']);
  refusedWith(variant((v) => (find(find(v.chunks, 'SKEL').subs, 'NBRS').flags = 3)), ['NBRS', 'width 3']);
  refusedWith(variant((v) => (find(v.chunks, 'SKEL').subs = find(v.chunks, 'SKEL').subs.filter((s) => s.id !== 'MATL'))), ['has no MATL']);
  refusedWith(variant((v) => find(v.chunks, 'SKEL').subs.push({ ...find(find(v.chunks, 'SKEL').subs, 'NBRS') })), ['second NBRS']);
  const geom0 = (v) => v.chunks.find((c) => c.id === 'GEOM').subs;
  refusedWith(variant((v) => (find(geom0(v), 'VPOS').flags = 4)), ['node 0', 'position width 4']);
  refusedWith(variant((v) => (find(geom0(v), 'INDX').flags = 3)), ['node 0', 'index width 3']);
  refusedWith(variant((v) => le(find(geom0(v), 'MATR').payload).setUint32(0, 9, true)), ['node 0', 'material range 0']);
  refusedWith(variant((v) => geom0(v).splice(1, 1)), ['node 0', 'lacks a VNRM']);
  refusedWith(variant((v) => geom0(v).push({ id: 'CLUS', flags: 0, payload: new Uint8Array(0) })), ['node 0', 'should not have a CLUS']);
  refusedWith(variant((v) => geom0(v).push({ ...find(geom0(v), 'VTEX') })), ['node 0', 'second VTEX']);
  // A NaN UV passes the structure but not the rules.
  refusedWith(variant((v) => le(find(geom0(v), 'VTEX').payload).setFloat32(4, NaN, true)), ['node 0', 'UV 0 is not finite']);
  // A vertex of the last node (level 0, small) moved outside its box, still on the grid.
  const geomLast = (v) => v.chunks.filter((c) => c.id === 'GEOM').at(-1).subs;
  const toGridEnd = (v) => {
    const vpos = find(geomLast(v), 'VPOS');
    const off = 2 ** 20 - 1 - le(vpos.payload).getUint32(0, true); // vertex 0's x at the last grid point
    for (let k = 0; k < vpos.flags; k++) vpos.payload[12 + k] = (off >>> (8 * k)) & 0xff;
  };
  refusedWith(variant(toGridEnd), ['node 19', "outside the node's box"]);
  // decodeNode with other bytes than the node's.
  const bytes = read('sphere.strata');
  const sk = decodeSkeleton(bytes, bytes.length);
  for (const [i, b] of [
    [0, nodeBytes(sk, 0, bytes).subarray(1)],
    [0, bytes.subarray(sk.offset[1], sk.offset[1] + sk.size[0])],
    [0, new Uint8Array(0)],
    [20, nodeBytes(sk, 0, bytes)],
    [-1, nodeBytes(sk, 0, bytes)],
    [0.5, nodeBytes(sk, 0, bytes)],
  ]) {
    assert.throws(() => decodeNode(sk, i, b), FormatError);
  }
});

// ---------------------------------------------------------------------------------------------
// (6) Truncations and extensions

test('truncations at every length and extensions are refused with a FormatError', () => {
  for (const name of ['plane', 'sphere']) {
    const bytes = read(`${name}.strata`);
    const sk = decodeSkeleton(bytes, bytes.length);
    for (let n = 0; n < bytes.length; n++) {
      const cut = bytes.subarray(0, n);
      assert.throws(() => decodeSkeleton(cut, n), FormatError, `${name} cut at ${n}`);
      // Fewer bytes than the skeleton, of a file of the right length.
      if (n < sk.skeletonEnd) assert.throws(() => decodeSkeleton(cut, bytes.length), FormatError, `${name} prefix ${n}`);
    }
    for (const extra of [1, 7, 8, 4096]) {
      const longer = new Uint8Array(bytes.length + extra);
      longer.set(bytes);
      assert.throws(() => decodeSkeleton(longer, longer.length), /truncated or extended/);
    }
    assert.throws(() => decodeSkeleton(bytes, NaN), FormatError);
    assert.throws(() => decodeSkeleton(bytes, -1), FormatError);
  }
});

// ---------------------------------------------------------------------------------------------
// Versions and unknown chunks (§3, §4.3)

test('a newer minor version is read with what it may add; unknown chunks are skipped', () => {
  const bytes = read('sphere.strata');
  const base = decodeAll(bytes);
  const tree = parseTree(bytes);
  const same = (b, what, minor = base.sk.minor) => {
    const { sk, geoms } = decodeAll(b);
    const a = dump(sk, geoms), e = dump(base.sk, base.geoms);
    e.version = `2.${minor}`;
    // Offsets, sizes and checksums move with inserted chunks; everything else stays.
    for (const d of [a, e]) {
      delete d.header.file_size;
      for (const n of d.nodes) for (const k of ['offset', 'size', 'crc']) delete n[k];
      for (const l of d.levels) delete l.bytes;
    }
    assert.equal(difference(e, a), null, what);
    return sk;
  };
  const variant = (edit) => {
    const v = clone(tree);
    edit(v);
    return serialize(v, { totals: true });
  };
  const unknown = (id, n = 13) => ({ id, flags: 5, payload: new Uint8Array(n).fill(0xab) });
  same(variant((v) => v.chunks.splice(1, 0, unknown('XTRA'), unknown('xtr2', 0))), 'unknown chunks between HEAD and SKEL');
  same(variant((v) => v.chunks.push(unknown('TAIL'))), 'an unknown chunk after the last GEOM');
  same(variant((v) => find(v.chunks, 'SKEL').subs.splice(2, 0, unknown('SKX1'))), 'an unknown sub-chunk in SKEL');
  same(variant((v) => v.chunks.filter((c) => c.id === 'GEOM').forEach((c) => c.subs.splice(1, 0, unknown('GMX1', 3)))), 'unknown sub-chunks in GEOM');
  // A newer minor: unknown attribute bits, fields after the tool string and after the last material.
  const newer = (v) => {
    v.minor = MINOR + 1;
    const h = find(v.chunks, 'HEAD');
    h.payload = concat([h.payload, new Uint8Array(24).fill(7)]);
    le(h.payload).setUint32(40, le(h.payload).getUint32(40, true) | 0x100, true);
    const m = find(find(v.chunks, 'SKEL').subs, 'MATL');
    m.payload = concat([m.payload, new Uint8Array(5).fill(9)]);
  };
  same(variant(newer), `minor ${MINOR + 1} with additions`, MINOR + 1);
  // The same additions in a 2.0 file are errors.
  const b = variant((v) => {
    newer(v);
    v.minor = 0;
  });
  assert.throws(() => decodeAll(b), /unknown attribute bits 0x107/);
  const only = (edit, re) => assert.throws(() => decodeAll(variant((v) => (edit(v), (v.minor = 0)))), re);
  only((v) => (find(v.chunks, 'HEAD').payload = concat([find(v.chunks, 'HEAD').payload, new Uint8Array(8)])), /8 bytes after the tool string/);
  only((v) => {
    const m = find(find(v.chunks, 'SKEL').subs, 'MATL');
    m.payload = concat([m.payload, new Uint8Array(3)]);
  }, /3 bytes after 2 materials/);
  // A known chunk where it is not allowed.
  assert.throws(() => decodeAll(variant((v) => v.chunks.splice(1, 0, { ...v.chunks[0] }))), /expected the SKEL chunk/);
  assert.throws(() => decodeAll(variant((v) => v.chunks.splice(1, 0, clone(v.chunks.find((c) => c.id === 'GEOM'))))), /expected the SKEL chunk/);
  // An unknown chunk between SKEL and node 0's GEOM breaks the back-to-back layout (§2).
  assert.throws(() => decodeAll(variant((v) => v.chunks.splice(2, 0, unknown('GAP1')))), FormatError);
  // Non-zero padding (§4.1).
  const padded = bytes.slice();
  const skelEnd = decodeSkeleton(bytes, bytes.length).skeletonEnd;
  padded[skelEnd - 1] = 1;
  assert.throws(() => decodeSkeleton(padded, padded.length), /padding is not zero/);
});

// ---------------------------------------------------------------------------------------------
// (7) The worked example of spec §9 and plane.strata

/** The bytes of the hex dump of spec §9, offsets checked line by line. */
function specExample() {
  const md = readFileSync(join(ROOT, 'format-spec', 'strata-v2.md'), 'utf8');
  const block = md.split('```hex\n')[1].split('```')[0];
  const out = [];
  for (const line of block.split('\n').filter(Boolean)) {
    const m = /^([0-9a-f]{8})  ([0-9a-f ]+?)\s*\|/.exec(line);
    assert.ok(m, line);
    assert.equal(parseInt(m[1], 16), out.length, line);
    out.push(...m[2].trim().split(/\s+/).map((x) => parseInt(x, 16)));
  }
  return new Uint8Array(out);
}

test('the worked example of spec §9 and plane.strata decode to the values the spec gives', () => {
  const step = 2 ** -19;
  const unitSquare = (sk, g, what) => {
    const h = sk.header;
    assert.equal(h.metresPerUnit, 1, what);
    assert.deepEqual([h.min, h.max], [[0, 0, 0], [1, 1, 0]], what);
    assert.deepEqual(h.attributes, { normals: false, uvs: false, colors: false }, what);
    assert.deepEqual([h.levels, h.nodes, h.materials, h.inputVertices, h.inputFaces, h.clusters], [1, 1, 1, 4, 2, 1], what);
    assert.deepEqual(h.grid, { origin: [0, 0, 0], step, bits: 20 }, what);
    assert.equal(h.levelRatio, 0.5);
    assert.deepEqual(sk.materials, [{ name: 'default', baseColor: [fr(0.8), fr(0.8), fr(0.8), 1], texture: null }], what);
    assert.deepEqual(sk.levels, [{ firstNode: 0, nodes: 1, faces: 2, vertices: 4, bytes: sk.size[0] + ((8 - (sk.size[0] % 8)) % 8) }], what);
    assert.deepEqual([...sk.boxMin, ...sk.boxMax, ...sk.center], [0, 0, 0, 1, 1, 0, 0.5, 0.5, 0], what);
    assert.deepEqual([...sk.coneAxis, sk.coneHalfAngle[0]], [0, 0, 1, 0], what);
    assert.equal(sk.error[0], fr((step * Math.sqrt(3)) / 2), what);
    assert.deepEqual([sk.childCount[0], sk.neighborCount[0], sk.parent[0], sk.faces[0], sk.vertices[0]], [0, 0, 0xffffffff, 2, 4], what);
    assert.equal(sk.offset[0], sk.skeletonEnd, `${what}: GEOM right after SKEL`);
    assert.deepEqual([...g.positions], [0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0], what);
    assert.deepEqual([...g.indices], [0, 1, 2, 0, 2, 3], what);
    assert.deepEqual(g.materialRanges, [[0, 0, 6]], what);
    assert.deepEqual([g.normals, g.uvs, g.colors], [null, null, null], what);
    assert.equal(g.clusters.length, 1, what);
    const c = g.clusters[0];
    assert.deepEqual([c.axis, c.halfAngle, c.center, c.firstFace, c.faceCount], [[0, 0, 1], 0, [0.5, 0.5, 0], 0, 2], what);
  };

  const spec = specExample();
  assert.equal(spec.length, 648);
  assert.equal(crc32(spec, 0, 12), 0x9dac61cd);
  const ex = decodeAll(spec);
  unitSquare(ex.sk, ex.geoms[0], 'spec §9');
  assert.equal(ex.sk.header.tool, 'strata test');
  assert.equal(ex.sk.header.fileSize, 648);
  assert.equal(ex.sk.skeletonEnd, 448);
  assert.deepEqual([ex.sk.offset[0], ex.sk.size[0], ex.sk.crc[0]], [448, 196, 0x4b7f2f50]);
  assert.equal(ex.sk.radius[0], 1537 * 2 ** 8 * step); // 0x4601
  assert.equal(ex.sk.radius[0], 0.75048828125);
  assert.equal(ex.geoms[0].clusters[0].radius, 0.75048828125);
  assert.deepEqual(ex.sk.header.params, {
    cluster_faces: 64,
    cluster_angle: new DataView(new Uint8Array([0xc2, 0xb8, 0x32, 0x3f]).buffer).getFloat32(0, true),
    leaf_faces: 512,
    leaf_angle: new DataView(new Uint8Array([0x36, 0x8d, 0xa7, 0x3f]).buffer).getFloat32(0, true),
    angle_step: new DataView(new Uint8Array([0x92, 0x0a, 0x06, 0x3f]).buffer).getFloat32(0, true),
    growth: 4,
    kc: 1,
    ks: 0.25,
    kn: fr(0.1),
    top_groups: 8,
  });
  assert.deepEqual(openingRange(spec, spec.length), { skeletonEnd: 448, topEnd: 648, pagesEnd: 448 });

  const plane = read('plane.strata');
  const pl = decodeAll(plane);
  unitSquare(pl.sk, pl.geoms[0], 'plane.strata');
  // The vector's sphere is the tight one: √½ times the writer's margin, rounded up to a code.
  assert.ok(pl.sk.radius[0] >= Math.SQRT1_2 && pl.sk.radius[0] < Math.SQRT1_2 * 1.001);
  // opts.localOrigin: positions relative to a point, computed in f64 before the rounding to f32.
  const g = decodeNode(pl.sk, 0, nodeBytes(pl.sk, 0, plane), { localOrigin: [0.5, 0.5, 0] });
  assert.deepEqual([...g.local], [-0.5, -0.5, 0, 0.5, -0.5, 0, 0.5, 0.5, 0, -0.5, 0.5, 0]);
});

// ---------------------------------------------------------------------------------------------
// Format 3 (format-spec/strata-v3.md)

/**
 * A value of strata-v3.md §4.3 as (alphabet, symbol) and raw bits: values 0–3 are symbols; a value
 * of b ≥ 3 bits is symbol 4 + 2(b − 3) + its bit below the leading one, its b − 2 low bits raw.
 */
function putValue(out, alphabet, u) {
  if (u < 4) return out.symbols.push([alphabet, u]);
  const b = 32 - Math.clz32(u);
  out.symbols.push([alphabet, 4 + 2 * (b - 3) + ((u >>> (b - 2)) & 1)]);
  for (let k = b - 3; k >= 0; k--) out.bits.push((u >>> k) & 1);
}
const putSigned = (out, alphabet, v) => putValue(out, alphabet, ((v << 1) ^ (v >> 31)) >>> 0);

/**
 * rANS as §4.1 specifies it, written here from the spec: symbols last to first from the state
 * 2^23, bytes pushed out low first while the state is at least (2^23 >> 11 << 8)·f; then the final
 * state, and everything reversed, so that a reader finds the state first (little-endian).
 */
function ransEncode(symbols, tables) {
  let x = 2 ** 23;
  const out = [];
  for (let k = symbols.length - 1; k >= 0; k--) {
    const [a, s] = symbols[k];
    const f = tables[a][s], c = tables[a].slice(0, s).reduce((p, q) => p + q, 0);
    assert.ok(f > 0, `symbol ${s} of alphabet ${a} has no frequency`);
    while (x >= ((2 ** 23 / 2048) * 256) * f) {
      out.push(x % 256);
      x = Math.floor(x / 256);
    }
    x = Math.floor(x / f) * 2048 + (x % f) + c;
  }
  out.push((x >>> 24) & 255, (x >>> 16) & 255, (x >>> 8) & 255, x & 255);
  return out.reverse();
}

/** A node payload (§5.1): the stream's length (LEB128), the stream, the raw bits (MSB first, zero-padded). */
function payloadBytes(stream, bits) {
  const out = [];
  for (let n = stream.length; ; ) {
    const b = n & 0x7f;
    n >>>= 7;
    out.push(n > 0 ? b | 0x80 : b);
    if (n === 0) break;
  }
  out.push(...stream);
  const raw = new Array(Math.ceil(bits.length / 8)).fill(0);
  bits.forEach((bit, k) => (raw[k >> 3] |= bit << (7 - (k & 7))));
  return new Uint8Array([...out, ...raw]);
}

/** A CODE payload (§3): normal bits, colour bits, reserved, the alphabet count, each alphabet's frequencies. */
function codeBytes(nb, cb, freqs, count = freqs.length) {
  const out = [nb, cb, 0, 0, count & 255, (count >>> 8) & 255, 0, 0];
  for (const f of freqs) out.push(f.length & 255, f.length >>> 8, ...f.flatMap((x) => [x & 255, x >>> 8]));
  return new Uint8Array(out);
}

/**
 * The unit square of strata-v2.md §9 in format 3 (strata-v3.md §7; tests/format3_handmade.rs
 * builds the same file in Rust): the example of v2 §9 with major 3, a CODE chunk of this test's
 * tables, and its GEOM chunk replaced by a GEOS chunk of a payload encoded here from the spec.
 */
function v3Example() {
  const [COUNT, START, CORNER, CONN_FIRST, CONN_AFTER_BOUNDARY, POS_JUMP, POS_BORDER_20] = [11, 8, 9, 7, 5, 13, 42 + 20];
  const tables = Array.from({ length: 64 }, () => []);
  tables[COUNT] = tables[START] = tables[CORNER] = tables[POS_BORDER_20] = [2016, 32];
  tables[CONN_FIRST] = tables[CONN_AFTER_BOUNDARY] = [1024, 0, 0, 0, 0, 1024];
  tables[POS_JUMP] = Array.from({ length: 41 }, (_, s) => ({ 0: 1000, 37: 524, 40: 524 })[s] ?? 0);
  const out = { symbols: [], bits: [] };
  putValue(out, COUNT, 0); // one material range
  putValue(out, COUNT, 0); // material 0
  putValue(out, COUNT, 0); // one cluster
  putValue(out, START, 0); // a new triangle
  for (let k = 0; k < 3; k++) putValue(out, CORNER, 0); // new vertices 0, 1, 2
  out.symbols.push([CONN_FIRST, 5], [CONN_AFTER_BOUNDARY, 5]); // gates 0→1, 1→2: BOUNDARY
  out.symbols.push([CONN_AFTER_BOUNDARY, 0]); // gate 2→0: VERTEX 3, triangle (0, 2, 3)
  // Vertex 0 from the middle of the box (2^18 on x and y), 1 from 0, 2 from 1 (jumps); 3 by the
  // parallelogram 2 + 0 − 1 across the gate, a border vertex of a triangle 2^19 steps wide.
  const [one, half] = [2 ** 19, 2 ** 18];
  const residuals = [[[-half, -half, 0], POS_JUMP], [[one, 0, 0], POS_JUMP], [[0, one, 0], POS_JUMP], [[0, 0, 0], POS_BORDER_20]];
  for (const [r, alphabet] of residuals) for (const v of r) putSigned(out, alphabet, v);
  const payload = payloadBytes(ransEncode(out.symbols, tables), out.bits);
  const tree = parseTree(specExample());
  tree.major = 3;
  tree.minor = MINOR3;
  const skel = find(tree.chunks, 'SKEL');
  skel.subs.push({ id: 'CODE', flags: 0, payload: codeBytes(0, 0, tables) });
  toPages(skel);
  tree.chunks = tree.chunks.filter((c) => c.id !== 'GEOM');
  tree.chunks.push({ id: 'GEOS', flags: 0, payload });
  tree.payloadSizes = [payload.length];
  return { bytes: serialize(tree, { totals: true }), payload };
}

test('the example of strata-v3.md §7, encoded here from the spec, decodes to the unit square; damage to its payload is refused', (t) => {
  const { bytes, payload } = v3Example();
  // The spec quotes the payload: the stream's length, the stream, the raw bits.
  const md = readFileSync(join(ROOT, 'format-spec', 'strata-v3.md'), 'utf8').replace(/\s+/g, ' ');
  const quoted = /payload is \d+ bytes: `([0-9a-f ]+)` \(the symbol stream's length\), the stream `([0-9a-f ]+)`, and the raw bits `([0-9a-f ]+)`/.exec(md);
  assert.ok(quoted, 'strata-v3.md §7 quotes the payload');
  const hexBytes = (b) => Array.from(b, (x) => x.toString(16).padStart(2, '0')).join(' ');
  assert.equal(hexBytes(payload), quoted.slice(1).join(' '));
  const { sk, geoms } = decodeAll(bytes);
  assert.deepEqual([sk.major, sk.minor], [3, MINOR3]);
  const g = geoms[0];
  assert.deepEqual([...g.positions], [0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0]);
  assert.deepEqual([...g.indices], [0, 1, 2, 0, 2, 3]);
  assert.deepEqual(g.materialRanges, [[0, 0, 6]]);
  assert.deepEqual(g.clusters, [{ firstFace: 0, faceCount: 2 }]);
  assert.deepEqual([g.normals, g.uvs, g.colors], [null, null, null]);
  assert.deepEqual([sk.offset[0], sk.size[0]], [sk.skeletonEnd + 16, payload.length]);
  assert.equal(planesOffset(sk), bytes.length);
  // Every bit of the payload flipped, its CRC in the node table and every checksum recomputed:
  // the codec's checks refuse it, or it decodes to a sound node (values no check can tell).
  const tree = parseTree(bytes);
  const geos = find(tree.chunks, 'GEOS');
  let refusedCount = 0, readCount = 0;
  for (let k = 0; k < payload.length; k++) {
    for (let bit = 0; bit < 8; bit++) {
      geos.payload[k] ^= 1 << bit;
      const b = serialize(tree);
      geos.payload[k] ^= 1 << bit;
      if (refused(b, `payload byte ${k} bit ${bit}`)) refusedCount++;
      else {
        readCount++;
        const d = decodeAll(b).geoms[0];
        assert.ok(d.positions.length === 12 && d.indices.every((i) => i < 4), `payload byte ${k} bit ${bit}`);
      }
    }
  }
  t.diagnostic(`${payload.length} payload bytes × 8 bits flipped and resealed: ${refusedCount} refused, ${readCount} read (raw bits of residuals the codec cannot check)`);
  assert.ok(refusedCount > readCount);
});

test('format 3: a node of many faces in few bytes decodes (the work bounded by its bytes, the decoder growing as faces come)', () => {
  // A fan of N triangles around vertex 0, every vertex at the middle of the box (the unit square
  // of v2 §9): symbols of frequency 2016 cost 1/44 bit, so N faces take some N/20 bytes, past the
  // decoder's first guess of 16 faces a byte.
  const N = 100000;
  const [COUNT, START, CORNER, CONN_FIRST, CONN_AFTER_VERTEX, POS_JUMP, POS_INNER_0, POS_BORDER_0] = [11, 8, 9, 7, 0, 13, 20, 42];
  const tables = Array.from({ length: 64 }, () => []);
  for (const a of [COUNT, START, CORNER, CONN_FIRST, CONN_AFTER_VERTEX, POS_JUMP, POS_INNER_0, POS_BORDER_0]) tables[a] = [2016, 32];
  const out = { symbols: [], bits: [] };
  for (let k = 0; k < 4; k++) putValue(out, [COUNT, COUNT, COUNT, START][k], 0);
  for (let k = 0; k < 3; k++) putValue(out, CORNER, 0);
  out.symbols.push([CONN_FIRST, 0]);
  for (let f = 2; f < N; f++) out.symbols.push([CONN_AFTER_VERTEX, 0]);
  // Vertices 0–2 jump (from the box's middle, then the vertex before); the others come across a
  // gate whose triangle spans nothing: POS_INNER + 0 or POS_BORDER + 0 (symbol 0 is residual 0 in
  // both, whichever a vertex is).
  for (let v = 0; v < N + 2; v++) for (let k = 0; k < 3; k++) out.symbols.push([v < 3 ? POS_JUMP : POS_INNER_0, 0]);
  const payload = payloadBytes(ransEncode(out.symbols, tables), out.bits);
  const tree = parseTree(specExample());
  tree.major = 3;
  tree.minor = MINOR3;
  find(tree.chunks, 'SKEL').subs.push({ id: 'CODE', flags: 0, payload: codeBytes(0, 0, tables) });
  toPages(find(tree.chunks, 'SKEL'));
  const [node] = recordOf(find(tree.chunks, 'SKEL'), 0);
  node.setUint32(40, N, true);
  node.setUint32(44, N + 2, true);
  le(find(tree.chunks, 'HEAD').payload).setBigUint64(64, BigInt(N), true);
  tree.chunks = tree.chunks.filter((c) => c.id !== 'GEOM');
  tree.chunks.push({ id: 'GEOS', flags: 0, payload });
  tree.payloadSizes = [payload.length];
  const bytes = serialize(tree, { totals: true });
  assert.ok(N > 16 * payload.length + 256, `${payload.length} bytes for ${N} faces`);
  const { geoms } = decodeAll(bytes);
  const g = geoms[0];
  assert.equal(g.indices.length, 3 * N);
  assert.deepEqual([...g.indices.subarray(0, 9)], [0, 1, 2, 1, 0, 3, 3, 0, 4]);
  assert.deepEqual([...g.indices.subarray(3 * N - 3)], [N, 0, N + 1]);
  assert.ok(g.positions.length === 3 * (N + 2) && g.positions.every((c, k) => c === [0.5, 0.5, 0][k % 3]));
  // Claiming more faces than the bytes can hold is refused before any work.
  const most = 353 * (payload.length + 4);
  node.setUint32(40, most + 1, true);
  le(find(tree.chunks, 'HEAD').payload).setBigUint64(64, BigInt(most + 1), true);
  assert.throws(() => decodeAll(serialize(tree, { totals: true })), (e) => (e instanceof FormatError && /node 0.*cannot fit/.test(e.message)) || assert.fail(e.message));
});

test('format 3: the CODE chunk is required and checked as strata checks it; a 2.x file ignores one', () => {
  const bytes = read('sphere-v3.strata');
  const tree = parseTree(bytes);
  const { freqs } = decodeSkeleton(bytes, bytes.length).code;
  const variant = (edit) => {
    const v = clone(tree);
    edit(v, find(v.chunks, 'SKEL').subs);
    return serialize(v, { totals: true });
  };
  const setCode = (subs, payload) => (find(subs, 'CODE').payload = payload);
  const refusedWith = (b, words) =>
    assert.throws(() => decodeAll(b), (e) => (e instanceof FormatError && words.every((w) => e.message.includes(w))) || assert.fail(`${e.name}: ${e.message}, not ${words}`));
  const withFreqs = (k, f) => freqs.map((x, j) => (j === k ? f : x));
  refusedWith(variant((v, subs) => subs.splice(subs.findIndex((c) => c.id === 'CODE'), 1)), ['SKEL', 'has no CODE']);
  refusedWith(variant((v, subs) => subs.splice(subs.findIndex((c) => c.id === 'CODE'), 0, { ...find(subs, 'CODE') })), ['SKEL', 'second CODE']);
  // The node pages come last, one per level, top first, and nothing else holds node records.
  refusedWith(variant((v, subs) => subs.push({ ...find(subs, 'CODE') })), ['SKEL', 'CODE chunk after the node pages']);
  refusedWith(variant((v, subs) => subs.pop()), ['SKEL', 'node pages (NODL) for']);
  refusedWith(variant((v, subs) => subs.push({ ...subs[subs.length - 1] })), ['SKEL', 'node pages (NODL) for']);
  refusedWith(variant((v, subs) => subs.splice(subs.findIndex((c) => c.id === 'CODE'), 0, { id: 'NODE', flags: 0, payload: new Uint8Array(56) })), ['SKEL', 'holds a NODE chunk']);
  refusedWith(variant((v, subs) => (subs.find((c) => c.id === 'NODL').flags = 3)), ['NODL', 'entry width 3']);
  refusedWith(
    variant((v, subs) => {
      const p = subs.find((c) => c.id === 'NODL');
      p.payload = concat([p.payload, new Uint8Array(p.flags)]);
    }),
    ['NODL', 'neighbour entries, the level']
  );
  refusedWith(
    variant((v, subs) => {
      const p = subs.find((c) => c.id === 'NODL');
      p.payload = p.payload.slice(0, p.payload.length - 1);
    }),
    ['NODL', 'do not fill it']
  );
  // Two pages swapped: the levels' record counts no longer fit them.
  refusedWith(
    variant((v, subs) => {
      const k = subs.findIndex((c) => c.id === 'NODL');
      [subs[k], subs[k + 1]] = [subs[k + 1], subs[k]];
    }),
    ['NODL']
  );
  for (const nb of [0, 1, 17]) refusedWith(variant((v, subs) => setCode(subs, codeBytes(nb, 8, freqs))), ['CODE', `normal bits ${nb}`]);
  for (const cb of [0, 9]) refusedWith(variant((v, subs) => setCode(subs, codeBytes(8, cb, freqs))), ['CODE', `colour bits ${cb}`]);
  refusedWith(variant((v, subs) => (find(subs, 'CODE').payload[3] = 1)), ['CODE', 'reserved']);
  refusedWith(variant((v, subs) => setCode(subs, codeBytes(8, 8, freqs, 63))), ['CODE', '63 alphabets']);
  refusedWith(variant((v, subs) => setCode(subs, codeBytes(8, 8, freqs.slice(0, 63), 64))), ['CODE', 'ends early']);
  refusedWith(variant((v, subs) => setCode(subs, new Uint8Array([...codeBytes(8, 8, freqs), 0, 0]))), ['CODE', '2 bytes after the last alphabet']);
  refusedWith(variant((v, subs) => setCode(subs, codeBytes(8, 8, withFreqs(11, [2016, 31])))), ['CODE', 'alphabet 11 (count)', 'add up to 2047']);
  refusedWith(variant((v, subs) => setCode(subs, codeBytes(8, 8, withFreqs(12, [2017, 31])))), ['CODE', 'alphabet 12 (shift)', 'more than 2016']);
  refusedWith(variant((v, subs) => setCode(subs, codeBytes(8, 8, withFreqs(30, [...new Array(256).fill(8), 0])))), ['CODE', 'alphabet 30 (pos/inner/10)', '257 symbols']);
  refusedWith(variant((v, subs) => setCode(subs, codeBytes(8, 8, withFreqs(13, [0, 0])))), ['CODE', 'alphabet 13 (pos/jump)', 'add up to 0']);
  // An alphabet without symbols opens, but a node that needs it is refused.
  refusedWith(variant((v, subs) => setCode(subs, codeBytes(8, 8, withFreqs(11, [])))), ['node 0', 'alphabet count', 'not a value']);
  // A file without normals has normal bits 0.
  const plane = parseTree(read('plane-v3.strata'));
  find(find(plane.chunks, 'SKEL').subs, 'CODE').payload[0] = 8;
  refusedWith(serialize(plane), ['CODE', 'normal bits 8', 'has no normals']);
  // A 2.x file's CODE chunk is no concern of its reader.
  const v2 = parseTree(read('sphere.strata'));
  find(v2.chunks, 'SKEL').subs.push({ ...find(find(tree.chunks, 'SKEL').subs, 'CODE') });
  const b = serialize(v2, { totals: true });
  const base = decodeAll(read('sphere.strata'));
  const a = decodeAll(b);
  assert.equal(a.sk.code, null);
  assert.deepEqual(a.geoms, base.geoms);
});

test('format 3: versions, layout, hostile counts and damaged payloads are refused with a FormatError naming the node', () => {
  const bytes = read('sphere-v3.strata');
  const tree = parseTree(bytes);
  const base = decodeAll(bytes);
  const variant = (edit, totals = true) => {
    const v = clone(tree);
    edit(v);
    return serialize(v, { totals });
  };
  const refusedWith = (b, words) =>
    assert.throws(() => decodeAll(b), (e) => (e instanceof FormatError && words.every((w) => e.message.includes(w))) || assert.fail(`${e.name}: ${e.message}, not ${words}`));
  const head = (v) => find(v.chunks, 'HEAD').payload;
  const node = (v) => recordOf(find(v.chunks, 'SKEL'), 0)[0];
  // A newer minor of 3 reads as 3.0 does, with what it may add; 3.0 refuses the additions; 5.x is refused.
  const newer = (minor) => (v) => {
    v.minor = minor;
    const h = find(v.chunks, 'HEAD');
    h.payload = concat([h.payload, new Uint8Array(8).fill(7)]);
    le(h.payload).setUint32(40, le(h.payload).getUint32(40, true) | 0x100, true);
  };
  const n = decodeAll(variant(newer(MINOR3 + 1)));
  assert.equal(`${n.sk.major}.${n.sk.minor}`, `3.${MINOR3 + 1}`);
  assert.deepEqual(n.geoms, base.geoms);
  refusedWith(variant(newer(MINOR3)), ['unknown attribute bits']);
  refusedWith(variant((v) => (v.major = 5)), [`format version 5.${MINOR3}`, 'newer']);
  // GEOS before SKEL; a node of no bytes; a payload longer than its stream and raw bits.
  refusedWith(variant((v) => v.chunks.splice(1, 0, find(v.chunks, 'GEOS'))), ['GEOS', 'expected the SKEL chunk']);
  const sizes = tree.payloadSizes;
  refusedWith(
    variant((v) => {
      find(v.chunks, 'GEOS').payload = find(v.chunks, 'GEOS').payload.slice(sizes[0]);
      v.payloadSizes = [0, ...sizes.slice(1)];
    }),
    ['node 0', 'geometry 0 bytes'],
  );
  refusedWith(
    variant((v) => {
      const g = find(v.chunks, 'GEOS').payload;
      find(v.chunks, 'GEOS').payload = concat([g.subarray(0, sizes[0]), new Uint8Array(1), g.subarray(sizes[0])]);
      v.payloadSizes = [sizes[0] + 1, ...sizes.slice(1)];
    }),
    ['node 0', 'raw bits end at byte'],
  );
  // The stream's length: more than 10 bytes, or past the payload.
  const payload0 = (edit) => (v) => {
    const g = find(v.chunks, 'GEOS').payload;
    const p = g.slice(0, sizes[0]);
    edit(p);
    g.set(p);
  };
  refusedWith(variant(payload0((p) => p.fill(0x80, 0, 10))), ['node 0', 'past 10 bytes']);
  refusedWith(variant(payload0((p) => (p[0] = 0x7f))), ['node 0', 'runs past the payload']);
  // Counts a payload cannot hold are refused before anything is allocated with them.
  refusedWith(variant((v) => node(v).setUint32(40, 0xffffffff, true)), ['node 0', '4294967295 faces', 'cannot fit']);
  refusedWith(variant((v) => node(v).setUint32(44, 3 * node(v).getUint32(40, true) + 1, true)), ['node 0', 'cannot fit']);
  refusedWith(variant((v) => node(v).setUint32(44, node(v).getUint32(44, true) + 1, true)), ['node 0', 'the node record says']);
  // A vertex off the node's box, decoded from a payload the codec accepts, is refused by the rules.
  const damaged = read('refused-v3-damaged-payload.strata');
  refusedWith(damaged, ['node 0', "outside the node's box"]);
  // decodeNode with other bytes than the node's.
  const sk = decodeSkeleton(bytes, bytes.length);
  for (const [i, b] of [
    [0, nodeBytes(sk, 0, bytes).subarray(1)],
    [0, bytes.subarray(sk.offset[1], sk.offset[1] + sk.size[0])],
    [0, new Uint8Array(0)],
    [1, nodeBytes(sk, 0, bytes)],
  ]) {
    assert.throws(() => decodeNode(sk, i, b), (e) => (e instanceof FormatError && e.node === i && /GEOS/.test(e.message)) || assert.fail(e.message));
  }
  assert.ok(head(tree).length > 0);
});

test('opts.localOrigin keeps precision far from the origin', (t) => {
  // The sphere moved by 2^20 on every axis: the grid origin shifts (exactly, in f64), grid points stay.
  const far0 = 2 ** 20;
  const tree = parseTree(read('sphere.strata'));
  const d = le(find(tree.chunks, 'HEAD').payload);
  for (let k = 0; k < 3; k++) {
    d.setFloat64(120 + 8 * k, d.getFloat64(120 + 8 * k, true) + far0, true);
    // Bounds widened to hold the rounded positions (an f32 step is 1/8 at 2^20).
    d.setFloat32(16 + 4 * k, d.getFloat32(16 + 4 * k, true) + far0 - 1, true);
    d.setFloat32(28 + 4 * k, d.getFloat32(28 + 4 * k, true) + far0 + 1, true);
  }
  const far = serialize(tree, { totals: true });
  const near = decodeAll(read('sphere.strata'));
  const sk = decodeSkeleton(far, far.length);
  let decoded = 0;
  for (let i = 0; i < sk.nodeCount; i++) {
    let g;
    try {
      g = decodeNode(sk, i, nodeBytes(sk, i, far), { localOrigin: [far0, far0, far0] });
    } catch (e) {
      // The rules are checked on the absolute positions, rounded to f32 steps of 1/8 here: the
      // tight spheres and cones of small nodes no longer hold them.
      assert.ok(e instanceof FormatError, String(e));
      continue;
    }
    decoded++;
    const exact = near.geoms[i].positions;
    assert.ok(!g.local.every((x, k) => x === g.positions[k] - far0), 'the absolute positions have lost precision');
    for (let k = 0; k < exact.length; k++) {
      assert.equal(g.local[k], exact[k], `node ${i} coordinate ${k}: local = the position near 0, bit for bit`);
      assert.ok(Math.abs(g.positions[k] - far0 - exact[k]) <= 1 / 16, 'the absolute position is the f32 nearest');
    }
  }
  assert.ok(decoded >= 1, 'some node decodes');
  t.diagnostic(`${decoded} of ${sk.nodeCount} nodes of the moved sphere decode; their local positions equal the unmoved ones`);
});

// ---------------------------------------------------------------------------------------------
// Files strata converts, against `strata inspect --json`

// The strata binary: STRATA_BIN (cargo test passes its own), else the release build. The CT head
// (566,027 faces) is converted only by a release build, in a few seconds.
const BIN = process.env.STRATA_BIN || join(ROOT, 'target', 'release', 'strata');
const RELEASE = BIN.split(/[\\/]/).includes('release');
const CTHEAD = join(ROOT, '..', 'shared', 'meshes', 'large', 'cthead_skin_native.ply');

function inspectJson(path, args = []) {
  return JSON.parse(execFileSync(BIN, ['inspect', '--json', ...args, path], { encoding: 'utf8', maxBuffer: 1 << 28 }));
}

/** Compare a decoded skeleton with what `strata inspect --json --depth L` prints. */
function compareWithInspect(sk, path) {
  const ins = inspectJson(path, ['--depth', String(sk.header.levels)]);
  const h = sk.header;
  const header = {
    file_size: h.fileSize,
    metres_per_unit: h.metresPerUnit,
    min: h.min,
    max: h.max,
    attributes: h.attributes,
    levels: h.levels,
    nodes: h.nodes,
    materials: sk.materials.map((m) => m.name),
    input_vertices: h.inputVertices,
    input_faces: h.inputFaces,
    clusters: h.clusters,
    params: h.params,
    grid: h.grid,
    level_ratio: h.levelRatio,
    tool: h.tool,
  };
  const deg = (rad) => fr(rad * fr(57.29577951308232));
  assert.equal(ins.version, `${sk.major}.${sk.minor}`);
  assert.equal(difference(ins.header, header, 'header'), null);
  const skel = ins.chunks.find((c) => c.id === 'SKEL');
  const e = skel.offset + 20 + skel.size;
  assert.equal(e + ((8 - (e % 8)) % 8), sk.skeletonEnd);
  const levels = sk.levels.map((l, k) => {
    const [a, b] = sk.levelNodes(k);
    let coneMax = 0, errMax = 0;
    for (let i = a; i < b; i++) [coneMax, errMax] = [Math.max(coneMax, deg(sk.coneHalfAngle[i])), Math.max(errMax, sk.error[i])];
    return { level: k, nodes: l.nodes, faces: l.faces, vertices: l.vertices, bytes: l.bytes, start: sk.offset[a], end: sk.offset[a] + l.bytes, cone_deg_max: coneMax, error_max: errMax };
  });
  assert.equal(difference(ins.levels, levels, 'levels'), null);
  assert.equal(ins.nodes.length, sk.nodeCount);
  for (const n of ins.nodes) {
    const i = n.node;
    const [c0, c1] = sk.children(i);
    const mine = {
      node: i,
      depth: n.depth,
      level: sk.level[i],
      parent: sk.parent[i] === 0xffffffff ? null : sk.parent[i],
      children: Array.from({ length: c1 - c0 }, (_, k) => c0 + k),
      neighbors: sk.neighbors(i).length,
      faces: sk.faces[i],
      vertices: sk.vertices[i],
      cone_deg: deg(sk.coneHalfAngle[i]),
      radius: sk.radius[i],
      error: sk.error[i],
      offset: sk.offset[i],
      bytes: sk.size[i],
      chunks: [],
    };
    assert.equal(difference(n, mine, `node ${i}`), null);
  }
}

const noBinary = !existsSync(BIN) && `skipping: no strata binary at ${BIN} (cargo build --release, or set STRATA_BIN)`;

test('files strata converts agree with `strata inspect --json`, and every node decodes', { skip: noBinary }, (t) => {
  const dir = mkdtempSync(join(process.env.STRATA_TEST_DIR || tmpdir(), 'strata-js-'));
  try {
    const inputs = ['icosphere.obj', 'colored_sphere.ply', 'two_materials.glb', 'cad_part.obj', 'noisy_sphere.ply'].map((f) => join(ROOT, 'fixtures', f));
    if (!existsSync(CTHEAD)) t.diagnostic(`skipping the CT head: ${CTHEAD} not found`);
    else if (!RELEASE) t.diagnostic(`skipping the CT head: ${BIN} is not a release build`);
    else inputs.push(CTHEAD);
    // Both formats, whatever convert's default: 2.x, and 3.0 with compressed node geometry.
    for (const [input, version] of inputs.filter(existsSync).flatMap((f) => [[f, '2'], [f, '3']])) {
      const out = join(dir, input.split('/').pop().replace(/\.\w+$/, `-v${version}.strata`));
      execFileSync(BIN, ['convert', '-q', '--format-version', version, input, out], { stdio: 'ignore' });
      const bytes = new Uint8Array(readFileSync(out));
      let t0 = performance.now();
      const sk = decodeSkeleton(bytes, bytes.length);
      const skelMs = performance.now() - t0;
      compareWithInspect(sk, out);
      const r = openingRange(bytes.subarray(0, Math.min(bytes.length, 65536)), bytes.length);
      if (r.need === undefined) {
        assert.equal(r.skeletonEnd, sk.skeletonEnd);
        // The top level's nodes come first: from node 0's offset (format 3: inside GEOS).
        if (r.topEnd !== undefined) assert.equal(r.topEnd, sk.offset[0] + sk.levels[sk.top()].bytes);
      }
      // Every node, three times: the best pass is reported (the first warms the JIT).
      let ms = Infinity, faces = 0;
      for (let pass = 0; pass < 3; pass++) {
        t0 = performance.now();
        for (let i = 0; i < sk.nodeCount; i++) {
          const g = decodeNode(sk, i, nodeBytes(sk, i, bytes));
          if (pass === 0) {
            assert.equal(g.positions.length, 3 * sk.vertices[i]);
            assert.equal(g.indices.length, 3 * sk.faces[i]);
            assert.equal(!!g.normals, sk.header.attributes.normals);
            faces += sk.faces[i];
          }
        }
        ms = Math.min(ms, performance.now() - t0);
      }
      const geomBytes = bytes.length - sk.skeletonEnd;
      t.diagnostic(
        `${input.split('/').pop()}, format ${sk.major}.${sk.minor}: ${bytes.length} bytes, ${sk.nodeCount} nodes, ${sk.levels.length} levels, ${faces} faces; ` +
          `skeleton ${sk.skeletonEnd} bytes in ${skelMs.toFixed(1)} ms; ` +
          `nodes in ${ms.toFixed(0)} ms: ${Math.round(sk.nodeCount / (ms / 1000))} nodes/s, ${(geomBytes / 1e6 / (ms / 1000)).toFixed(0)} MB/s, ` +
          `${((faces / 1e6) / (ms / 1000)).toFixed(1)} M faces/s`,
      );
      if (input === CTHEAD && version === '2') {
        t0 = performance.now();
        for (let k = 0; k < 5; k++) crc32(bytes);
        t.diagnostic(`crc32: ${((5 * bytes.length) / 1e6 / ((performance.now() - t0) / 1000)).toFixed(0)} MB/s`);
      }
    }
  } finally {
    rmSync(dir, { recursive: true, force: true });
  }
});

test('a prefix whose node counts SKEL could not hold is refused before anything is sized by them', () => {
  const file = read('sphere-v3.strata');
  const dv = (b) => new DataView(b.buffer, b.byteOffset, b.byteLength);
  const headSize = Number(dv(file).getBigUint64(24, true));
  const skel = 32 + headSize + 4 + ((8 - ((32 + headSize + 4) % 8)) % 8);
  assert.equal(String.fromCharCode(...file.subarray(skel, skel + 4)), 'SKEL');
  const levl = skel + 16;
  assert.equal(String.fromCharCode(...file.subarray(levl, levl + 4)), 'LEVL');
  const levlSize = Number(dv(file).getBigUint64(levl + 8, true));
  for (const extra of [50_000_000, 2 ** 32 - 2 - dv(file).getUint32(32 + 48, true)]) {
    const b = file.slice();
    const v = dv(b);
    // HEAD's node count and level 0's (LEVL's first record), each chunk's CRC made right; SKEL's
    // own CRC, which a prefix reader checks only with the rest, left as it was.
    v.setUint32(32 + 48, v.getUint32(32 + 48, true) + extra, true);
    v.setUint32(32 + headSize, crc32(b, 32, 32 + headSize), true);
    v.setUint32(levl + 16 + 4, v.getUint32(levl + 16 + 4, true) + extra, true);
    v.setUint32(levl + 16 + levlSize, crc32(b, levl + 16, levl + 16 + levlSize), true);
    const r = openingRange(b.subarray(0, 16384), b.length);
    assert.ok(r.pagesEnd < r.skeletonEnd, 'a prefix');
    assert.throws(() => decodeSkeleton(b.slice(0, r.pagesEnd), b.length, { topFirst: true }), (e) => e instanceof FormatError && /bytes of node records; SKEL holds/.test(e.message));
    assert.throws(() => decodeSkeleton(b, b.length), (e) => e instanceof FormatError);
  }
});

test('a completed skeleton lets go of the bytes it was decoded from', async () => {
  const v8 = await import('node:v8');
  v8.setFlagsFromString('--expose-gc');
  const gc = (await import('node:vm')).runInNewContext('gc');
  const file = read('sphere-v3.strata');
  const refs = [];
  const keep = (() => {
    const r = openingRange(file.subarray(0, 16384), file.length);
    const prefix = file.slice(0, r.pagesEnd), whole = file.slice(0, r.skeletonEnd);
    refs.push(new WeakRef(prefix.buffer), new WeakRef(whole.buffer));
    const sk = decodeSkeleton(prefix, file.length, { topFirst: true });
    completeSkeleton(sk, whole);
    return sk;
  })();
  await new Promise((r) => setImmediate(r));
  gc();
  assert.equal(keep.decoded, keep.nodeCount);
  assert.deepEqual(refs.map((r) => r.deref() === undefined), [true, true], 'both buffers collected');
});
