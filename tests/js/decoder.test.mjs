// Decoding in workers (viewer/decoder.js, viewer/decode_worker.js) against decoding on the main
// thread: the same nodes, the same arrays, the same errors. Node has no Web Workers: the stand-in
// below runs the worker's handler in later tasks and passes every message through structuredClone
// with its transfer list, as postMessage does (the browser test runs real Workers).

import { test } from 'node:test';
import assert from 'node:assert/strict';
import { existsSync, readFileSync } from 'node:fs';
import { Streamer } from '../../viewer/stream.js';
import { DecoderPool } from '../../viewer/decoder.js';
import { decodeHandler } from '../../viewer/decode_worker.js';
import { FormatError } from '../../viewer/format.js';
import { root, converted, cameraFrom } from './helpers.mjs';

class StandInWorker {
  /** `crashAfter` decodes, then an error event; `silentAfter`, then no answer; `throwOn`: a node whose decode throws a plain Error. */
  constructor({ crashAfter = Infinity, silentAfter = Infinity, throwOn = -1 } = {}) {
    this.handle = decodeHandler();
    Object.assign(this, { crashAfter, silentAfter, throwOn });
    this.decodes = 0;
    this.terminated = false;
  }
  postMessage(msg, transfer = []) {
    if (msg.op === 'decode') {
      // The node's bytes move, whole: a view of a larger buffer would be copied with all of it.
      assert.ok(transfer.includes(msg.bytes.buffer) && msg.bytes.byteLength === msg.bytes.buffer.byteLength, 'the bytes are transferred, alone');
    }
    const m = structuredClone(msg, { transfer });
    if (m.op === 'decode' && ++this.decodes > this.crashAfter) {
      setTimeout(() => this.onerror?.({ message: 'stand-in crash' }), 0);
      return;
    }
    if (m.op === 'decode' && this.decodes > this.silentAfter) return;
    setTimeout(() => {
      const r = m.op === 'decode' && m.node === this.throwOn ? { reply: { id: m.id, error: { message: 'stand-in exception', format: false } }, transfer: [] } : this.handle(m);
      if (r) this.onmessage?.({ data: structuredClone(r.reply, { transfer: r.transfer }) });
    }, 0);
  }
  terminate() {
    this.terminated = true;
  }
}

class MemorySource {
  constructor(bytes) {
    this.bytesOf = bytes;
    this.name = 'memory';
    this.length = bytes.length;
    this.requests = 0;
    this.bytes = 0;
  }
  async read(start, end) {
    this.requests++;
    await new Promise((r) => setTimeout(r, 0));
    const body = this.bytesOf.subarray(start, Math.min(end, this.length));
    this.bytes += body.length;
    return body;
  }
}

/** Stream `bytes` to full detail for two cameras; every geometry handed to onLoad, by node. */
async function stream(bytes, decoder, prefix = 16384, options = {}) {
  const loaded = new Map();
  const st = await Streamer.open(new MemorySource(bytes), { pixelError: 0.5, decoder, prefix, onLoad: (i, g) => loaded.set(i, g), ...options });
  for (const distance of [1, 0.4]) {
    const cam = cameraFrom(st.skeleton, [0.4, 0.3, 1.0], distance);
    for (let k = 0; ; k++) {
      assert.ok(k < 20000, 'the front never became resident');
      st.update(cam);
      if (st.error) return { st, loaded };
      if (st.idle()) break;
      await new Promise((r) => setTimeout(r, 0));
    }
  }
  return { st, loaded };
}

/** The borders for the seams between levels (made by a worker or the page) equal on both sides. */
function sameBorders(there, here) {
  let borders = 0;
  for (const [i, c] of here.st.cache) {
    const w = there.st.cache.get(i);
    if (!w) continue;
    assert.deepEqual(w.border, c.border, `node ${i}'s border`);
    borders += c.border.count > 0;
  }
  assert.ok(borders > 0, 'some resident nodes have a border');
}

const inputs = [['noisy_sphere_v3', `${root}/fixtures/noisy_sphere.ply`, ['--format-version', '3']], ['noisy_sphere', `${root}/fixtures/noisy_sphere.ply`, ['--format-version', '2']], ['colored_sphere', `${root}/fixtures/colored_sphere.ply`, []], ['textured_globe', `${root}/fixtures/textured_globe.glb`, []]];
const ct = `${root}/../shared/meshes/large/cthead_skin_native.ply`;
if (existsSync(ct)) inputs.push(['cthead', ct, []]);

