// The viewer's streaming: open a chunk file in as few round trips as its layout allows, then per
// frame select the front (select.js), draw what is resident, and read what is missing, coarsest
// first, a few requests at a time, within a memory budget kept by least-recently-used eviction.
//
// Opening: one read of the first `prefix` bytes (16 KB) tells where the skeleton ends and, from
// the skeleton's level table, where the top level's geometry ends; a second read fetches the rest
// of both. So the first frame needs two round trips (one when the file is smaller than the prefix).
//
// What is drawn is always a front by the rule: the same selection, with every node held whose
// visible children are not all resident yet (format 4: every group, selection.md §9). So a view
// refines level by level as data arrives, coarse before fine, never with a hole; the top level
// stays resident to stand in for anything. Drawn nodes and their ancestors (format 4: the
// outputs of the groups above them) are the most recently used, so moving away finds coarser
// nodes still resident. A tree's fronts are sealed between levels (selection.md §8); a DAG's
// shown nodes meet edge for edge and need no seams.
//
// Images (format 2.2, selection.md §4): once the drawn nodes' geometry is resident, their material
// ranges tell which images they sample; each image gets the level its most demanding drawn node
// needs. At the first textured frame one range fetches the coarsest level of every image the
// materials use, which stays resident (it stands in for any finer level until that arrives); then
// wanted levels are read as they change (where the budget lacks room for one, the finest coarser
// level that fits). Decoded levels count 4·w·h bytes against the same budget as the geometry and
// are evicted with it, least recently used first.

import { FormatError, IMAGE_MIME, MAP_KINDS, completeSkeleton, isComplete, skeletonNeeds, decodeImageLevel, decodeNode, decodePlanes, decodeSkeleton, openingRange, planesOffset } from './format.js';
import { Orderer } from './order.js';
import { NodeDecodeError } from './decoder.js';
import { Selector, recordBytes, sees } from './select.js';
import { length, sub } from './camera.js';
import { border, seams, takingPart } from './seams.js';

const NO_PARENT = 0xffffffff;

function concat(a, b) {
  const c = new Uint8Array(a.length + b.length);
  c.set(a);
  c.set(b, a.length);
  return c;
}

/** Node i's bytes within `bytes`, read from file offset `start`. */
function nodeIn(s, i, bytes, start) {
  const at = s.offset[i] - start;
  if (at + s.size[i] > bytes.length) throw new FormatError(`node ${i}: the file ends before its geometry (byte ${s.offset[i] + s.size[i]})`);
  return bytes.subarray(at, at + s.size[i]);
}

/** Bytes a decoded image level counts against the memory budget (RGBA8, selection.md §4). */
export const levelBytes = (entry) => 4 * entry.width * entry.height;

/**
 * The level of `image` a node needs (selection.md §4) where a model unit spans `pixelsPerUnit`
 * pixels and `density` UV units: the largest level whose geometric-mean side reaches
 * `pixelsPerUnit / density` texels, or 0 when even level 0 has fewer.
 */
export function neededLevel(skeleton, image, pixelsPerUnit, density) {
  const { images, levels } = skeleton.textures;
  const entries = images[image].levels;
  const texels = pixelsPerUnit / density;
  for (let l = entries.length - 1; l > 0; l--) {
    const v = levels[entries[l]];
    if (Math.sqrt(v.width * v.height) >= texels) return l;
  }
  return 0;
}

/**
 * Each image's wanted level for the displayed nodes `nodes` (selection.md §4): the finest level any
 * of them needs, over the maps of kinds `kinds` of the materials `materialsOf(i)` lists for node i
 * (its geometry's material ranges; null while its geometry is not known). A node of UV density 0
 * needs none. Returns a Map image → level, images ascending.
 */
export function wantedLevels(skeleton, nodes, materialsOf, camera, kinds = MAP_KINDS) {
  const s = skeleton;
  const wanted = new Map();
  for (const i of nodes) {
    const d = s.textures.uvDensity[i];
    if (!(d > 0)) continue;
    const materials = materialsOf(i);
    if (!materials) continue;
    const o = [s.center[3 * i], s.center[3 * i + 1], s.center[3 * i + 2]];
    const pixels = camera.pixelsPerUnit(Math.max(length(sub(camera.eye, o)) - s.radius[i], 0));
    for (const m of materials) {
      const maps = s.materials[m]?.maps;
      if (!maps) continue;
      for (const kind of kinds) {
        const slot = maps[kind];
        if (!slot) continue;
        const l = neededLevel(s, slot.image, pixels, d);
        if (!(wanted.get(slot.image) <= l)) wanted.set(slot.image, l);
      }
    }
  }
  return new Map([...wanted].sort((a, b) => a[0] - b[0]));
}

