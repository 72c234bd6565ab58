// Exported GLB files stand alone and are valid glTF: the Khronos glTF-Validator (npm
// `gltf-validator`) reports zero errors for what `strata extract`, `strata simplify` and
// `strata stream --export-cut` write from textured models (the shipped textured globe, and every
// textured glTF sample of ../shared/meshes when present), and every image they use is embedded.
// Skips with a line saying so where gltf-validator is not installed (`npm ci --prefix tests/js`).

import test from 'node:test';
import assert from 'node:assert/strict';
import { existsSync, readdirSync, readFileSync, statSync } from 'node:fs';
import { createRequire } from 'node:module';
import { join } from 'node:path';
import { converted, root, run, scratch, strataBin } from './helpers.mjs';

const require = createRequire(import.meta.url);
let validator = null;
try {
  validator = require('gltf-validator');
} catch {
  validator = null;
}

/** The glTF files under `dir` whose materials name an image, each folder's .gltf and .glb. */
function texturedSamples(dir) {
  const out = [];
  const walk = (d) => {
    for (const name of readdirSync(d)) {
      const p = join(d, name);
      if (statSync(p).isDirectory()) walk(p);
      else if (/\.(gltf|glb)$/i.test(name) && !p.includes('Draco')) {
        const text = readFileSync(p).toString('latin1');
        if (text.includes('"images"') && /"(baseColorTexture|normalTexture|emissiveTexture)"/.test(text)) out.push(p);
      }
    }
  };
  if (existsSync(dir)) walk(dir);
  return out.sort();
}

async function validate(file) {
  const bytes = new Uint8Array(readFileSync(file));
  const report = await validator.validateBytes(bytes, { maxIssues: 200 });
  const errors = report.issues.messages.filter((m) => m.severity === 0);
  return { report, errors, json: JSON.parse(glbJson(bytes)) };
}

function glbJson(bytes) {
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const length = dv.getUint32(12, true);
  return new TextDecoder().decode(bytes.subarray(20, 20 + length));
}

test('exported GLB files validate with zero errors and embed their images', { skip: !validator && 'skipping: gltf-validator not installed (npm ci --prefix tests/js)' }, async (t) => {
  const bin = strataBin();
  const inputs = [join(root, 'fixtures', 'textured_globe.glb'), ...texturedSamples(join(root, '..', 'shared', 'meshes', 'gltf'))];
  if (inputs.length === 1) t.diagnostic('skipping the shared samples: ../shared/meshes/gltf not found');
  const dir = scratch();
  let files = 0;
  for (const [k, input] of inputs.entries()) {
    const strata = converted(`validator-${k}`, input, []);
    const outs = [`${dir}/extract-${k}.glb`, `${dir}/simplify-${k}.glb`, `${dir}/cut-${k}.glb`];
    run(bin, ['extract', strata, '--level', '0', '-o', outs[0]]);
    run(bin, ['simplify', input, '--ratio', '0.5', '-o', outs[1]]);
    run(bin, ['stream', strata, '--orbit', '3', '--export-cut', outs[2]]);
    for (const out of outs) {
      const { report, errors, json } = await validate(out);
      assert.equal(errors.length, 0, `${input} -> ${out}: ${JSON.stringify(errors.slice(0, 5))}`);
      for (const image of json.images ?? []) {
        assert.ok(image.bufferView !== undefined && image.uri === undefined, `${out}: image not embedded: ${JSON.stringify(image)}`);
      }
      assert.ok(!(json.images ?? []).length || report.info.resources.every((r) => r.storage !== 'external'), `${out}: external resources`);
      files++;
    }
    const textured = JSON.parse(run(bin, ['inspect', strata, '--json'])).images.length;
    const { json } = await validate(outs[0]);
    assert.ok(textured === 0 || (json.images ?? []).length > 0, `${input}: the .strata file has ${textured} images but the export none`);
  }
  t.diagnostic(`${files} GLB files from ${inputs.length} textured models: 0 validator errors`);
});
