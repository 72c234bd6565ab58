// The web viewer's seams between levels (viewer/seams.js, selection.md §8) against strata's own
// (`strata stream`) on the fronts of one orbit: the Rust streamer's fronts replayed in Node, each
// front's seams made as the viewer makes them (the borders of the nodes taking part and of their
// displayed neighbours), the fill checked against strata's `seam_faces`.
//
//   node benches/js/seams.mjs file.strata...      (STRATA_BIN: the strata binary)
//
// Prints per file: a node's border in ms (made once per kept node), the seams per front in ms,
// median / most, and the same run's `seams_ms` of strata stream, median / most, with the ratio of
// medians; and whether every front got the same number of fill faces in both.

import { readFileSync } from 'node:fs';
import { execFileSync } from 'node:child_process';
import { decodeSkeleton, decodeNode } from '../../viewer/format.js';
import { border, seams, takingPart } from '../../viewer/seams.js';
import { strataBin } from '../../tests/js/helpers.mjs';

const files = process.argv.slice(2);
if (files.length === 0) {
  console.error('usage: node benches/js/seams.mjs file.strata...');
  process.exit(2);
}
const ORBIT = 32, PASSES = 3;
const median = (a) => [...a].sort((x, y) => x - y)[a.length >> 1];

for (const file of files) {
  const out = execFileSync(strataBin(), ['stream', file, '--json', '--print-front', '--orbit', `${ORBIT}`], { encoding: 'utf8', maxBuffer: 1 << 30 });
  const frames = out.trim().split('\n').map((l) => JSON.parse(l));
  const bytes = new Uint8Array(readFileSync(file));
  const s = decodeSkeleton(bytes, bytes.length);
  const h = s.header;
  const localOrigin = h.min.map((m, k) => (m + h.max[k]) / 2);
  const geometry = new Map();
  for (const f of frames) {
    for (const i of f.front) {
      if (!geometry.has(i)) geometry.set(i, decodeNode(s, i, bytes.subarray(s.offset[i], s.offset[i] + s.size[i]), { localOrigin }));
    }
  }
  // Borders: a warm-up pass, then the best of PASSES.
  let borders, borderMs = Infinity;
  for (let pass = 0; pass <= PASSES; pass++) {
    const t0 = performance.now();
    borders = new Map([...geometry].map(([i, g]) => [i, border(s.level[i], s.error[i], g)]));
    if (pass > 0) borderMs = Math.min(borderMs, (performance.now() - t0) / geometry.size);
  }
  const fronts = frames.map((f) => {
    const { sealing, near } = takingPart(f.front, (i) => s.neighbors(i));
    return { sealing: sealing.map((i) => borders.get(i)), near: near.map((i) => borders.get(i)), faces: f.seam_faces };
  });
  // Per front, the best of PASSES after a warm-up pass.
  const ms = new Float64Array(fronts.length).fill(Infinity);
  let agree = 0;
  for (let pass = 0; pass <= PASSES; pass++) {
    fronts.forEach((f, k) => {
      const t0 = performance.now();
      const fill = seams(f.sealing, f.near);
      if (pass > 0) ms[k] = Math.min(ms[k], performance.now() - t0);
      if (pass === 0 && fill.faces === f.faces) agree++;
    });
  }
  const rust = frames.map((f) => f.seams_ms);
  const js = Array.from(ms);
  console.log(
    `${file}: ${geometry.size} nodes, a border ${borderMs.toFixed(3)} ms; seams per front ${median(js).toFixed(1)} / ${Math.max(...js).toFixed(1)} ms ` +
      `(strata stream ${median(rust).toFixed(1)} / ${Math.max(...rust).toFixed(1)} ms, ratio of medians ${(median(js) / median(rust)).toFixed(2)}); ` +
      `fill faces as strata's on ${agree} of ${fronts.length} fronts`,
  );
}