// A 256-byte first read: format 3's skeleton opens from its top pages, and the workers complete
// theirs from the bytes the page completes its own from.
for (const [name, mesh, args, prefix] of [...inputs, ['noisy_sphere_v3', `${root}/fixtures/noisy_sphere.ply`, ['--format-version', '3'], 256]]) {
  test(`nodes decoded in workers equal nodes decoded on the main thread (${name}${prefix ? `, a ${prefix}-byte first read` : ''})`, async (t) => {
    const bytes = new Uint8Array(readFileSync(converted(name, mesh, args)));
    const here = await stream(bytes, null, prefix);
    const workers = [new StandInWorker(), new StandInWorker()];
    const pool = new DecoderPool(workers);
    const there = await stream(bytes, pool, prefix);
    assert.equal(there.st.error, null);
    assert.deepEqual(there.st.drawn, here.st.drawn);
    assert.deepEqual([...there.loaded.keys()].sort((a, b) => a - b), [...here.loaded.keys()].sort((a, b) => a - b));
    for (const [i, g] of here.loaded) assert.deepEqual(there.loaded.get(i), g, `node ${i}`);
    sameBorders(there, here);
    const top = there.st.skeleton.levelNodes(there.st.skeleton.top());
    assert.equal(pool.decoded, here.loaded.size - (top[1] - top[0]), 'every node below the top level came from a worker');
    assert.ok(pool.decoded > 0);
    if (prefix) assert.ok(there.st.skeleton.decoded === there.st.skeleton.nodeCount && here.st.openBytes < bytes.length / 2, 'opened from a prefix');
    there.st.close();
    assert.ok(workers.every((w) => w.terminated), 'closing the streamer ends its workers');
    t.diagnostic(`${name}: ${here.loaded.size} nodes, ${pool.decoded} decoded in the workers`);
  });
}

test('a damaged node fails with the same error in a worker as on the main thread', async () => {
  const bytes = new Uint8Array(readFileSync(converted('noisy_sphere_v3', `${root}/fixtures/noisy_sphere.ply`, ['--format-version', '3'])));
  const probe = await stream(bytes, null);
  const s = probe.st.skeleton;
  // A byte in the middle of the deepest node drawn: its CRC fails.
  const node = Math.min(...probe.st.drawn);
  assert.ok(s.level[node] < s.top());
  const damaged = bytes.slice();
  damaged[s.offset[node] + (s.size[node] >> 1)] ^= 0x10;
  const here = await stream(damaged, null);
  const there = await stream(damaged, new DecoderPool([new StandInWorker()]));
  assert.ok(here.st.error instanceof FormatError, String(here.st.error));
  assert.ok(there.st.error instanceof FormatError, String(there.st.error));
  assert.equal(there.st.error.message, here.st.error.message);
  assert.equal(there.st.error.node, here.st.error.node);
  assert.match(there.st.error.message, new RegExp(`node ${node}`));
});

test('when a worker fails, decoding moves back to the main thread and the stream still completes', async () => {
  const bytes = new Uint8Array(readFileSync(converted('noisy_sphere_v3', `${root}/fixtures/noisy_sphere.ply`, ['--format-version', '3'])));
  const here = await stream(bytes, null);
  const pool = new DecoderPool([new StandInWorker({ crashAfter: 3 })]);
  const there = await stream(bytes, pool);
  assert.equal(there.st.error, null);
  assert.match(there.st.decoderError, /stand-in crash/);
  assert.equal(there.st.decoder, null);
  assert.deepEqual(there.st.drawn, here.st.drawn);
  for (const [i, g] of here.loaded) assert.deepEqual(there.loaded.get(i), g, `node ${i}`);
});

test('a worker that stops answering hands its work to the main thread after the timeout', async () => {
  const bytes = new Uint8Array(readFileSync(converted('noisy_sphere_v3', `${root}/fixtures/noisy_sphere.ply`, ['--format-version', '3'])));
  const here = await stream(bytes, null);
  const there = await stream(bytes, new DecoderPool([new StandInWorker({ silentAfter: 3 })], { timeoutMs: 50 }));
  assert.equal(there.st.error, null);
  assert.match(there.st.decoderError, /did not answer in 50 ms/);
  assert.deepEqual(there.st.drawn, here.st.drawn);
  for (const [i, g] of here.loaded) assert.deepEqual(there.loaded.get(i), g, `node ${i}`);
});

