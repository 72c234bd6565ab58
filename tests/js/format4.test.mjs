// Format 4 (format-spec/strata-v4.md) in the viewer's reader (viewer/format.js): files strata
// converts with --dag read as the DAG their pages describe, against `strata inspect --json`, an
// independent walk of the pages and the rules of v4 §2 that `strata verify` checks; top first as
// whole; damaged and resealed pages are refused with a FormatError or leave the DAG as it was.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import { existsSync, readFileSync, writeFileSync } from 'node:fs';
import { spawnSync } from 'node:child_process';
import { FormatError, crc32, completeSkeleton, decodeNode, decodePlanes, decodeSkeleton, openingRange, planesOffset } from '../../viewer/format.js';
import { root, converted, run, scratch, strataBin } from './helpers.mjs';

const NONE = 0xffffffff;
const fr = Math.fround;
const BUNNY = `${root}/../shared/meshes/scans/stanford_bun_zipper.ply`;

/** `mesh` (a fixture, or a path) converted to format 4. */
function dagFile(name, mesh, args = []) {
  return converted(`${name}_dag`, mesh.includes('/') ? mesh : `${root}/fixtures/${mesh}`, ['--dag', ...args]);
}

const readBytes = (path) => new Uint8Array(readFileSync(path));
const le = (b) => new DataView(b.buffer, b.byteOffset, b.byteLength);
const ascii = (b, o) => String.fromCharCode(b[o], b[o + 1], b[o + 2], b[o + 3]);
const pad8 = (n) => (8 - (n % 8)) % 8;

/** Top-level chunks `{id, at, size}` of a file, and SKEL's sub-chunks (`subs`, payload offsets `ps`). */
function chunks(b) {
  const out = [];
  for (let pos = 16; pos + 20 <= b.length; ) {
    const size = Number(le(b).getBigUint64(pos + 8, true));
    const c = { id: ascii(b, pos), at: pos, ps: pos + 16, size };
    if (c.id === 'SKEL') {
      c.subs = [];
      for (let s = c.ps; s < c.ps + size; ) {
        const n = Number(le(b).getBigUint64(s + 8, true));
        c.subs.push({ id: ascii(b, s), at: s, ps: s + 16, size: n });
        s += 20 + n + pad8(20 + n);
      }
    }
    out.push(c);
    pos += 20 + size + pad8(20 + size);
  }
  return out;
}

/** Every CRC of SKEL's sub-chunks and of the top-level chunks recomputed after an edit. */
function reseal(b) {
  for (const c of chunks(b)) {
    for (const s of c.subs ?? []) le(b).setUint32(s.ps + s.size, crc32(b, s.ps, s.ps + s.size), true);
    le(b).setUint32(c.ps + c.size, crc32(b, c.ps, c.ps + c.size), true);
  }
  return b;
}

/** The NODL pages' payload offsets and sizes, top level first. */
function pages(b) {
  return chunks(b).find((c) => c.id === 'SKEL').subs.filter((s) => s.id === 'NODL');
}