/** Images the materials map in slots of `kinds`, ascending; none in a file without UVs (nothing is mapped). */
export function usedImages(skeleton, kinds = MAP_KINDS) {
  if (!skeleton.header.attributes.uvs) return [];
  const used = new Set();
  for (const m of skeleton.materials) for (const kind of kinds) if (m.maps?.[kind]) used.add(m.maps[kind].image);
  return [...used].sort((a, b) => a - b);
}

export class Streamer {
  /**
   * Open `source` (source.js): read the skeleton and the top level, check and decode the top two
   * levels' records and the top level's geometry (the rest of the node table by the second update).
   * `options`: `prefix` (first read, bytes), `budget` (resident bytes), `maxInFlight`,
   * `maxRequestBytes`, `maxGapBytes` (bytes of other nodes a range may span), `sliceMs` (the longest run of node decoding
   * on this thread before the nodes left wait for the next task), `yieldTask()` (how they wait: a promise, by default of
   * a `setTimeout` of 0), `pixelError`, `maxFaces`, `priority`, `onLoad(i, geometry)` → a handle
   * kept with the node (the renderer's buffers), `onEvict(i, handle)`, `onChange()`; for images, `maps` (the map kinds
   * drawn, whose images are read: `['baseColor']`), `onImage(image, level, fileBytes, mime)` → a handle or a promise of
   * one (the renderer's texture; a rejection leaves that level out), `onImageEvict(image, level, handle)`; `decoder`:
   * a DecoderPool (decoder.js) that decodes nodes below the top level off the main thread (the streamer closes it).
   */
  static async open(source, options = {}) {
    try {
      return await Streamer.#open(source, options);
    } catch (e) {
      options.decoder?.close();
      throw e;
    }
  }

