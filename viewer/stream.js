// The viewer's streaming: open a chunk file in as few round trips as its layout allows, then per
// frame select the front (select.js), draw what is resident, and read what is missing, coarsest
// first, a few requests at a time, within a memory budget kept by least-recently-used eviction.
//
// Opening: one read of the first `prefix` bytes (16 KB) tells where the skeleton ends and, from
// the skeleton's level table, where the top level's geometry ends; a second read fetches the rest
// of both. So the first frame needs two round trips (one when the file is smaller than the prefix).
//
// What is drawn is always a front by the rule: the same selection, with every node held whose
// visible children are not all resident yet. So a view refines level by level as data arrives,
// coarse before fine, never with a hole; the top level stays resident to stand in for anything.
// Drawn nodes and their ancestors are the most recently used, so moving away finds coarser nodes
// still resident.

import { FormatError, decodeNode, decodeSkeleton, openingRange } from './format.js';
import { Selector, recordBytes, sees } from './select.js';

const NO_PARENT = 0xffffffff;

function concat(a, b) {
  const c = new Uint8Array(a.length + b.length);
  c.set(a);
  c.set(b, a.length);
  return c;
}

export class Streamer {
  /**
   * Open `source` (source.js): read the skeleton and the top level, decode and check them.
   * `options`: `prefix` (first read, bytes), `budget` (resident bytes), `maxInFlight`,
   * `maxRequestBytes`, `maxGapBytes` (bytes of other nodes a range may span), `pixelError`, `maxFaces`, `priority`, `onLoad(i, geometry)` → a handle
   * kept with the node (the renderer's buffers), `onEvict(i, handle)`, `onChange()`.
   */
  static async open(source, options = {}) {
    const t0 = performance.now();
    const prefix = options.prefix ?? 16384;
    let bytes = await source.read(0, prefix);
    let range = openingRange(bytes, source.length);
    while (range.need !== undefined) {
      if (bytes.length >= (source.length ?? Infinity)) throw new FormatError(`${source.name}: the file ends at byte ${bytes.length}, before its skeleton`);
      bytes = concat(bytes, await source.read(bytes.length, Math.max(range.need, bytes.length + prefix)));
      range = openingRange(bytes, source.length);
    }
    const want = Math.max(range.topEnd ?? 0, range.skeletonEnd);
    if (bytes.length < want) bytes = concat(bytes, await source.read(bytes.length, want));
    const skeleton = decodeSkeleton(bytes, source.length);
    const s = new Streamer(source, skeleton, options);
    const [top0, top1] = skeleton.levelNodes(skeleton.top());
    const topEnd = skeleton.offset[top1 - 1] + skeleton.size[top1 - 1];
    if (bytes.length < topEnd) bytes = concat(bytes, await source.read(bytes.length, topEnd));
    for (let i = top0; i < top1; i++) s.insert(i, bytes.subarray(skeleton.offset[i], skeleton.offset[i] + skeleton.size[i]));
    s.openMs = performance.now() - t0;
    s.openRequests = source.requests;
    s.openBytes = source.bytes;
    return s;
  }

  constructor(source, skeleton, options) {
    this.source = source;
    this.skeleton = skeleton;
    this.selector = new Selector(skeleton);
    this.drawSelector = new Selector(skeleton);
    const [top0, top1] = skeleton.levelNodes(skeleton.top());
    this.topBytes = 0;
    for (let i = top0; i < top1; i++) this.topBytes += recordBytes(skeleton, i);
    this.touched = new Uint32Array(skeleton.nodeCount);
    this.failures = 0;
    this.retryAt = 0;
    this.closed = false;
    this.budget = options.budget ?? 512 * 2 ** 20;
    this.pixelError = options.pixelError ?? 2;
    this.maxFaces = options.maxFaces;
    this.priority = options.priority ?? 'error';
    this.maxInFlight = options.maxInFlight ?? 4;
    this.maxRequestBytes = options.maxRequestBytes ?? 1 << 20;
    this.maxGapBytes = options.maxGapBytes ?? 16384;
    this.onLoad = options.onLoad ?? (() => null);
    this.onEvict = options.onEvict ?? (() => {});
    this.onChange = options.onChange ?? (() => {});
    const [x, y, z] = skeleton.header.min.map((m, k) => (m + skeleton.header.max[k]) / 2);
    /** Positions are drawn relative to this point (model units, f64), so large coordinates keep their precision. */
    this.localOrigin = options.localOrigin ?? [x, y, z];
    /** node → `{geometry, handle, bytes}`, least recently drawn first */
    this.cache = new Map();
    this.pending = new Set();
    this.inFlight = 0;
    this.residentBytes = 0;
    this.peakResidentBytes = 0;
    this.frame = 0;
    this.front = [];
    this.culled = [];
    this.drawn = [];
    this.missing = [];
    this.error = null;
  }

  /** Decode and check node i from its bytes and keep it. */
  insert(i, bytes) {
    if (this.cache.has(i)) return;
    const geometry = decodeNode(this.skeleton, i, bytes, { localOrigin: this.localOrigin });
    const size = recordBytes(this.skeleton, i);
    const handle = this.onLoad(i, geometry);
    // What picking needs stays on this side; the rest lives in the renderer's buffers.
    const kept = { local: geometry.local, positions: geometry.local ? null : geometry.positions, indices: geometry.indices, materialRanges: geometry.materialRanges };
    this.cache.set(i, { geometry: kept, handle, bytes: size });
    this.residentBytes += size;
    this.peakResidentBytes = Math.max(this.peakResidentBytes, this.residentBytes);
  }