/** The DAG of a format-4 file read from its pages by strata-v4.md §1 alone, without checks. */
function walkPages(b) {
  const skel = chunks(b).find((c) => c.id === 'SKEL');
  const levl = skel.subs.find((s) => s.id === 'LEVL');
  const L = levl.size / 32;
  const d = le(b);
  const level = (l) => ({ first: d.getUint32(levl.ps + 32 * l, true), nodes: d.getUint32(levl.ps + 32 * l + 4, true) });
  const headAt = 32;
  const grid = { origin: [0, 1, 2].map((k) => d.getFloat64(headAt + 120 + 8 * k, true)), step: d.getFloat64(headAt + 144, true) };
  const decodePoint = (at) => {
    const v = d.getBigUint64(at, true);
    return [0n, 21n, 42n].map((s, k) => fr(grid.origin[k] + Number((v >> s) & 0x1fffffn) * grid.step));
  };
  const groups = [], consumerStored = [], levelGroups = [];
  skel.subs.filter((s) => s.id === 'NODL').forEach((p, k) => {
    const l = L - 1 - k, lev = level(l);
    const G = d.getUint32(p.ps, true);
    levelGroups[l] = [groups.length, groups.length + G];
    let next = lev.first;
    for (let q = 0; q < G; q++) {
      const at = p.ps + 4 + 24 * q;
      const code = d.getUint16(at + 12, true);
      groups.push({
        level: l,
        firstOutput: next,
        outputs: d.getUint32(at, true),
        children: d.getUint32(at + 4, true),
        error: d.getFloat32(at + 8, true),
        radius: fr((code & 0x7ff) * 2 ** (code >> 11) * grid.step),
        center: decodePoint(at + 16),
      });
      next += d.getUint32(at, true);
    }
    for (let i = 0; i < lev.nodes; i++) consumerStored[lev.first + i] = d.getUint32(p.ps + 4 + 24 * G + 56 * i, true);
  });
  const N = consumerStored.length;
  const levelOf = [];
  for (let l = 0; l < L; l++) for (let i = 0, lev = level(l); i < lev.nodes; i++) levelOf[lev.first + i] = l;
  const consumer = consumerStored.map((c, i) => (c === NONE ? NONE : levelGroups[levelOf[i] + 1][0] + c));
  const source = new Array(N).fill(NONE);
  groups.forEach((g, q) => source.fill(q, g.firstOutput, g.firstOutput + g.outputs));
  const children = groups.map((_, q) => consumer.flatMap((c, i) => (c === q ? [i] : [])));
  return { groups, consumer, source, children, levelGroups };
}

/** The DAG `sk.dag` decoded, as walkPages gives it. */
function dagOf(sk) {
  const d = sk.dag, g = d.groups;
  return {
    groups: Array.from({ length: d.groupCount }, (_, q) => ({
      level: g.level[q],
      firstOutput: g.firstOutput[q],
      outputs: g.outputs[q],
      children: g.children[q],
      error: g.error[q],
      radius: g.radius[q],
      center: Array.from(g.center.subarray(3 * q, 3 * q + 3)),
    })),
    consumer: Array.from(d.consumer),
    source: Array.from(d.source),
    children: Array.from({ length: d.groupCount }, (_, q) => Array.from(d.childrenOf(q))),
    levelGroups: d.levelGroups,
  };
}

/** The DAG's structure alone: what no damaged page may change unnoticed. */
function structure(sk) {
  const { groups, consumer, source, children, levelGroups } = dagOf(sk);
  return { groups: groups.map((g) => [g.level, g.firstOutput, g.outputs, g.children]), consumer, source, children, levelGroups };
}

/** The rules of strata-v4.md §2 on the decoded DAG (rules::dag): problems found, as text. */
function dagRules(sk) {
  const d = sk.dag, g = d.groups, out = [];
  const holds = (a, r, b, s) => Math.hypot(g.center[3 * a] - b[0], g.center[3 * a + 1] - b[1], g.center[3 * a + 2] - b[2]) + s <= r * (1 + 1e-5) + 1e-30;
  for (let i = 0; i < sk.nodeCount; i++) {
    const s = d.source[i];
    if ((s === NONE) !== (sk.level[i] === 0)) out.push(`node ${i}: source ${s} at level ${sk.level[i]}`);
    if (s !== NONE && g.error[s] !== sk.error[i]) out.push(`node ${i}: error ${sk.error[i]} is not its source group ${s}'s ${g.error[s]}`);
    if ((d.consumer[i] === NONE) !== (sk.level[i] === sk.top())) out.push(`node ${i}: consumer ${d.consumer[i]} at level ${sk.level[i]}`);
  }
  for (let q = 0; q < d.groupCount; q++) {
    const kids = d.childrenOf(q);
    if (kids.length !== g.children[q] || kids.length === 0) out.push(`group ${q}: ${kids.length} children, ${g.children[q]} stored`);
    for (const c of kids) {
      if (sk.level[c] !== g.level[q] - 1 || d.consumer[c] !== q) out.push(`group ${q}: child ${c} of level ${sk.level[c]}`);
      if (sk.error[c] > g.error[q]) out.push(`group ${q}: error ${g.error[q]} is smaller than child ${c}'s ${sk.error[c]}`);
      if (!holds(q, g.radius[q], sk.center.subarray(3 * c, 3 * c + 3), sk.radius[c])) out.push(`group ${q}: sphere does not contain child ${c}'s`);
      const s = d.source[c];
      if (s !== NONE && !holds(q, g.radius[q], g.center.subarray(3 * s, 3 * s + 3), g.radius[s])) {
        out.push(`group ${q}: sphere does not contain the sphere of child ${c}'s source group ${s}`);
      }
    }
    const [o0, o1] = d.outputsOf(q);
    for (let o = o0; o < o1; o++) if (d.source[o] !== q || sk.level[o] !== g.level[q]) out.push(`group ${q}: output ${o}`);
  }
  return out;
}