test('an exception on one node is met on the main thread, and the workers stay', async () => {
  const bytes = new Uint8Array(readFileSync(converted('noisy_sphere_v3', `${root}/fixtures/noisy_sphere.ply`, ['--format-version', '3'])));
  const here = await stream(bytes, null);
  const node = Math.max(...here.st.drawn);
  const pool = new DecoderPool([new StandInWorker({ throwOn: node })]);
  const there = await stream(bytes, pool);
  assert.equal(there.st.error, null);
  assert.equal(there.st.decoder, pool, 'the pool is kept');
  assert.equal(there.st.decoderError, null);
  const top = there.st.skeleton.levelNodes(there.st.skeleton.top());
  assert.equal(there.st.mainDecoded, top[1] - top[0] + 1, 'the top level at open, and that node');
  for (const [i, g] of here.loaded) assert.deepEqual(there.loaded.get(i), g, `node ${i}`);
});

// With sliceMs 0 every node decoded on the page's thread is a task of its own: the nodes a failed
// pool hands back (all the ranges in flight at once) go through the same queue as without workers.
for (const [what, pool] of [['without workers', () => null], ['after the pool fails', () => new DecoderPool([new StandInWorker({ crashAfter: 3 })])]]) {
  test(`decoding on the page's thread yields between nodes at sliceMs 0 (${what})`, async (t) => {
    const bytes = new Uint8Array(readFileSync(converted('noisy_sphere_v3', `${root}/fixtures/noisy_sphere.ply`, ['--format-version', '3'])));
    const here = await stream(bytes, null);
    // Nodes decoded on the page's thread at each start of the streamer's decoding loop and at each
    // of its yields (both called as its methods): between two of them, one run.
    const marks = [];
    const yieldTask = function () {
      marks.push(this.mainDecoded);
      return new Promise((r) => setTimeout(r, 0));
    };
    const runSlices = Streamer.prototype.runSlices;
    Streamer.prototype.runSlices = function () {
      marks.push(this.mainDecoded);
      return runSlices.call(this);
    };
    t.after(() => {
      Streamer.prototype.runSlices = runSlices;
    });
    const there = await stream(bytes, pool(), 16384, { sliceMs: 0, yieldTask });
    assert.equal(there.st.error, null);
    for (const [i, g] of here.loaded) assert.deepEqual(there.loaded.get(i), g, `node ${i}`);
    sameBorders(there, here);
    const top = there.st.skeleton.levelNodes(there.st.skeleton.top());
    const opened = top[1] - top[0];
    const sliced = there.st.mainDecoded - opened;
    assert.ok(sliced > 10, `${sliced} nodes decoded on the page's thread after open`);
    marks.push(there.st.mainDecoded);
    const runs = marks.slice(1).map((n, k) => n - marks[k]);
    assert.equal(marks[0], opened, 'the top level decoded at open');
    assert.ok(Math.max(...runs) === 1, `runs of up to ${Math.max(...runs)} nodes`);
  });
}

// A yieldTask that throws or rejects (a caller's) must not stop the queue with nodes in it.
for (const [what, yieldTask] of [
  ['throws', () => { throw new Error('no tasks'); }],
  ['rejects', () => Promise.reject(new Error('no tasks'))],
]) {
  test(`the page's decoding queue goes on when yieldTask ${what}`, async () => {
    const bytes = new Uint8Array(readFileSync(converted('noisy_sphere_v3', `${root}/fixtures/noisy_sphere.ply`, ['--format-version', '3'])));
    const here = await stream(bytes, null);
    const there = await stream(bytes, null, 16384, { sliceMs: 0, yieldTask });
    assert.equal(there.st.error, null);
    assert.deepEqual(there.st.drawn, here.st.drawn);
    for (const [i, g] of here.loaded) assert.deepEqual(there.loaded.get(i), g, `node ${i}`);
    assert.equal(there.st.slicing, false);
    assert.equal(there.st.sliced.length, 0);
  });
}