  limits() {
    return { pixelError: this.pixelError, maxFaces: this.maxFaces, maxBytes: this.budget, priority: this.priority };
  }

  /**
   * Select the front for `camera` and start the reads it lacks; return the nodes to draw now: the
   * same selection with every node held whose visible children are not all resident, so what is
   * drawn is always a front by the rule, coarser where data is missing, never a hole.
   */
  update(camera) {
    const s = this.skeleton;
    this.frame++;
    const limits = this.limits();
    // The top level stays resident (it stands in for everything): the front gets what it leaves.
    limits.maxBytes -= this.topBytes;
    const planes = camera.frustum();
    const cut = this.selector.select(camera, limits);
    this.front = cut.shown;
    this.culled = cut.culled;
    this.faces = cut.faces;
    this.missing = cut.shown.filter((i) => !this.cache.has(i));
    let drawn = cut.shown;
    if (this.missing.length > 0) {
      const waiting = {
        has: (i) => {
          const [c0, c1] = s.children(i);
          for (let c = c0; c < c1; c++) if (!this.cache.has(c) && sees(s, c, camera, planes)) return true;
          return false;
        },
      };
      drawn = this.drawSelector.select(camera, limits, waiting).shown;
    }
    this.drawn = drawn;
    // Drawn nodes and their ancestors become the most recently used, ancestors first, so that
    // moving away finds the coarser nodes still resident.
    for (const i of drawn) {
      const chain = [];
      for (let a = s.parent[i]; a !== NO_PARENT && this.touched[a] !== this.frame; a = s.parent[a]) chain.push(a);
      for (let k = chain.length - 1; k >= 0; k--) this.touch(chain[k]);
      this.touch(i);
    }
    this.request();
    this.evict();
    return this.drawn;
  }

  /** Move node i to the recent end of the cache's order (a Map keeps insertion order: the LRU list). */
  touch(i) {
    this.touched[i] = this.frame;
    const e = this.cache.get(i);
    if (!e) return;
    this.cache.delete(i);
    this.cache.set(i, e);
  }

  /** Start reads of missing front nodes, coarsest first, consecutive nodes in one range. */
  request() {
    const s = this.skeleton;
    if (performance.now() < this.retryAt) return;
    const queue = this.missing.filter((i) => !this.pending.has(i));
    let k = 0;
    while (this.inFlight < this.maxInFlight && k < queue.length && !this.error && !this.closed) {
      // Nodes lie in the file in id order: one range takes the next missing ones while the bytes
      // between them (other nodes' geometry, read and dropped) stay under maxGapBytes.
      const first = queue[k];
      const nodes = [first];
      let last = first;
      k++;
      while (
        k < queue.length &&
        s.offset[queue[k]] - (s.offset[last] + s.size[last]) <= this.maxGapBytes &&
        s.offset[queue[k]] + s.size[queue[k]] - s.offset[first] <= this.maxRequestBytes
      ) {
        last = queue[k++];
        nodes.push(last);
      }
      for (const i of nodes) this.pending.add(i);
      this.inFlight++;
      const start = s.offset[first];
      this.source
        .read(start, s.offset[last] + s.size[last])
        .then((bytes) => {
          if (this.closed) return;
          for (const i of nodes) {
            const at = s.offset[i] - start;
            if (at + s.size[i] > bytes.length) throw new FormatError(`node ${i}: the file ends before its geometry (byte ${s.offset[i] + s.size[i]})`);
            this.insert(i, bytes.subarray(at, at + s.size[i]));
          }
          this.failures = 0;
          this.evict();
        })
        .catch((e) => {
          // A file that breaks a rule is never drawn from; a failed read is tried again a few times.
          if (e instanceof FormatError || ++this.failures > 3) this.error = e;
          else {
            const delay = 500 * 2 ** this.failures;
            this.retryAt = performance.now() + delay;
            setTimeout(() => !this.closed && this.onChange(), delay);
          }
        })
        .finally(() => {
          for (const i of nodes) this.pending.delete(i);
          this.inFlight--;
          if (!this.closed) this.onChange();
        });
    }
  }

  /** Drop least-recently drawn nodes, neither drawn nor in the front nor of the top level, while over the budget. */
  evict() {
    if (this.residentBytes <= this.budget) return;
    const s = this.skeleton;
    const [top0, top1] = s.levelNodes(s.top());
    const keep = new Set([...this.drawn, ...this.front]);
    for (const [i, e] of this.cache) {
      if (this.residentBytes <= this.budget) break;
      if (keep.has(i) || (i >= top0 && i < top1)) continue;
      this.onEvict(i, e.handle);
      this.cache.delete(i);
      this.residentBytes -= e.bytes;
    }
  }

  /** Release everything; reads still in flight are dropped when they land. */
  close() {
    this.closed = true;
    for (const [i, e] of this.cache) this.onEvict(i, e.handle);
    this.cache.clear();
    this.residentBytes = 0;
  }

  /** Nothing missing and nothing in flight: the drawn nodes are the selected front. */
  idle() {
    return this.missing.length === 0 && this.inFlight === 0;
  }

  geometry(i) {
    return this.cache.get(i)?.geometry;
  }

  handle(i) {
    return this.cache.get(i)?.handle;
  }
}