/** The skeleton as the viewer opens it: from the prefix openingRange names, top first, then completed. */
function topFirst(bytes) {
  const r = openingRange(bytes.subarray(0, Math.min(bytes.length, 16384)), bytes.length);
  const sk = decodeSkeleton(bytes.subarray(0, r.pagesEnd ?? r.skeletonEnd), bytes.length, { topFirst: true });
  const early = sk.dag && dagOf(sk);
  completeSkeleton(sk, bytes);
  return { sk, early };
}

/** The error each opening gives (null: read), whole and top first, which must agree; anything but a FormatError fails. */
function outcome(bytes, what) {
  const attempt = (open) => {
    try {
      return { sk: open(), error: null };
    } catch (e) {
      if (!(e instanceof FormatError)) assert.fail(`${what}: threw ${e?.name}: ${e?.message}\n${e?.stack}`);
      return { sk: null, error: e };
    }
  };
  const whole = attempt(() => decodeSkeleton(bytes, bytes.length));
  const first = attempt(() => topFirst(bytes).sk);
  assert.equal(first.error === null, whole.error === null, `${what}: whole ${whole.error?.message}; top first ${first.error?.message}`);
  return whole;
}

const inputs = () => [
  ['noisy_sphere', 'noisy_sphere.ply', []],
  ['colored_sphere', 'colored_sphere.ply', []],
  ['icosphere', 'icosphere.obj', []],
  ...(existsSync(BUNNY) ? [['bunny', BUNNY, []]] : []),
];

