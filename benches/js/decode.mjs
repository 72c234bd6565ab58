// The web viewer's node decoding speed (viewer/format.js) on one core, in Node: every node of each
// file given, decoded as the viewer decodes it (decodeNode with a local origin: CRC, codec, rules;
// positions, normals, colours, UVs and indices into typed arrays), best of several passes after a
// warm-up. Also the slowest node, which bounds how long a decode can hold up a frame.
//
//   node benches/js/decode.mjs file.strata...
//
// Prints per file: faces, nodes, M faces/s, MB/s of node bytes, and the slowest node in ms.

import { readFileSync } from 'node:fs';
import { decodeSkeleton, decodeNode } from '../../viewer/format.js';

const files = process.argv.slice(2);
if (files.length === 0) {
  console.error('usage: node benches/js/decode.mjs file.strata...');
  process.exit(2);
}
const PASSES = 7;

for (const file of files) {
  const bytes = new Uint8Array(readFileSync(file));
  const sk = decodeSkeleton(bytes, bytes.length);
  const h = sk.header;
  const localOrigin = h.min.map((m, k) => (m + h.max[k]) / 2);
  const n = sk.nodeCount;
  const nodes = Array.from({ length: n }, (_, i) => bytes.subarray(sk.offset[i], sk.offset[i] + sk.size[i]));
  let faces = 0, nodeBytes = 0;
  for (let i = 0; i < n; i++) {
    faces += sk.faces[i];
    nodeBytes += sk.size[i];
  }
  const opts = { localOrigin };
  // Warm-up, then whole passes (the best reported) and each node's best time.
  for (let i = 0; i < n; i++) decodeNode(sk, i, nodes[i], opts);
  let best = Infinity;
  const nodeBest = new Float64Array(n).fill(Infinity);
  for (let pass = 0; pass < PASSES; pass++) {
    const t0 = performance.now();
    for (let i = 0; i < n; i++) {
      const a = performance.now();
      decodeNode(sk, i, nodes[i], opts);
      const ms = performance.now() - a;
      if (ms < nodeBest[i]) nodeBest[i] = ms;
    }
    best = Math.min(best, performance.now() - t0);
  }
  let slowest = 0;
  for (let i = 1; i < n; i++) if (nodeBest[i] > nodeBest[slowest]) slowest = i;
  const s = best / 1000;
  const attrs = Object.entries(h.attributes).filter(([, v]) => v).map(([k]) => k).join('+') || 'positions';
  console.log(
    `${file}: format ${sk.major}.${sk.minor}, ${n} nodes, ${faces} faces (${attrs}), ${nodeBytes} node bytes: ` +
      `${(faces / 1e6 / s).toFixed(1)} M faces/s, ${(nodeBytes / 1e6 / s).toFixed(0)} MB/s, ${best.toFixed(1)} ms a pass; ` +
      `slowest node ${slowest} (${sk.faces[slowest]} faces) ${nodeBest[slowest].toFixed(2)} ms`,
  );
}
