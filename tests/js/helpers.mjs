// What the JavaScript tests share: the repository root, the strata binary (STRATA_BIN, set by
// tests/viewer_js.rs, else target/release/strata), and chunk files converted once per run.

import { execFileSync } from 'node:child_process';
import { existsSync, mkdirSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { dirname, resolve } from 'node:path';
import { fileURLToPath } from 'node:url';

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