test('files strata converts with --dag read as their DAG: against strata inspect, the pages and the rules of v4 §2', (t) => {
  if (!existsSync(BUNNY)) t.diagnostic(`skipping the bunny: ${BUNNY} not found`);
  for (const [name, mesh, args] of inputs()) {
    const path = dagFile(name, mesh, args);
    const bytes = readBytes(path);
    const sk = decodeSkeleton(bytes, bytes.length);
    assert.equal(`${sk.major}.${sk.minor}`, '4.0', name);
    const ins = JSON.parse(run(strataBin(), ['inspect', '--json', path]));
    assert.equal(ins.version, '4.0');
    assert.equal(sk.levels.length, ins.header.levels);
    // Per level: the group count the page's size gives (4 + 24·G + 56·n bytes), and each node as inspect lists it.
    const nodl = ins.chunks.filter((c) => c.id === 'NODL');
    assert.equal(nodl.length, sk.levels.length);
    let groups = 0;
    for (let l = sk.top(); l >= 0; l--) {
      const G = (nodl[sk.top() - l].size - 4 - 56 * sk.levels[l].nodes) / 24;
      const [g0, g1] = sk.dag.levelGroups[l];
      assert.equal(g1 - g0, G, `${name}: level ${l}'s groups`);
      assert.equal(g0, groups, `${name}: level ${l}'s groups follow the levels above`);
      groups += G;
      const listed = JSON.parse(run(strataBin(), ['inspect', '--json', '--level', String(l), path])).nodes;
      const [a, b] = sk.levelNodes(l);
      assert.equal(listed.length, b - a);
      for (const n of listed) {
        const i = n.node;
        const mine = {
          node: i, depth: n.depth, level: sk.level[i], parent: null, children: [], neighbors: 0, faces: sk.faces[i], vertices: sk.vertices[i],
          cone_deg: fr(sk.coneHalfAngle[i] * fr(57.29577951308232)), radius: sk.radius[i], error: sk.error[i], offset: sk.offset[i], bytes: sk.size[i], chunks: [],
        };
        // f32 fields print as their shortest decimal: read back as f32.
        assert.deepEqual({ ...n, cone_deg: fr(n.cone_deg), radius: fr(n.radius), error: fr(n.error) }, mine, `${name}: node ${i}`);
      }
    }
    assert.equal(sk.dag.groupCount, groups);
    // Nodes of a DAG have no children and no neighbours of their own.
    for (let i = 0; i < sk.nodeCount; i++) {
      assert.deepEqual([sk.childCount[i], sk.neighborCount[i], sk.parent[i]], [0, 0, NONE], `${name}: node ${i}`);
    }
    assert.deepEqual(dagOf(sk), walkPages(bytes), `${name}: the DAG the pages describe`);
    assert.deepEqual(dagRules(sk), [], `${name}: v4 §2`);
    assert.match(run(strataBin(), ['verify', path]), /sound/);
    // Top first: the top two pages' groups, then everything, as whole.
    const { sk: top, early } = topFirst(bytes);
    assert.deepEqual(dagOf(top), dagOf(sk), `${name}: top first`);
    if (sk.levels.length > 2) assert.deepEqual(early.groups, dagOf(sk).groups.slice(0, sk.dag.levelGroups[sk.top() - 1][1]), `${name}: the top pages' groups`);
    // Node payloads are format 3's: every node decodes, and checks against its record.
    let faces = 0;
    for (let i = 0; i < sk.nodeCount; i++) {
      const g = decodeNode(sk, i, bytes.subarray(sk.offset[i], sk.offset[i] + sk.size[i]));
      assert.equal(g.indices.length, 3 * sk.faces[i]);
      faces += sk.faces[i];
    }
    assert.equal(decodePlanes(sk, bytes.subarray(Math.min(planesOffset(sk), bytes.length))).entries.length, 0);
    t.diagnostic(`${name}: ${sk.levels.length} levels, ${sk.nodeCount} nodes, ${sk.dag.groupCount} groups, ${faces} faces decoded`);
  }
});

test('format 4: every damaged byte of SKEL is refused, whole and top first', () => {
  const bytes = readBytes(dagFile('colored_sphere', 'colored_sphere.ply'));
  const skel = chunks(bytes).find((c) => c.id === 'SKEL');
  const end = skel.ps + skel.size + 4;
  let tried = 0;
  for (let k = skel.at; k < end + pad8(end); k++) {
    // SKEL's flags are not a reader's to check (strata-v2.md §4.3).
    if (k >= skel.at + 4 && k < skel.at + 8) continue;
    for (const x of [0x01, 0x80, 0xff]) {
      const b = bytes.slice();
      b[k] ^= x;
      assert.ok(outcome(b, `byte ${k} ^ ${x}`).error, `byte ${k} ^ 0x${x.toString(16)} read`);
      tried++;
    }
  }
  assert.ok(tried > 3000);
});

test('format 4: resealed damage to a page (every CRC made right) is refused, or leaves the DAG as it was; as strata refuses it', (t) => {
  const bytes = readBytes(dagFile('colored_sphere', 'colored_sphere.ply'));
  const want = structure(decodeSkeleton(bytes, bytes.length));
  const file = `${scratch()}/resealed.strata`;
  let tried = 0, read = 0, compared = 0;
  for (const p of pages(bytes)) {
    for (let k = p.ps; k < p.ps + p.size; k++) {
      for (let bit = 0; bit < 8; bit++) {
        const b = bytes.slice();
        b[k] ^= 1 << bit;
        reseal(b);
        const r = outcome(b, `byte ${k} bit ${bit}`);
        tried++;
        // A sample against strata's reader (`strata inspect` opens the file whole).
        if ((k - p.ps) % 3 === 0 && bit === k % 8) {
          writeFileSync(file, b);
          const rust = spawnSync(strataBin(), ['inspect', '--json', file], { encoding: 'utf8' });
          assert.equal(rust.status === 0, r.error === null, `byte ${k} bit ${bit}: strata ${rust.status === 0 ? 'reads it' : rust.stderr.trim()}; viewer ${r.error?.message ?? 'reads it'}`);
          compared++;
        }
        if (r.error) continue;
        read++;
        assert.deepEqual(structure(r.sk), want, `byte ${k} bit ${bit}: read with another DAG`);
      }
    }
  }
  t.diagnostic(`${tried} resealed single-bit changes of the pages: ${tried - read} refused, ${read} read with the same DAG (a changed error, sphere, box or cone); ${compared} of them refused or read by strata alike`);
  assert.ok(read > 0 && read < tried);
});