  static async #open(source, options) {
    const t0 = performance.now();
    const prefix = options.prefix ?? 16384;
    let bytes = await source.read(0, prefix);
    let range = openingRange(bytes, source.length);
    // Up to the skeleton's end, or in format 3 the end of its top pages (strata-v3.md §1.1).
    while (range.need !== undefined || (range.pagesEnd === undefined && bytes.length < range.skeletonEnd)) {
      if (bytes.length >= (source.length ?? Infinity)) throw new FormatError(`${source.name}: the file ends at byte ${bytes.length}, before its skeleton`);
      // A sub-chunk larger than the prefix (TEXR: 2 bytes a node) is stepped over in one read.
      const from = Math.max(bytes.length, range.nextFrame ?? 0);
      const end = range.need !== undefined ? Math.max(range.need, bytes.length + prefix) : Math.min(range.skeletonEnd, from + prefix);
      bytes = concat(bytes, await source.read(bytes.length, end));
      range = openingRange(bytes, source.length);
    }
    const pagesEnd = range.pagesEnd ?? range.skeletonEnd;
    // The top level's geometry: with the pages in one read, or beside them in a second read at the
    // same time when the rest of the skeleton lies between.
    let geo = { at: 0, bytes };
    if (range.topEnd !== undefined && range.skeletonEnd - Math.max(bytes.length, pagesEnd) > (options.maxGapBytes ?? 16384)) {
      const [pages, top] = await Promise.all([bytes.length < pagesEnd ? source.read(bytes.length, pagesEnd) : null, source.read(range.skeletonEnd, range.topEnd)]);
      if (pages) bytes = concat(bytes, pages);
      geo = { at: range.skeletonEnd, bytes: top };
    } else {
      const want = Math.max(range.topEnd ?? 0, pagesEnd);
      if (bytes.length < want) bytes = concat(bytes, await source.read(bytes.length, want));
      geo = { at: 0, bytes };
    }
    // The first frame shows the top level: the rest of the node table is checked and decoded by
    // the second update (selection.md §6), once the rest of the skeleton is read.
    const skeleton = decodeSkeleton(bytes, source.length, { topFirst: true });
    const s = new Streamer(source, skeleton, options);
    if (skeletonNeeds(skeleton) > bytes.length) s.skeletonPrefix = bytes;
    // The workers decode their own skeleton from the same bytes while the top level is decoded here.
    s.decoder?.open(bytes, source.length, s.localOrigin);
    const [top0, top1] = skeleton.levelNodes(skeleton.top());
    const topStart = skeleton.offset[top0], topEnd = skeleton.offset[top1 - 1] + skeleton.size[top1 - 1];
    if (!(topStart >= geo.at && topEnd <= geo.at + geo.bytes.length)) {
      geo = topStart >= bytes.length ? { at: topStart, bytes: await source.read(topStart, topEnd) } : { at: 0, bytes: (bytes = concat(bytes, await source.read(bytes.length, topEnd))) };
    }
    for (let i = top0; i < top1; i++) s.insert(i, geo.bytes.subarray(skeleton.offset[i] - geo.at, skeleton.offset[i] - geo.at + skeleton.size[i]));
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
    this.sliceMs = options.sliceMs ?? 8;
    this.yieldTask = options.yieldTask ?? (() => new Promise((r) => setTimeout(r, 0)));
    /** Nodes waiting to be decoded on this thread (decodeSliced), and whether their loop runs. */
    this.sliced = [];
    this.slicing = false;
    this.decoder = options.decoder ?? null;
    /** Why decoding moved back to the main thread (a worker failed), or null. */
    this.decoderError = null;
    /** Nodes decoded on the main thread (the top level at open, and all others without a decoder), and the time it took. */
    this.mainDecoded = 0;
    this.mainDecodeMs = 0;
    this.onLoad = options.onLoad ?? (() => null);
    this.onEvict = options.onEvict ?? (() => {});
    /** The fill of the seams between the drawn nodes' levels (selection.md §8), and a count of its changes. */
    this.seams = null;
    this.seamsVersion = 0;
    this.seamNodes = '';
    this.onChange = options.onChange ?? (() => {});
    this.maps = options.maps ?? ['baseColor'];
    this.onImage = options.onImage ?? (() => null);
    this.onImageEvict = options.onImageEvict ?? (() => {});
    const t = skeleton.textures;
    /** Images the drawn map kinds use; their coarsest levels stay resident from the first textured frame on. */
    this.usedImages = usedImages(skeleton, this.maps);
    this.coarsest = this.usedImages.map((image) => t.images[image].levels.at(-1));
    this.pinnedBytes = this.coarsest.reduce((sum, e) => sum + levelBytes(t.levels[e]), 0);
    /** level entry → `{image, level, handle, bytes, used}` (used: the last frame that drew or wanted it), least recently used first */
    this.levelCache = new Map();
    this.levelPending = new Set();
    /** level entry → why the renderer could not take it (coarser levels stand in, or none: drawn untextured) */
    this.imageErrors = new Map();
    /** Per image the drawn nodes use: its wanted level, the level read for it (coarser when the budget lacks room) and the entry drawn. */
    this.imagePlan = new Map();
    /** Level entries the plan lacks: reads to make. */
    this.imageMissing = [];
    this.textureBytesRead = 0;
    this.textureResidentBytes = 0;
    this.textureRequests = 0;
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
    /** The drawn nodes from front to back (selection.md §5), the order to draw them in. */
    this.drawOrder = [];
    /** Until the separating planes are read (once the first front is loaded), the nearest box goes first. */
    this.orderer = new Orderer(skeleton, { starts: [], entries: [] });
    this.planes = 'unread';
    this.planesError = null;
    this.missing = [];
    this.error = null;
    /** A format-3 skeleton opened from its top pages: the bytes read, until the rest of SKEL is (skeletonBytes). */
    this.skeletonPrefix = null;
    this.skeletonBytes = null;
  }

  /**
   * Read the separating planes (ORDR, the file's last chunk) in the background; a bad chunk only
   * leaves the order without them (planesError says why). Format 4 has none: one there is refused.
   */
  async readPlanes() {
    const at = planesOffset(this.skeleton), end = this.source.length;
    if (this.skeleton.dag) return this.refusePlanes(at, end);
    // Planes came with format 2.3; every format-3 file may have them.
    if (!(end >= at + 16) || (this.skeleton.major < 3 && this.skeleton.minor < 3)) {
      this.planes = 'none';
      return;
    }
    this.planes = 'reading';
    this.inFlight++;
    try {
      // The frame, then the chunk alone; anything but ORDR there means no planes.
      const frame = await this.source.read(at, at + 16);
      const dv = new DataView(frame.buffer, frame.byteOffset, frame.byteLength);
      if (String.fromCharCode(...frame.subarray(0, 4)) !== 'ORDR') {
        this.planes = 'none';
        return;
      }
      const span = 16 + Number(dv.getBigUint64(8, true)) + 4;
      if (!(at + span <= end)) throw new FormatError(`${this.source.name}: byte offset ${at + 8}: chunk ORDR at offset ${at}: size runs past the end of the file`);
      const bytes = await this.source.read(at, at + span);
      const planes = decodePlanes(this.skeleton, bytes);
      if (this.closed) return;
      this.orderer = new Orderer(this.skeleton, planes);
      this.planes = `${planes.entries.length} planes`;
    } catch (e) {
      this.planes = 'failed';
      this.planesError = `${this.source.name}: the drawing order's planes: ${e.message}`;
    } finally {
      this.inFlight--;
    }
    if (!this.closed) this.onChange();
  }

  /**
   * Format 4 (strata-v4.md §0): an ORDR chunk after the geometry makes the file refused; anything
   * else there is no planes. A failed read only leaves that unchecked (planesError says why).
   */
  async refusePlanes(at, end) {
    this.planes = 'none';
    if (!(end >= at + 4)) return;
    this.inFlight++;
    try {
      const id = await this.source.read(at, at + 4);
      if (!this.closed && String.fromCharCode(...id.subarray(0, 4)) === 'ORDR') {
        this.error = new FormatError(`${this.source.name}: byte offset ${at}: an ORDR chunk in a format-4 file, which has no separating planes (strata-v4.md §0)`, { offset: at });
      }
    } catch (e) {
      this.planes = 'failed';
      this.planesError = `${this.source.name}: the bytes after the geometry: ${e.message}`;
    } finally {
      this.inFlight--;
    }
    if (!this.closed) this.onChange();
  }

  /** The whole node table decoded now, reading the rest of the skeleton first if need be (for callers that need every node). */
  async loadSkeleton() {
    if (isComplete(this.skeleton)) return;
    if (this.skeletonPrefix) await this.readSkeletonRest();
    if (this.error) throw this.error;
    this.completeTable();
  }

  /** Decode the rest of the node table (its bytes read), here and in the decoder's workers. */
  completeTable() {
    if (isComplete(this.skeleton)) return;
    completeSkeleton(this.skeleton, this.skeletonBytes);
    this.decoder?.complete(this.skeletonBytes);
    this.skeletonBytes = null;
  }

  /** Read the rest of a skeleton opened from its top pages (format 3), after the first frame: one read, however often asked. */
  readSkeletonRest() {
    return (this.restRead ??= this.readRest());
  }

  async readRest() {
    const prefix = this.skeletonPrefix, end = skeletonNeeds(this.skeleton);
    this.inFlight++;
    try {
      for (;;) {
        try {
          this.skeletonBytes = concat(prefix, await this.source.read(prefix.length, end));
          break;
        } catch (e) {
          if (++this.failures > 3 || this.closed) throw e;
          await new Promise((r) => setTimeout(r, 500 * 2 ** this.failures));
        }
      }
      this.failures = 0;
      this.skeletonPrefix = null;
    } catch (e) {
      this.error = e;
    } finally {
      this.inFlight--;
    }
    if (!this.closed) this.onChange();
  }

  /** Decode and check node i from its bytes and keep it. */
  insert(i, bytes) {
    if (this.cache.has(i)) return;
    this.keep(i, this.decodeHere(i, bytes));
  }

  /** Node i decoded and checked on this thread, counted. */
  decodeHere(i, bytes) {
    const t0 = performance.now();
    const geometry = decodeNode(this.skeleton, i, bytes, { localOrigin: this.localOrigin });
    this.mainDecodeMs += performance.now() - t0;
    this.mainDecoded++;
    return geometry;
  }

  /** Keep node i, decoded and checked. */
  keep(i, geometry) {
    if (this.cache.has(i)) return;
    const s = this.skeleton, size = recordBytes(s, i);
    // The node's open border for the seams: made by the decoding worker, else here where the
    // normals still are. A DAG has no seams.
    const edge = s.dag ? null : geometry.border ?? border(s.level[i], s.error[i], geometry);
    delete geometry.border;
    const handle = this.onLoad(i, geometry);
    // What picking needs stays on this side, with the border; the rest lives in the renderer's buffers.
    const kept = { local: geometry.local, positions: geometry.local ? null : geometry.positions, indices: geometry.indices, materialRanges: geometry.materialRanges };
    this.cache.set(i, { geometry: kept, handle, bytes: size, border: edge });
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
    if (!isComplete(s)) {
      if (this.frame === 1) {
        setTimeout(() => !this.closed && (this.skeletonPrefix ? this.readSkeletonRest() : this.onChange()), 0);
      } else if (!this.skeletonPrefix) {
        try {
          this.completeTable();
        } catch (e) {
          this.error = e;
          return this.drawn;
        }
      }
    }
    const limits = this.limits();
    // The top level and the images' coarsest levels stay resident (they stand in for everything):
    // the front gets what they leave.
    limits.maxBytes -= this.topBytes + this.pinnedBytes;
    const planes = camera.frustum();
    const cut = this.selector.select(camera, limits);
    this.front = cut.shown;
    this.culled = cut.culled;
    this.faces = cut.faces;
    this.missing = cut.shown.filter((i) => !this.cache.has(i));
    let drawn = cut.shown;
    if (this.missing.length > 0) {
      // Held: a node (format 4: a group) with a visible child not resident.
      const waiting = {
        has: s.dag
          ? (g) => s.dag.childrenOf(g).some((c) => !this.cache.has(c) && sees(s, c, camera, planes))
          : (i) => {
            const [c0, c1] = s.children(i);
            for (let c = c0; c < c1; c++) if (!this.cache.has(c) && sees(s, c, camera, planes)) return true;
            return false;
          },
      };
      drawn = this.drawSelector.select(camera, limits, waiting).shown;
    }
    this.drawn = drawn;
    this.drawOrder = this.orderer.order(drawn, camera);
    if (!s.dag) this.sealSeams(drawn);
    // Drawn nodes and their ancestors become the most recently used, ancestors first, so that
    // moving away finds the coarser nodes still resident.
    if (s.dag) this.touchAbove(drawn);
    for (const i of drawn) {
      const chain = [];
      for (let a = s.parent[i]; a !== NO_PARENT && this.touched[a] !== this.frame; a = s.parent[a]) chain.push(a);
      for (let k = chain.length - 1; k >= 0; k--) this.touch(chain[k]);
      this.touch(i);
    }
    // Image levels lie after the geometry, where the level totals say: read once they are checked.
    if (isComplete(s)) this.planImages(camera);
    this.requestImages(true);
    this.request();
    this.requestImages(false);
    this.evict();
    // The planes only reorder what is drawn: they are read once nothing else is wanted.
    if (this.planes === 'unread' && this.idle()) this.readPlanes();
    return this.drawn;
  }

  /**
   * Format 4: touch the nodes above `drawn`, the outputs of their consumers and of those outputs'
   * consumers up to the top, coarsest first (nodes are numbered top level first).
   */
  touchAbove(drawn) {
    const d = this.skeleton.dag;
    const groups = new Set();
    const stack = [];
    for (const i of drawn) stack.push(d.consumer[i]);
    while (stack.length > 0) {
      const g = stack.pop();
      if (g === NO_PARENT || groups.has(g)) continue;
      groups.add(g);
      const [o0, o1] = d.outputsOf(g);
      for (let o = o0; o < o1; o++) stack.push(d.consumer[o]);
    }
    const above = [];
    for (const g of groups) {
      const [o0, o1] = d.outputsOf(g);
      for (let o = o0; o < o1; o++) above.push(o);
    }
    above.sort((a, b) => a - b);
    for (const o of above) this.touch(o);
  }

  /**
   * Per image the drawn nodes use: the wanted level; the level to hold, the finest from the wanted
   * one up whose bytes fit what the budget leaves after the geometry the front and the drawn nodes
   * keep and the coarsest levels (images in order); and the level to draw, the finest resident at
   * or above that one.
   */
  planImages(camera) {
    this.imagePlan = new Map();
    this.imageMissing = [];
    if (this.usedImages.length === 0) return;
    const s = this.skeleton, t = s.textures;
    const materialsOf = (i) => this.cache.get(i)?.geometry.materialRanges.map((r) => r[0]) ?? null;
    const wanted = wantedLevels(s, this.drawn, materialsOf, camera, this.maps);
    if (wanted.size === 0) return;
    const [top0, top1] = s.levelNodes(s.top());
    let room = this.budget - this.topBytes - this.pinnedBytes;
    for (const i of new Set([...this.front, ...this.drawn])) if (i < top0 || i >= top1) room -= recordBytes(s, i);
    // From the first textured frame on, every used image's coarsest level is read and kept.
    for (const e of this.coarsest) if (!this.levelCache.has(e) && !this.imageErrors.has(e)) this.imageMissing.push(e);
    for (const [image, want] of wanted) {
      const entries = t.images[image].levels;
      const last = entries.length - 1;
      let hold = last;
      for (let l = want; l < last; l++) {
        const bytes = levelBytes(t.levels[entries[l]]);
        if (bytes <= room && !this.imageErrors.has(entries[l])) {
          hold = l;
          room -= bytes;
          break;
        }
      }
      if (hold < last && !this.levelCache.has(entries[hold])) this.imageMissing.push(entries[hold]);
      let drawn = null;
      for (let l = hold; l <= last && drawn === null; l++) if (this.levelCache.has(entries[l])) drawn = entries[l];
      for (const e of [entries[hold], drawn]) this.touchLevel(e);
      this.imagePlan.set(image, { wanted: want, hold, drawn });
    }
    this.imageMissing.sort((a, b) => a - b);
  }

  /** Mark level entry e used this frame: the recent end of the level cache's order. */
  touchLevel(e) {
    const v = this.levelCache.get(e);
    if (!v) return;
    v.used = this.frame;
    this.levelCache.delete(e);
    this.levelCache.set(e, v);
  }

  /**
   * Start reads of missing image levels in file order, adjacent levels in one range: with `coarse`,
   * the coarsest levels (one range where they lie together, as writers lay them out, whatever its
   * size); otherwise, once those are resident, the levels held for the wanted ones.
   */
  requestImages(coarse) {
    const s = this.skeleton, t = s.textures;
    if (this.imageMissing.length === 0 || performance.now() < this.retryAt) return;
    const isCoarse = (e) => t.levels[e].level === t.images[t.levels[e].image].levels.length - 1;
    // Finer levels wait until every coarsest one is resident.
    if (!coarse && this.imageMissing.some(isCoarse)) return;
    const queue = this.imageMissing.filter((e) => isCoarse(e) === coarse && !this.levelPending.has(e));
    const end = (e) => t.levels[e].offset + t.levels[e].size;
    let k = 0;
    while (this.inFlight < this.maxInFlight && k < queue.length && !this.error && !this.closed) {
      const first = queue[k++];
      const entries = [first];
      let last = first;
      while (
        k < queue.length &&
        t.levels[queue[k]].offset - end(last) <= this.maxGapBytes &&
        (coarse || end(queue[k]) - t.levels[first].offset <= this.maxRequestBytes)
      ) {
        last = queue[k++];
        entries.push(last);
      }
      this.readLevels(entries, t.levels[first].offset, end(last));
    }
  }

  /** Read bytes [start, end) holding level entries `entries`, check each level and hand it to the renderer. */
  readLevels(entries, start, end) {
    const s = this.skeleton, t = s.textures;
    for (const e of entries) this.levelPending.add(e);
    this.inFlight++;
    this.textureRequests++;
    this.source
      .read(start, end)
      .then(async (bytes) => {
        if (this.closed) return;
        this.textureBytesRead += bytes.length;
        const files = entries.map((e) => {
          const lv = t.levels[e];
          const at = lv.offset - start;
          if (at + lv.size > bytes.length) {
            throw new FormatError(`image ${lv.image} level ${lv.level}: the file ends before it (byte ${lv.offset + lv.size})`);
          }
          return decodeImageLevel(s, e, bytes.subarray(at, at + lv.size));
        });
        await Promise.all(
          entries.map(async (e, k) => {
            const lv = t.levels[e];
            let handle;
            try {
              handle = await this.onImage(lv.image, lv.level, files[k], IMAGE_MIME[t.images[lv.image].codec]);
            } catch (err) {
              this.imageErrors.set(e, `image ${lv.image} (${t.images[lv.image].name}) level ${lv.level}: ${err?.message ?? err}`);
              return;
            }
            if (this.closed) return this.onImageEvict(lv.image, lv.level, handle);
            this.insertLevel(e, handle);
          }),
        );
        this.failures = 0;
        this.evict();
      })
      .catch((e) => {
        if (e instanceof FormatError || ++this.failures > 3) this.error = e;
        else {
          const delay = 500 * 2 ** this.failures;
          this.retryAt = performance.now() + delay;
          setTimeout(() => !this.closed && this.onChange(), delay);
        }
      })
      .finally(() => {
        for (const e of entries) this.levelPending.delete(e);
        this.inFlight--;
        if (!this.closed) this.onChange();
      });
  }

  /** Keep level entry e, decoded by the renderer into `handle`. */
  insertLevel(e, handle) {
    const lv = this.skeleton.textures.levels[e];
    if (this.levelCache.has(e)) return this.onImageEvict(lv.image, lv.level, handle);
    const bytes = levelBytes(lv);
    this.levelCache.set(e, { image: lv.image, level: lv.level, handle, bytes, used: 0 });
    this.textureResidentBytes += bytes;
    this.residentBytes += bytes;
    this.peakResidentBytes = Math.max(this.peakResidentBytes, this.residentBytes);
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
        .then(async (bytes) => {
          if (!(await this.decodeRange(nodes, bytes, start))) return;
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

  /**
   * Decode and keep `nodes`, read as `bytes` from offset `start`: in the decoder's workers, all at
   * once, or on this thread in the slices of decodeSliced; false if the streamer was
   * closed meanwhile.
   */
  async decodeRange(nodes, bytes, start) {
    const s = this.skeleton;
    const results = await Promise.allSettled(
      nodes.map(async (i) => {
        const own = nodeIn(s, i, bytes, start);
        let geometry = null;
        if (this.decoder) {
          try {
            geometry = await this.decoder.decode(i, own.slice());
          } catch (e) {
            if (this.closed) return;
            if (e instanceof FormatError) throw e;
            // An exception on this node alone is decoded here again (and met again, or not); a
            // worker that failed or went silent hands this node and the rest to this thread.
            if (this.decoder && !(e instanceof NodeDecodeError)) {
              this.decoderError = e.message;
              this.decoder.close();
              this.decoder = null;
            }
          }
        }
        if (this.closed) return;
        geometry ??= await this.decodeSliced(i, own);
        if (this.closed || !geometry) return;
        this.keep(i, geometry);
        this.onChange();
      }),
    );
    const failed = results.filter((r) => r.status === 'rejected').map((r) => r.reason);
    if (failed.length) throw failed.find((e) => e instanceof FormatError) ?? failed[0];
    return !this.closed;
  }

  /**
   * Node i decoded and checked on this thread, once the nodes asked before it are: one queue for
   * every range in flight, decoded in runs of at most `sliceMs` with a task between runs, so that
   * frames draw while a range (up to maxRequestBytes of nodes, tens of ms to decode) or the work a
   * failed worker pool hands back is decoded. Resolves to null if the streamer closes first.
   */
  decodeSliced(i, bytes) {
    return new Promise((resolve, reject) => {
      this.sliced.push({ i, bytes, resolve, reject });
      // Started after the caller's synchronous work, so that a range's nodes queue before any runs.
      if (!this.slicing) {
        this.slicing = true;
        queueMicrotask(() => this.runSlices());
      }
    });
  }

  async runSlices() {
    let slice = performance.now();
    try {
      while (this.sliced.length > 0) {
        if (this.closed) {
          for (const job of this.sliced.splice(0)) job.resolve(null);
          break;
        }
        const job = this.sliced.shift();
        try {
          job.resolve(this.decodeHere(job.i, job.bytes));
        } catch (e) {
          job.reject(e);
        }
        // At least one node a run, however short sliceMs is. Nodes kept so far may be evicted
        // before the next run, as the ranges they came in may finish much later.
        if (this.sliced.length > 0 && performance.now() - slice > this.sliceMs) {
          this.evict();
          // A yield that fails still yields: the queue must not stop with nodes in it.
          await Promise.resolve()
            .then(() => this.yieldTask())
            .catch(() => new Promise((r) => setTimeout(r, 0)));
          slice = performance.now();
        }
      }
    } finally {
      this.slicing = false;
    }
  }

  /**
   * While over the budget, drop what was least recently used, nodes and image levels alike, but
   * never the drawn nodes, the front, the top level, the image levels held or drawn, nor the
   * coarsest levels.
   */
  evict() {
    if (this.residentBytes <= this.budget) return;
    const s = this.skeleton;
    const [top0, top1] = s.levelNodes(s.top());
    const keep = new Set([...this.drawn, ...this.front]);
    const keepLevels = new Set(this.coarsest);
    const entries = s.textures.images.map((r) => r.levels);
    for (const [image, p] of this.imagePlan) keepLevels.add(entries[image][p.hold]).add(p.drawn);
    const nodes = this.cache.entries(), levels = this.levelCache.entries();
    const next = (it, skip) => {
      for (let n = it.next(); !n.done; n = it.next()) if (!skip(n.value[0])) return n.value;
      return null;
    };
    const skipNode = (i) => keep.has(i) || (i >= top0 && i < top1);
    const skipLevel = (e) => keepLevels.has(e);
    let node = next(nodes, skipNode), level = next(levels, skipLevel);
    while (this.residentBytes > this.budget && (node || level)) {
      if (node && (!level || this.touched[node[0]] <= level[1].used)) {
        const [i, e] = node;
        this.onEvict(i, e.handle);
        this.cache.delete(i);
        this.residentBytes -= e.bytes;
        node = next(nodes, skipNode);
      } else {
        const [e, v] = level;
        this.onImageEvict(v.image, v.level, v.handle);
        this.levelCache.delete(e);
        this.residentBytes -= v.bytes;
        this.textureResidentBytes -= v.bytes;
        level = next(levels, skipLevel);
      }
    }
  }

  /** Release everything; reads still in flight are dropped when they land. */
  close() {
    this.closed = true;
    this.decoder?.close();
    for (const [i, e] of this.cache) this.onEvict(i, e.handle);
    this.cache.clear();
    for (const v of this.levelCache.values()) this.onImageEvict(v.image, v.level, v.handle);
    this.levelCache.clear();
    this.residentBytes = 0;
    this.textureResidentBytes = 0;
  }

  /** The node table decoded, nothing missing and nothing in flight: the drawn nodes are the selected front, with the image levels it wants. */
  idle() {
    const s = this.skeleton;
    return this.missing.length === 0 && this.imageMissing.length === 0 && this.inFlight === 0 && isComplete(s);
  }

  /** The renderer's handle of the level of `image` to draw this frame, or null (drawn untextured). */
  imageHandle(image) {
    const e = this.imagePlan.get(image)?.drawn;
    return e === undefined || e === null ? null : this.levelCache.get(e)?.handle ?? null;
  }

  /** Per image the drawn nodes use: [image, wanted level, level drawn or null], as `strata stream` reports them. */
  textureLevels() {
    const t = this.skeleton.textures;
    return [...this.imagePlan].map(([image, p]) => [image, p.wanted, p.drawn === null ? null : t.levels[p.drawn].level]);
  }

  /**
   * The seams between the drawn nodes (selection.md §8): from the borders of those with a
   * neighbour of their level not drawn, made again when those nodes or their drawn neighbours
   * change.
   */
  sealSeams(drawn) {
    const { sealing, near } = takingPart(drawn, (i) => this.skeleton.neighbors(i), (i) => this.cache.has(i));
    const key = `${sealing.join(',')}|${near.join(',')}`;
    if (key === this.seamNodes) return;
    this.seamNodes = key;
    const borders = (nodes) => nodes.map((i) => this.cache.get(i).border);
    this.seams = seams(borders(sealing), borders(near));
    this.seamsVersion++;
  }

  geometry(i) {
    return this.cache.get(i)?.geometry;
  }

  handle(i) {
    return this.cache.get(i)?.handle;
  }
}
