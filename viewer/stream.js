// The viewer's streaming: open a chunk file in as few round trips as its layout allows, then per
// frame select the front (select.js), draw what is resident, and read what is missing, coarsest
// first, a few requests at a time, within a memory budget kept by least-recently-used eviction.
//
// Opening: one read of the first `prefix` bytes (16 KB) tells where the skeleton ends and, from
// the skeleton's level table, where the top level's geometry ends; a second read fetches the rest
// of both. So the first frame needs two round trips (one when the file is smaller than the prefix).
//
// While a node of the front is not resident, its nearest resident ancestor stands in for it (and
// for its siblings, so nothing is drawn twice); when the camera moves away and a coarser node is
// not resident yet, its resident descendants drawn last frame stand in. The screen never goes
// blank where it showed something, and coarse always comes before fine.

import { FormatError, decodeNode, decodeSkeleton, openingRange } from './format.js';
import { Selector, recordBytes } from './select.js';

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
   * `maxRequestBytes`, `pixelError`, `maxFaces`, `priority`, `onLoad(i, geometry)` → a handle
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
    this.budget = options.budget ?? 512 * 2 ** 20;
    this.pixelError = options.pixelError ?? 2;
    this.maxFaces = options.maxFaces;
    this.priority = options.priority ?? 'error';
    this.maxInFlight = options.maxInFlight ?? 4;
    this.maxRequestBytes = options.maxRequestBytes ?? 1 << 20;
    this.onLoad = options.onLoad ?? (() => null);
    this.onEvict = options.onEvict ?? (() => {});
    this.onChange = options.onChange ?? (() => {});
    const [x, y, z] = skeleton.header.min.map((m, k) => (m + skeleton.header.max[k]) / 2);
    /** Positions are drawn relative to this point (model units, f64), so large coordinates keep their precision. */
    this.localOrigin = options.localOrigin ?? [x, y, z];
    /** node → `{geometry, handle, bytes, used}` */
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
    this.cache.set(i, { geometry, handle: this.onLoad(i, geometry), bytes: size, used: this.frame });
    this.residentBytes += size;
    this.peakResidentBytes = Math.max(this.peakResidentBytes, this.residentBytes);
  }

  limits() {
    return { pixelError: this.pixelError, maxFaces: this.maxFaces, maxBytes: this.budget, priority: this.priority };
  }

  /** Select the front for `camera`, decide what to draw now, start the reads it lacks. Returns the nodes to draw. */
  update(camera) {
    const s = this.skeleton;
    this.frame++;
    const cut = this.selector.select(camera, this.limits());
    this.front = cut.shown;
    this.culled = cut.culled;
    this.faces = cut.faces;
    const draw = new Set();
    const missing = cut.shown.filter((i) => !this.cache.has(i));
    const missingSet = new Set(missing);
    // Zooming out: a coarser node not yet resident keeps what was drawn beneath it last frame.
    const keptBelow = new Set(), covered = new Set();
    for (const d of this.drawn) {
      if (!this.cache.has(d)) continue;
      for (let a = s.parent[d]; a !== NO_PARENT; a = s.parent[a]) {
        if (missingSet.has(a)) {
          keptBelow.add(d);
          covered.add(a);
          break;
        }
      }
    }
    // Zooming in: the nearest resident ancestor stands in for a node not yet resident.
    const standIns = new Set();
    for (const i of missing) {
      if (covered.has(i)) continue;
      let a = s.parent[i];
      while (a !== NO_PARENT && !this.cache.has(a)) a = s.parent[a];
      if (a !== NO_PARENT) standIns.add(a);
    }
    const under = (i, set) => {
      for (let a = s.parent[i]; a !== NO_PARENT; a = s.parent[a]) if (set.has(a)) return true;
      return false;
    };
    for (const i of cut.shown) if (this.cache.has(i) && !under(i, standIns)) draw.add(i);
    for (const a of standIns) if (!under(a, standIns)) draw.add(a);
    for (const d of keptBelow) if (!under(d, standIns)) draw.add(d);
    this.drawn = [...draw].sort((a, b) => a - b);
    for (const i of this.drawn) this.cache.get(i).used = this.frame;
    this.missing = missing;
    this.request();
    this.evict();
    return this.drawn;
  }

  /** Start reads of missing front nodes, coarsest first, consecutive nodes in one range. */
  request() {
    const s = this.skeleton;
    const queue = this.missing.filter((i) => !this.pending.has(i));
    let k = 0;
    while (this.inFlight < this.maxInFlight && k < queue.length && !this.error) {
      const first = queue[k];
      let last = first;
      k++;
      while (k < queue.length && queue[k] === last + 1 && s.offset[queue[k]] + s.size[queue[k]] - s.offset[first] <= this.maxRequestBytes) last = queue[k++];
      const nodes = [];
      for (let i = first; i <= last; i++) {
        nodes.push(i);
        this.pending.add(i);
      }
      this.inFlight++;
      const start = s.offset[first];
      this.source
        .read(start, s.offset[last] + s.size[last])
        .then((bytes) => {
          for (const i of nodes) {
            const at = s.offset[i] - start;
            if (at + s.size[i] > bytes.length) throw new FormatError(`node ${i}: the file ends before its geometry (byte ${s.offset[i] + s.size[i]})`);
            this.insert(i, bytes.subarray(at, at + s.size[i]));
          }
          this.evict();
        })
        .catch((e) => {
          this.error = e;
        })
        .finally(() => {
          for (const i of nodes) this.pending.delete(i);
          this.inFlight--;
          this.onChange();
        });
    }
  }

  /** Drop least-recently drawn nodes not in the front while over the budget. */
  evict() {
    if (this.residentBytes <= this.budget) return;
    const keep = new Set([...this.drawn, ...this.front]);
    const victims = [...this.cache.entries()].filter(([i]) => !keep.has(i)).sort((a, b) => a[1].used - b[1].used);
    for (const [i, e] of victims) {
      if (this.residentBytes <= this.budget) break;
      this.onEvict(i, e.handle);
      this.cache.delete(i);
      this.residentBytes -= e.bytes;
    }
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