test('format 4: broken DAG rules of the pages are refused with what is wrong, as strata refuses them', () => {
  const bytes = readBytes(dagFile('colored_sphere', 'colored_sphere.ply'));
  const sk = decodeSkeleton(bytes, bytes.length);
  assert.ok(sk.levels.length >= 3, 'a file of three levels, so that opening top first leaves a page for later');
  const P = pages(bytes);
  const groupsOf = (k) => le(bytes).getUint32(P[k].ps, true);
  const groupAt = (k, q) => P[k].ps + 4 + 24 * q;
  const recordAt = (k, i) => P[k].ps + 4 + 24 * groupsOf(k) + 56 * i;
  const file = `${scratch()}/broken.strata`;
  // Refused by the viewer and by strata (`strata inspect`), both saying `words`.
  const refusedBoth = (b, words) => {
    const r = outcome(b, words.join(' '));
    assert.ok(r.error, `${words}: read`);
    assert.ok(words.every((w) => r.error.message.includes(w)), `${r.error.message}: not ${words}`);
    writeFileSync(file, b);
    const rust = spawnSync(strataBin(), ['inspect', '--json', file], { encoding: 'utf8' });
    assert.ok(rust.status !== 0 && words.every((w) => rust.stderr.includes(w)), `strata: ${rust.stderr.trim()}: not ${words}`);
  };
  const broken = (edit, words, { whole = true } = {}) => {
    const b = bytes.slice();
    edit(le(b), b);
    reseal(b);
    refusedBoth(b, words);
    if (whole) return;
    // Found only once the page below is read: the top two pages open.
    const o = openingRange(b.subarray(0, 16384), b.length);
    const early = decodeSkeleton(b.subarray(0, o.pagesEnd), b.length, { topFirst: true });
    assert.throws(() => completeSkeleton(early, b), (e) => e instanceof FormatError && words.every((w) => e.message.includes(w)));
  };
  // A consumer past the level above's groups; a top node with one.
  broken((d) => d.setUint32(recordAt(1, 0), groupsOf(0), true), [`consumer ${groupsOf(0)}`, `level ${sk.top()} has ${groupsOf(0)} groups`]);
  broken((d) => d.setUint32(recordAt(0, 0), 0, true), ['node 0: consumer 0', 'a top-level node has none']);
  // A children count no node list matches: of the top's groups at once, of a lower level's on completing.
  broken((d) => d.setUint32(groupAt(0, 0) + 4, d.getUint32(groupAt(0, 0) + 4, true) + 1, true), ['group 0 of level', 'children stored', 'nodes name it']);
  broken((d) => d.setUint32(groupAt(1, 0) + 4, d.getUint32(groupAt(1, 0) + 4, true) + 1, true), [`group 0 of level ${sk.top() - 1}`, 'children stored'], { whole: false });
  // Moving a child to another group of the same level: the counts no longer match.
  if (groupsOf(1) > 1) {
    const k = 2, last = sk.levels[sk.top() - 2].nodes - 1;
    broken((d) => d.setUint32(recordAt(k, last), (d.getUint32(recordAt(k, last), true) + 1) % groupsOf(1), true), ['children stored', 'nodes name it'], { whole: false });
  }
  // Outputs that do not tile the level, or none; no children; reserved bits.
  broken((d) => d.setUint32(groupAt(0, 0), d.getUint32(groupAt(0, 0), true) + 1, true), ['outputs', 'run past the level']);
  broken((d) => d.setUint32(groupAt(0, 0), 0, true), ['0 outputs']);
  broken((d) => d.setUint32(groupAt(0, 0) + 4, 0, true), ['0 children']);
  broken((d) => d.setUint16(groupAt(0, 0) + 14, 1, true), ['reserved 1']);
  if (groupsOf(1) > 1 && le(bytes).getUint32(groupAt(1, 0), true) > 1) {
    broken((d) => d.setUint32(groupAt(1, 0), d.getUint32(groupAt(1, 0), true) - 1, true), ['outputs of level', 'cover nodes up to']);
  }
  // Values: the center off the grid, the error negative or not a number.
  broken((d) => d.setUint32(groupAt(0, 0) + 20, 0x80000000, true), ['sphere center off the']);
  broken((d) => d.setFloat32(groupAt(0, 0) + 8, -1, true), ['geometric error -1']);
  broken((d) => d.setFloat32(groupAt(0, 0) + 8, NaN, true), ['geometric error NaN']);
  // Group counts: none above level 0; a level-0 page with groups (sized to hold them); a count the page cannot hold.
  const withPage = (k, G, words) => {
    const records = bytes.slice(P[k].ps + 4 + 24 * groupsOf(k), P[k].ps + P[k].size);
    const payload = new Uint8Array(4 + 24 * G + records.length);
    le(payload).setUint32(0, G, true);
    payload.set(records, 4 + 24 * G);
    refusedBoth(reseal(replacePage(bytes, k, payload)), words);
  };
  withPage(0, 0, [`level ${sk.top()} has 0 groups`]);
  withPage(P.length - 1, 1, ['level 0 has 1 groups']);
  broken((d) => d.setUint32(P[0].ps, groupsOf(0) + 1, true), ['group records and', 'node records need']);
  // Page flags: format 4's pages have no neighbour entries.
  broken((d) => d.setUint32(P[0].at + 4, 2, true), ['flags 2', 'a format-4 page has 0']);
});

