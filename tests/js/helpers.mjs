// What the JavaScript tests share: the repository root, the strata binary (STRATA_BIN, set by
// tests/viewer_js.rs, else target/release/strata), and chunk files converted once per run.

import { execFileSync } from 'node:child_process';
import { existsSync, mkdirSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { dirname, resolve } from 'node:path';
import { fileURLToPath } from 'node:url';
import { Camera } from '../../viewer/camera.js';

export const root = resolve(dirname(fileURLToPath(import.meta.url)), '../..');

export function strataBin() {
  const bin = process.env.STRATA_BIN ?? `${root}/target/release/strata`;
  if (!existsSync(bin)) throw new Error(`${bin} not found: build it with cargo build --release (or run cargo test --release)`);
  return bin;
}

/** Scratch folder of this run (STRATA_TEST_DIR when the Rust harness sets it). */
export function scratch() {
  const dir = process.env.STRATA_TEST_DIR ?? `${tmpdir()}/strata-js-${process.pid}`;
  mkdirSync(dir, { recursive: true });
  return dir;
}

export function run(bin, args) {
  return execFileSync(bin, args, { encoding: 'utf8', maxBuffer: 1 << 30, stdio: ['ignore', 'pipe', 'pipe'] });
}

/** `mesh` converted with `args` into `<scratch>/<name>.strata`, once per run. */
export function converted(name, mesh, args) {
  const out = `${scratch()}/${name}.strata`;
  if (!existsSync(out)) run(strataBin(), ['convert', mesh, out, '-q', ...args]);
  return out;
}

/** A 640×480 camera on skeleton `s`'s model from `direction`, at `distance` times the framing distance. */
export function cameraFrom(s, direction, distance) {
  const h = s.header;
  const center = h.min.map((m, i) => (m + h.max[i]) / 2);
  const radius = Math.hypot(...h.max.map((m, i) => m - h.min[i])) / 2;
  const cam = Camera.framing(center, radius, direction, 1.0, 640, 480);
  const dir = cam.eye.map((e, i) => e - center[i]);
  cam.eye = center.map((c, i) => c + dir[i] * distance);
  const d = Math.hypot(...dir) * distance;
  cam.near = Math.max(d - radius, d * 1e-3);
  cam.far = d + radius;
  return cam;
}
