// Node decoding in Workers (decode_worker.js), so that a range of nodes arriving never holds up a
// frame, and several ranges decode at once on a machine of several cores. The Streamer takes a
// pool as its `decoder` option; without one it decodes on the main thread in slices (`sliceMs`).

import { FormatError } from './format.js';

export class DecoderPool {
  /**
   * A pool over `workers`: objects with `postMessage(msg, transfer)`, `onmessage`, `onerror` and
   * `terminate()` (Web Workers, or stand-ins in tests). Use `DecoderPool.create` in a page.
   */
  constructor(workers, { timeoutMs = 10000 } = {}) {
    this.workers = workers.map((w) => ({ w, busy: 0 }));
    /** A decode not answered in this long means a worker that is gone (killed without an error event). */
    this.timeoutMs = timeoutMs;
    this.pending = new Map();
    this.nextId = 1;
    /** Why the pool stopped (a worker failed to load or crashed): every decode then rejects with it. */
    this.failed = null;
    /** Nodes decoded by the workers. */
    this.decoded = 0;
    for (const slot of this.workers) {
      slot.w.onmessage = (e) => this.answer(slot, e.data);
      slot.w.onerror = (e) => this.fail(new Error(`a decoding worker failed: ${e?.message ?? 'it could not start'}`));
      slot.w.onmessageerror = () => this.fail(new Error('a decoding worker sent a message that could not be read'));
    }
  }

  /** `count` module Workers, or null where the page has none (or count < 1). */
  static create(count, url = new URL('./decode_worker.js', import.meta.url)) {
    if (typeof Worker === 'undefined' || !(count >= 1)) return null;
    const workers = [];
    try {
      for (let k = 0; k < Math.min(count, 16); k++) workers.push(new Worker(url, { type: 'module' }));
    } catch (e) {
      // A page that may not start workers (a worker-src policy, a file:// page) decodes on its own thread.
      for (const w of workers) w.terminate();
      DecoderPool.unavailable = e?.message ?? String(e);
      return null;
    }
    return new DecoderPool(workers);
  }

  get size() {
    return this.workers.length;
  }

  /** Give every worker the skeleton: the bytes `decodeSkeleton` read (top pages first) and the file's length. */
  open(bytes, length, localOrigin) {
    for (const { w } of this.workers) w.postMessage({ op: 'open', bytes: own(bytes), length, localOrigin });
  }

  /** Tell every worker the skeleton is complete, with the bytes the main thread completed it from. */
  complete(bytes) {
    for (const { w } of this.workers) w.postMessage({ op: 'complete', bytes: bytes && own(bytes) });
  }

  /** Node `node` decoded and checked from its `bytes` (which this takes: their buffer moves to the worker). */
  decode(node, bytes) {
    if (this.failed) return Promise.reject(this.failed);
    const slot = this.workers.reduce((a, b) => (b.busy < a.busy ? b : a));
    const id = this.nextId++;
    slot.busy++;
    return new Promise((resolve, reject) => {
      const timer = setTimeout(() => this.fail(new Error(`a decoding worker did not answer in ${this.timeoutMs} ms`)), this.timeoutMs);
      this.pending.set(id, { slot, resolve, reject, timer });
      slot.w.postMessage({ op: 'decode', id, node, bytes }, [bytes.buffer]);
    });
  }

  answer(slot, msg) {
    const p = this.pending.get(msg?.id);
    if (!p) return;
    this.pending.delete(msg.id);
    clearTimeout(p.timer);
    slot.busy--;
    if (msg.error) {
      const e = msg.error;
      // A file's fault, or an exception of the decoder on this node (the worker itself is fine).
      p.reject(e.format ? new FormatError(e.message, { offset: e.offset, node: e.node }) : new NodeDecodeError(e.message));
    } else {
      this.decoded++;
      p.resolve(msg.geometry);
    }
  }

  fail(error) {
    this.failed ??= error;
    for (const p of this.pending.values()) {
      clearTimeout(p.timer);
      p.reject(this.failed);
    }
    this.pending.clear();
    for (const slot of this.workers) slot.busy = 0;
  }

  close() {
    this.fail(new Error('the decoder is closed'));
    for (const { w } of this.workers) w.terminate();
  }
}

/** An exception a worker met decoding one node that is not the file's fault (the pool stays up). */
export class NodeDecodeError extends Error {
  constructor(message) {
    super(message);
    this.name = 'NodeDecodeError';
  }
}

/** `bytes` over a buffer of their own: a message copies a view's whole buffer, not the view. */
const own = (bytes) => (bytes.byteOffset === 0 && bytes.byteLength === bytes.buffer.byteLength ? bytes : bytes.slice());