/** `bytes` with page k's payload replaced: sizes of the page, SKEL and the file, and offsets after, moved. */
function replacePage(bytes, k, payload) {
  const skel = chunks(bytes).find((c) => c.id === 'SKEL');
  const p = pages(bytes)[k];
  const oldSpan = 20 + p.size + pad8(20 + p.size), newSpan = 20 + payload.length + pad8(20 + payload.length);
  const delta = newSpan - oldSpan;
  const page = new Uint8Array(newSpan);
  page.set(bytes.subarray(p.at, p.at + 16));
  le(page).setBigUint64(8, BigInt(payload.length), true);
  page.set(payload, 16);
  const b = new Uint8Array(bytes.length + delta);
  b.set(bytes.subarray(0, p.at));
  b.set(page, p.at);
  b.set(bytes.subarray(p.at + oldSpan), p.at + newSpan);
  le(b).setBigUint64(skel.at + 8, BigInt(skel.size + delta), true);
  le(b).setBigUint64(32, BigInt(b.length), true);
  return b;
}

test('format 4: an ORDR chunk is refused (strata-v4.md §0)', () => {
  const bytes = readBytes(dagFile('colored_sphere', 'colored_sphere.ply'));
  const sk = decodeSkeleton(bytes, bytes.length);
  assert.equal(planesOffset(sk), bytes.length);
  const payload = new Uint8Array(4 * (sk.nodeCount + 1));
  const ordr = new Uint8Array(20 + payload.length + pad8(20 + payload.length));
  ordr.set([0x4f, 0x52, 0x44, 0x52]);
  le(ordr).setUint32(4, 2, true);
  le(ordr).setBigUint64(8, BigInt(payload.length), true);
  le(ordr).setUint32(16 + payload.length, crc32(payload), true);
  const b = new Uint8Array(bytes.length + ordr.length);
  b.set(bytes);
  b.set(ordr, bytes.length);
  le(b).setBigUint64(32, BigInt(b.length), true);
  reseal(b);
  const withPlanes = decodeSkeleton(b, b.length);
  assert.throws(() => decodePlanes(withPlanes, b.subarray(planesOffset(withPlanes))), (e) => e instanceof FormatError && /ORDR chunk in a format-4 file/.test(e.message));
});
