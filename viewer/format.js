// The web viewer's reader of the strata chunk file, formats 2.x (format-spec/strata-v2.md), 3.x
// (format-spec/strata-v3.md: node geometry compressed, one GEOS chunk, coding tables in CODE, the
// node table in pages from 3.1) and 4.x (format-spec/strata-v4.md: format 3.1 with the node table
// a DAG of nodes and groups, `skeleton.dag`).
//
// A plain ES module without dependencies, for browsers and Node 20. It is written from the spec and
// agrees with strata's Rust reader (src/format/) value for value: every decoded float is the f32 the
// Rust reader computes, bit for bit (Math.fround wherever Rust rounds to f32), and a file is refused
// where the Rust reader refuses it, with two deliberate exceptions: non-zero padding after HEAD,
// SKEL or a chunk between them is refused (spec §4.1; the Rust reader leaves it to `strata verify`),
// and so are u64 counts beyond 2^53, which a JS number cannot hold (HEAD's input vertices are the
// only such field Rust accepts). A viewer opens a file in two steps, then reads nodes on demand:
//
//   openingRange(prefix, fileLength)  how many bytes the skeleton needs (a few short reads);
//   decodeSkeleton(bytes, fileLength) the header, levels, node table, neighbours, materials and, in
//                                     format 4, the DAG's groups (skeleton.dag); with { topFirst:
//                                     true } the top two levels' records only, from a prefix of SKEL
//                                     from format 3.1 on (completeSkeleton(skeleton, bytes) the rest,
//                                     isComplete(skeleton), skeletonNeeds(skeleton));
//   decodeNode(skeleton, i, bytes)    one node's geometry, checked and decoded: its GEOM chunk
//                                     (format 2) or its payload in GEOS (formats 3 and 4);
//   decodeImageLevel(skeleton, e, b)  one image level's TEXL chunk (2.2), checked: the PNG or JPEG
//                                     file inside, for the browser to decode.
//
// Hostile input never hangs the reader nor makes it throw anything but a FormatError: every read is
// bounds-checked first, every size taken from the file is checked against counts and lengths before
// anything is allocated with it, and u64 fields beyond 2^53 are refused. A format-3 payload's work
// is bounded by its bytes (strata-v3.md §5.1), and its decoder stops at the first byte or bit read
// past the payload's end (strata's reader reads zeros there and refuses the node at its end).

/** The format 2 version this reader knows (2.3); it also reads format 3 up to 3.MINOR3 and 4 up to NEWEST_MAJOR.MINOR4. */
export const MAJOR = 2, MINOR = 3;
/** The newest major version this reader reads (format 4, strata-v4.md), the minor of it it knows, and the minor of format 3 it knows. */
export const NEWEST_MAJOR = 4, MINOR4 = 0, MINOR3 = 1;

/** The newest minor of `major` this reader knows: a newer minor only adds what older readers skip. */
export const knownMinor = (major) => (major >= 4 ? MINOR4 : major === 3 ? MINOR3 : MINOR);

/** A file that breaks the format; `offset` is the byte offset the message names, `node` the node. */
export class FormatError extends Error {
  constructor(message, info = {}) {
    super(message);
    this.name = 'FormatError';
    this.offset = info.offset;
    this.node = info.node;
  }
}

const MAGIC = [0x89, 0x53, 0x54, 0x52, 0x41, 0x54, 0x41, 0x0a];
const PROLOGUE = 16;
const FRAME = 16; // ID, flags, size
const TRAILER = 4; // CRC
const MAX_HEAD_BYTES = 65536;
const HEAD_FIXED = 160;
const MAX_TOOL = 1024;
const MAX_GRID_BITS = 21;
const NODE_BYTES = 56;
const GROUP_BYTES = 24;
const LEVEL_BYTES = 32;
const CLUSTER_BYTES = 16;
const RANGE_BYTES = 12;
const NO_PARENT = 0xffffffff;
const TWO32 = 4294967296;
const F32_MAX = 3.4028234663852886e38;
// Rules (src/format/rules.rs): angles may exceed a half-angle by 1e-5 rad (f64); distances a radius
// by a factor of 1 + 1e-5, computed in f32 as Rust does.
const ANGLE_TOLERANCE = 1e-5;
const fr = Math.fround;
const RADIUS_FACTOR = fr(1 + fr(1e-5));
const RADIUS_TINY = fr(1e-30);

// ---------------------------------------------------------------------------------------------
// CRC-32 (ISO-HDLC, as zlib and PNG), slice-by-8.

const CRC_TABLE = (() => {
  const t = new Int32Array(8 * 256); // signed: V8 keeps the lookups in 32-bit registers
  for (let i = 0; i < 256; i++) {
    let c = i;
    for (let k = 0; k < 8; k++) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
    t[i] = c;
  }
  for (let i = 0; i < 256; i++) {
    for (let k = 1; k < 8; k++) {
      const p = t[(k - 1) * 256 + i];
      t[k * 256 + i] = (p >>> 8) ^ t[p & 0xff];
    }
  }
  return t;
})();

const LITTLE_ENDIAN = new Uint8Array(new Uint32Array([1]).buffer)[0] === 1;

/** CRC-32 of bytes[start, end), as an unsigned 32-bit number. */
export function crc32(bytes, start = 0, end = bytes.length) {
  if (!(Number.isInteger(start) && Number.isInteger(end) && 0 <= start && start <= end && end <= bytes.length)) {
    throw new RangeError(`crc32: range ${start}..${end} of ${bytes.length} bytes`);
  }
  const t = CRC_TABLE;
  const b = bytes;
  let c = -1;
  let i = start;
  if (LITTLE_ENDIAN && end - i >= 256) {
    // Up to a 4-byte boundary of the buffer, then 8 bytes at a time as two aligned 32-bit words.
    for (; (b.byteOffset + i) & 3; i++) c = t[(c ^ b[i]) & 0xff] ^ (c >>> 8);
    const n = ((end - i) >> 3) << 1;
    const w = new Int32Array(b.buffer, b.byteOffset + i, n);
    for (let k = 0; k < n; k += 2) {
      const a = c ^ w[k], d = w[k + 1];
      c =
        t[1792 + (a & 0xff)] ^
        t[1536 + ((a >>> 8) & 0xff)] ^
        t[1280 + ((a >>> 16) & 0xff)] ^
        t[1024 + (a >>> 24)] ^
        t[768 + (d & 0xff)] ^
        t[512 + ((d >>> 8) & 0xff)] ^
        t[256 + ((d >>> 16) & 0xff)] ^
        t[d >>> 24];
    }
    i += 4 * n;
  }
  for (const stop = end - 8; i <= stop; i += 8) {
    const a = c ^ (b[i] | (b[i + 1] << 8) | (b[i + 2] << 16) | (b[i + 3] << 24));
    c =
      t[1792 + (a & 0xff)] ^
      t[1536 + ((a >>> 8) & 0xff)] ^
      t[1280 + ((a >>> 16) & 0xff)] ^
      t[1024 + (a >>> 24)] ^
      t[768 + b[i + 4]] ^
      t[512 + b[i + 5]] ^
      t[256 + b[i + 6]] ^
      t[b[i + 7]];
  }
  for (; i < end; i++) c = t[(c ^ b[i]) & 0xff] ^ (c >>> 8);
  return ~c >>> 0;
}

// ---------------------------------------------------------------------------------------------
// Little-endian fields. Callers check bounds first.

const u16 = (b, o) => b[o] | (b[o + 1] << 8);
const i16 = (b, o) => (u16(b, o) << 16) >> 16;
const u32 = (b, o) => (b[o] | (b[o + 1] << 8) | (b[o + 2] << 16) | (b[o + 3] << 24)) >>> 0;
/** A u64 as a number; Infinity when it exceeds 2^53 − 1 (not exactly representable). */
const u64 = (b, o) => {
  const hi = u32(b, o + 4);
  return hi > 0x1fffff ? Infinity : hi * TWO32 + u32(b, o);
};
const view = (b) => new DataView(b.buffer, b.byteOffset, b.byteLength);

/** Zero bytes after `end` up to the next multiple of 8. */
const padding = (end) => (8 - (end % 8)) % 8;

/** Node 0's offset, SKEL (and its padding) ending at `start`: format 3's payloads lie in a GEOS chunk. */
const geometryStart = (major, start) => (major >= 3 ? start + FRAME : start);
/** Whether a file of this version keeps its node table in NODL pages (3.1 on, strata-v3.md §1.1) rather than NODE and NBRS. */
const isPaged = (major, minor) => major > 3 || (major === 3 && minor >= 1);

/** The end of node geometry, padding included, of `bytes` bytes (LEVL's sum) after SKEL's end `start`. */
function geometryEnd(major, start, bytes) {
  if (major < 3) return start + bytes;
  const end = start + FRAME + bytes + TRAILER;
  return end + padding(end);
}

/** A chunk ID as text, non-printable bytes escaped (as Rust's chunk::id_str). */
function idStr(b, o) {
  const c0 = b[o], c1 = b[o + 1], c2 = b[o + 2], c3 = b[o + 3];
  const printable = (c) => c >= 0x20 && c < 0x7f;
  if (printable(c0) && printable(c1) && printable(c2) && printable(c3)) return String.fromCharCode(c0, c1, c2, c3);
  let s = '';
  for (let k = 0; k < 4; k++) {
    const c = b[o + k];
    s += c >= 0x20 && c < 0x7f ? String.fromCharCode(c) : '\\x' + c.toString(16).padStart(2, '0');
  }
  return s;
}

const isId = (b, o, id) => b[o] === id.charCodeAt(0) && b[o + 1] === id.charCodeAt(1) && b[o + 2] === id.charCodeAt(2) && b[o + 3] === id.charCodeAt(3);

function fail(at, msg, node) {
  return new FormatError(at === undefined ? msg : `byte offset ${at}: ${msg}`, { offset: at, node });
}

/** An error in chunk `id` at `chunkAt`, at byte `at`. */
function chunkFail(at, id, chunkAt, msg, node) {
  return fail(at, `chunk ${id} at offset ${chunkAt}: ${msg}`, node);
}

// Strict UTF-8 that keeps a leading BOM, as Rust's String::from_utf8.
const UTF8 = new TextDecoder('utf-8', { fatal: true, ignoreBOM: true });

/** The UTF-8 string of b[start, end), or null when it is not UTF-8. */
function utf8(b, start, end) {
  try {
    return UTF8.decode(b.subarray(start, end));
  } catch {
    return null;
  }
}

// ---------------------------------------------------------------------------------------------
// Codes (spec §5.1, §7.2, §8.2), each rounded to f32 exactly where the Rust reader rounds.

/** The position of grid coordinate g on one axis: f64 product and sum, one rounding to f32. */
const gridDecode = (origin, step, g) => fr(origin + g * step);

/** Cone half-angle code k: f32(k·π/65535) computed in f64. */
const angleDecode = (k) => fr((k * Math.PI) / 65535);

/** Radius code k in grid steps: (k & 0x7FF) · 2^(k >> 11). */
const radiusSteps = (k) => (k & 0x7ff) * 2 ** (k >> 11);

/**
 * Octahedral code (qx, qy) to a unit vector written at out[o..o+3], emulating Rust's f32 operations
 * (src/format/octa.rs and glam's Vec3::normalize) one by one. `scale` is the code of 1: 32767 in
 * format 2, 2^(bits−1) − 1 in format 3 (octa::decode_at; the f64 quotient rounds to the f32 one).
 */
export function octaDecode(qx, qy, out, o, scale = 32767) {
  let x = fr(qx / scale);
  if (x < -1) x = -1;
  else if (x > 1) x = 1;
  let y = fr(qy / scale);
  if (y < -1) y = -1;
  else if (y > 1) y = 1;
  const z = fr(fr(1 - Math.abs(x)) - Math.abs(y));
  if (z < 0) {
    const nx = fr(1 - Math.abs(y)) * (x >= 0 ? 1 : -1);
    const ny = fr(1 - Math.abs(x)) * (y >= 0 ? 1 : -1);
    x = nx;
    y = ny;
  }
  const len = fr(Math.sqrt(fr(fr(fr(x * x) + fr(y * y)) + fr(z * z))));
  const r = fr(1 / len);
  out[o] = fr(x * r);
  out[o + 1] = fr(y * r);
  out[o + 2] = fr(z * r);
}

/** Unpack a packed grid point at b[o..o+8] into g[0..3]; false when bit 63 is set. */
function unpack(b, o, g) {
  const lo = u32(b, o), hi = u32(b, o + 4);
  if (hi >>> 31) return false;
  g[0] = lo & 0x1fffff;
  g[1] = (lo >>> 21) | ((hi & 0x3ff) << 11);
  g[2] = (hi >>> 10) & 0x1fffff;
  return true;
}

// ---------------------------------------------------------------------------------------------
// Chunk frames.

/**
 * The sub-chunks of the payload b[start, end), whose first byte is at file offset `base`, inside
 * chunk `parent` at file offset `parentAt`: each frame's bounds, CRC and zero padding checked.
 */
function subChunks(b, start, end, base, parent, parentAt, node) {
  const err = (off, msg) => chunkFail(off, parent, parentAt, node === undefined ? msg : `node ${node}: ${msg}`, node);
  const out = [];
  let pos = start;
  while (pos < end) {
    const at = base + (pos - start);
    const rest = end - pos;
    if (rest < FRAME + TRAILER) throw err(at, `${rest} bytes left at offset ${at}, too few for a sub-chunk`);
    const id = idStr(b, pos);
    const size = u64(b, pos + 8);
    const room = rest - FRAME - TRAILER;
    if (size > room) throw err(at + 8, `chunk ${id} at offset ${at} says ${size === Infinity ? 'more than 2^53' : size} bytes but its parent has ${room} left`);
    const ps = pos + FRAME, pe = ps + size;
    const stored = u32(b, pe), actual = crc32(b, ps, pe);
    if (stored !== actual) throw err(base + (pe - start), `chunk ${id} at offset ${at}: CRC ${hex(actual)} != stored ${hex(stored)}`);
    const after = pe + TRAILER;
    const pad = padding(base + (after - start));
    if (pad > end - after) throw err(base + (after - start), `chunk ${id} at offset ${at}: padding runs past its parent`);
    for (let k = after; k < after + pad; k++) {
      if (b[k] !== 0) throw err(base + (after - start), `chunk ${id} at offset ${at}: padding is not zero`);
    }
    out.push({ id, flags: u32(b, pos + 4), size, at, ps, pe });
    pos = after + pad;
  }
  return out;
}

const hex = (x) => x.toString(16).padStart(8, '0');

// ---------------------------------------------------------------------------------------------
// Prologue (§3) and the walk to SKEL (§2, §4.3).

function checkPrologue(b, fileLength) {
  if (fileLength !== undefined && fileLength < PROLOGUE) throw fail(0, `a file of ${fileLength} bytes is too short for a strata file`);
  for (let k = 0; k < 8; k++) {
    if (b[k] !== MAGIC[k]) throw fail(0, 'not a strata file (the first 8 bytes are not the strata magic)');
  }
  const major = u16(b, 8), minor = u16(b, 10);
  if (major > NEWEST_MAJOR) {
    throw fail(8, `format version ${major}.${minor} is newer than this reader's ${NEWEST_MAJOR}.${MINOR4}: a newer strata viewer is needed`);
  }
  if (major < MAJOR) throw fail(8, `format version ${major}.${minor} is not supported (this reader reads ${MAJOR}.x to ${NEWEST_MAJOR}.x)`);
  const stored = u32(b, 12), actual = crc32(b, 0, 12);
  if (stored !== actual) throw fail(12, `prologue CRC ${hex(actual)} != stored ${hex(stored)}`);
  return { major, minor };
}

/** The end (padding included) of the chunk at `pos` with payload `size`; it must lie in the file. */
function chunkEnd(pos, id, size, fileLength) {
  const end = pos + FRAME + size + TRAILER;
  if (size === Infinity || (fileLength !== undefined && end > fileLength)) {
    const len = fileLength === undefined ? '' : ` (${fileLength} bytes)`;
    throw chunkFail(pos + 8, id, pos, `size ${size === Infinity ? 'beyond 2^53' : size} runs past the end of the file${len}`);
  }
  // The file goes on after HEAD and SKEL (at least one GEOM follows), so their padding lies in it.
  if (fileLength !== undefined && end + padding(end) > fileLength) {
    throw chunkFail(end, id, pos, `its padding runs past the end of the file (${fileLength} bytes)`);
  }
  return end + padding(end);
}

function frameFits(pos, fileLength) {
  if (fileLength !== undefined && pos + FRAME + TRAILER > fileLength) {
    throw fail(pos, `a chunk at offset ${pos} runs past the end of the file (${fileLength} bytes)`);
  }
}

function checkHeadFrame(b, fileLength) {
  const pos = PROLOGUE;
  frameFits(pos, fileLength);
  const id = idStr(b, pos);
  if (!isId(b, pos, 'HEAD')) throw chunkFail(pos, id, pos, 'expected the HEAD chunk here');
  const size = u64(b, pos + 8);
  if (size > MAX_HEAD_BYTES) throw chunkFail(pos + 8, id, pos, `size ${size === Infinity ? 'beyond 2^53' : size} exceeds the ${MAX_HEAD_BYTES}-byte limit`);
  if (size < HEAD_FIXED) throw chunkFail(pos + FRAME, id, pos, `${size} bytes, fewer than the ${HEAD_FIXED} of its fixed fields`);
  return { size, end: chunkEnd(pos, id, size, fileLength) };
}

/**
 * How far the opening reads must go, given a prefix of the file: `{ need }` when the prefix is too
 * short to tell (the prefix length needed to learn more), else `{ skeletonEnd, topEnd, pagesEnd }`:
 * topEnd, where the top level's geometry ends, is undefined unless SKEL's LEVL sub-chunk lies in
 * the prefix; pagesEnd, the bytes `decodeSkeleton(…, { topFirst: true })` needs, is skeletonEnd in
 * format 2, and from format 3.1 on the end of the top two levels' NODL pages (strata-v3.md §1.1),
 * undefined unless the frames up to them lie in the prefix; then nextFrame, where it is known, is
 * the offset of the next sub-chunk's frame, beyond the prefix (read on from there).
 */
export function openingRange(prefix, fileLength) {
  const b = prefix;
  const n = b.length;
  if (fileLength !== undefined && fileLength < PROLOGUE) throw fail(0, `a file of ${fileLength} bytes is too short for a strata file`);
  if (n < PROLOGUE) return { need: PROLOGUE };
  const { major, minor } = checkPrologue(b, fileLength);
  const paged = isPaged(major, minor);
  frameFits(PROLOGUE, fileLength);
  if (n < PROLOGUE + FRAME) return { need: PROLOGUE + FRAME };
  const head = checkHeadFrame(b, fileLength);
  const headPayload = PROLOGUE + FRAME;
  let levels;
  if (n >= headPayload + head.size + TRAILER) {
    const stored = u32(b, headPayload + head.size), actual = crc32(b, headPayload, headPayload + head.size);
    if (stored !== actual) throw chunkFail(headPayload + head.size, 'HEAD', PROLOGUE, `CRC ${hex(actual)} != stored ${hex(stored)}`);
    const fileSize = u64(b, headPayload);
    if (fileLength !== undefined && fileSize !== fileLength) {
      throw chunkFail(headPayload, 'HEAD', PROLOGUE, `the file is ${fileLength} bytes but HEAD says ${fileSize}: truncated or extended`);
    }
    levels = u32(b, headPayload + 44);
  }
  let pos = head.end;
  for (;;) {
    frameFits(pos, fileLength);
    if (n < pos + FRAME) return { need: pos + FRAME };
    const id = idStr(b, pos);
    const size = u64(b, pos + 8);
    if (id === 'SKEL') break;
    if (id === 'HEAD' || id === 'GEOM' || id === 'GEOS') throw chunkFail(pos, id, pos, 'expected the SKEL chunk before any other known chunk');
    pos = chunkEnd(pos, id, size, fileLength);
  }
  const skelSize = u64(b, pos + 8);
  const skeletonEnd = chunkEnd(pos, 'SKEL', skelSize, fileLength);
  // Hints, which decodeSkeleton checks: the top level's bytes from LEVL, if its record lies in the
  // prefix; from format 3.1 on, the end of the top two levels' NODL pages, if their frames do.
  let topEnd, pagesEnd = paged && levels !== undefined && levels <= 2 ? skeletonEnd : undefined;
  const se = pos + FRAME + skelSize, payloadEnd = Math.min(se, n);
  let s = pos + FRAME, pages = 0;
  while (levels !== undefined && s + FRAME <= payloadEnd) {
    const size = u64(b, s + 8);
    if (size === Infinity) break;
    if (isId(b, s, 'LEVL') && topEnd === undefined) {
      const rec = s + FRAME + (levels - 1) * LEVEL_BYTES;
      if (levels >= 1 && size === levels * LEVEL_BYTES && rec + LEVEL_BYTES <= payloadEnd) {
        const bytes = u64(b, rec + 24);
        const end = geometryStart(major, skeletonEnd) + bytes;
        if (bytes !== Infinity && (fileLength === undefined || end <= fileLength)) topEnd = end;
      }
      if (!paged) break;
    }
    const page = isId(b, s, 'NODL');
    const e = s + FRAME + size + TRAILER;
    if (e > se) break;
    s = Math.min(e + padding(e), se);
    if (page && ++pages === 2 && pagesEnd === undefined) {
      pagesEnd = s >= se ? skeletonEnd : s;
      break;
    }
  }
  // Where the scan stopped for want of bytes: the next sub-chunk's frame, past the prefix (the
  // sub-chunks before it, whatever their size, need no further look to be stepped over).
  const nextFrame = paged && pagesEnd === undefined && s < se && s + FRAME > n ? s : undefined;
  return paged ? { skeletonEnd, topEnd, pagesEnd, nextFrame } : { skeletonEnd, topEnd, pagesEnd: skeletonEnd };
}

// ---------------------------------------------------------------------------------------------
// The skeleton (§5, §7, §10 "To open").

const onGrid = (g, last) => g[0] <= last && g[1] <= last && g[2] <= last;

/** Whether every node record of `sk` is decoded (a skeleton without `decoded` counts as whole). */
export function isComplete(sk) {
  return !(sk.decoded < sk.nodeCount);
}

/** The bytes of the file `completeSkeleton(sk, bytes)` needs, [0, needs): 0 if it needs none. */
export function skeletonNeeds(sk) {
  return isComplete(sk) || sk._failed ? 0 : sk._needs;
}

/**
 * Check and decode the node records `decodeSkeleton(…, { topFirst: true })` left; throws a
 * FormatError as it would have. A format-3 skeleton decoded from a prefix of the file (its SKEL
 * up to the top pages) needs `bytes`, the file from its first byte to at least skeletonNeeds(sk).
 */
export function completeSkeleton(sk, bytes) {
  if (isComplete(sk)) return;
  if (sk._failed) throw sk._failed;
  if (typeof sk._rest !== 'function') throw new Error('completeSkeleton: not a skeleton decodeSkeleton returned (a copy?)');
  if (sk._needs && !(bytes && bytes.length >= sk._needs)) {
    throw new Error(`completeSkeleton: needs the file's bytes up to offset ${sk._needs} (skeletonNeeds); ${bytes ? bytes.length : 'none'} given`);
  }
  try {
    sk._rest(bytes);
  } catch (e) {
    Object.defineProperty(sk, '_failed', { value: e });
    throw e;
  }
  delete sk._rest;
  sk.decoded = sk.nodeCount;
}

class Skeleton {
  /** Nodes of level l as [start, end); [0, 0] past the top. */
  levelNodes(l) {
    const r = this.levels[l];
    return r ? [r.firstNode, r.firstNode + r.nodes] : [0, 0];
  }

  /** The top level, L − 1. */
  top() {
    return this.levels.length - 1;
  }

  /** Children of node i as [first, end). */
  children(i) {
    if (!(i >= 0 && i < this.nodeCount)) return [0, 0];
    return [this.firstChild[i], this.firstChild[i] + this.childCount[i]];
  }

  /** Same-level neighbours of node i (absolute node ids). */
  neighbors(i) {
    if (!(i >= 0 && i < this.nodeCount)) return this.neighborList.subarray(0, 0);
    const f = this.neighborFirst[i];
    return this.neighborList.subarray(f, f + this.neighborCount[i]);
  }
}

/**
 * Format 4's DAG (strata-v4.md §1): groups numbered in file order (the top level's first), each
 * with the level of its outputs, its run of outputs, its children count, error and sphere; per
 * node its consumer and source group (0xFFFFFFFF: none); per group its children, in node order.
 * Of a skeleton decoded in part, the groups of the pages decoded and those pages' nodes.
 */
class Dag {
  constructor(N, G, L) {
    this.groupCount = G;
    /** Per level (finest first), its groups as [start, end). */
    this.levelGroups = Array.from({ length: L }, () => [0, 0]);
    this.groups = {
      level: new Uint32Array(G),
      firstOutput: new Uint32Array(G),
      outputs: new Uint32Array(G),
      children: new Uint32Array(G),
      error: new Float32Array(G),
      center: new Float32Array(3 * G),
      radius: new Float32Array(G),
    };
    this.consumer = new Uint32Array(N).fill(NO_PARENT);
    this.source = new Uint32Array(N).fill(NO_PARENT);
    this.childOffsets = new Uint32Array(G + 1);
    this.childItems = new Uint32Array(0);
  }

  /** The outputs of group g as [first, end). */
  outputsOf(g) {
    const first = this.groups.firstOutput[g];
    return [first, first + this.groups.outputs[g]];
  }

  /** The children of group g (nodes of the level below its outputs), ascending. */
  childrenOf(g) {
    return this.childItems.subarray(this.childOffsets[g], this.childOffsets[g + 1]);
  }
}

function decodeHead(b, dv, pos, size, major, minor) {
  const p0 = pos + FRAME;
  const end = p0 + size;
  const newer = minor > knownMinor(major);
  const err = (at, msg) => chunkFail(at, 'HEAD', pos, msg);
  const fileSize = u64(b, p0);
  const metresPerUnit = dv.getFloat64(p0 + 8, true);
  if (!(Number.isFinite(metresPerUnit) && metresPerUnit >= 0)) throw err(p0 + 8, `metres per unit ${metresPerUnit}`);
  const min = [0, 1, 2].map((k) => dv.getFloat32(p0 + 16 + 4 * k, true));
  const max = [0, 1, 2].map((k) => dv.getFloat32(p0 + 28 + 4 * k, true));
  if (!min.concat(max).every(Number.isFinite)) throw err(p0 + 16, 'bounds are not finite');
  const bits = u32(b, p0 + 40);
  if (bits & ~7 && !newer) throw err(p0 + 40, `unknown attribute bits 0x${bits.toString(16)}`);
  const levels = u32(b, p0 + 44), nodes = u32(b, p0 + 48), materials = u32(b, p0 + 52);
  if (levels === 0 || nodes < levels || nodes === NO_PARENT) throw err(p0 + 44, `${levels} levels and ${nodes} nodes`);
  const inputVertices = u64(b, p0 + 56), inputFaces = u64(b, p0 + 64);
  if (inputVertices === Infinity) throw err(p0 + 56, 'input vertices beyond 2^53');
  if (inputFaces === Infinity) throw err(p0 + 64, 'input faces beyond 2^53');
  const clusters = u32(b, p0 + 72);
  const f32 = (o) => dv.getFloat32(p0 + o, true);
  const params = {
    cluster_faces: u32(b, p0 + 76),
    cluster_angle: f32(80),
    leaf_faces: u32(b, p0 + 84),
    leaf_angle: f32(88),
    angle_step: f32(92),
    growth: u32(b, p0 + 96),
    kc: f32(100),
    ks: f32(104),
    kn: f32(108),
    top_groups: u32(b, p0 + 112),
  };
  const levelRatio = f32(116);
  const origin = [0, 1, 2].map((k) => dv.getFloat64(p0 + 120 + 8 * k, true));
  const step = dv.getFloat64(p0 + 144, true);
  const gbits = u32(b, p0 + 152);
  const sane =
    origin.every(Number.isFinite) &&
    Number.isFinite(step) &&
    step > 0 &&
    gbits >= 1 &&
    gbits <= MAX_GRID_BITS &&
    origin.every((o) => Number.isFinite(gridDecode(o, step, 0)) && Number.isFinite(gridDecode(o, step, 2 ** gbits - 1)));
  if (!sane) throw err(p0 + 120, `grid origin [${origin.join(', ')}], step ${step}, ${gbits} bits`);
  const toolLen = u32(b, p0 + 156);
  if (toolLen > MAX_TOOL) throw err(p0 + 156, `tool string of ${toolLen} bytes exceeds ${MAX_TOOL}`);
  const t0 = p0 + HEAD_FIXED;
  if (toolLen > end - t0) throw err(t0, `needs ${toolLen} more bytes, ${end - t0} left`);
  const tool = utf8(b, t0, t0 + toolLen);
  if (tool === null) throw err(t0, 'string is not UTF-8');
  const rest = end - t0 - toolLen;
  if (rest > 0 && !newer) throw err(t0 + toolLen, `${rest} bytes after the tool string`);
  return {
    fileSize,
    metresPerUnit,
    min,
    max,
    attributes: { normals: (bits & 1) !== 0, uvs: (bits & 2) !== 0, colors: (bits & 4) !== 0 },
    levels,
    nodes,
    materials,
    inputVertices,
    inputFaces,
    clusters,
    params,
    grid: { origin, step, bits: gbits },
    levelRatio,
    tool,
  };
}

const GEOR_FIXED = 52;
const GEO_FRAMES = ['unplaced', 'local_tangent', 'projected'];

/**
 * The GEOR chunk at `pos` (§5.2): where terrain sits on Earth. `frame` is 'unplaced',
 * 'local_tangent' (origin: longitude°, latitude°, height m on WGS 84; x east, y up, z south) or
 * 'projected' (easting = origin[0] + x / k, northing = origin[1] − z / k).
 */
function decodeGeoref(b, dv, pos, size, major, minor) {
  const p0 = pos + FRAME, end = p0 + size;
  const err = (at, msg) => chunkFail(at, 'GEOR', pos, msg);
  const newer = minor > knownMinor(major);
  if (size < GEOR_FIXED) throw err(p0, `${size} bytes, fewer than the ${GEOR_FIXED} of its fixed fields`);
  const code = u32(b, p0);
  if (code >= GEO_FRAMES.length) throw err(p0, newer ? `frame ${code} is newer than this reader (format ${major}.${knownMinor(major)})` : `unknown frame ${code}`);
  if (u32(b, p0 + 4) !== 0 && !newer) throw err(p0 + 4, 'reserved field is not 0');
  const origin = [0, 1, 2].map((k) => dv.getFloat64(p0 + 8 + 8 * k, true));
  if (!origin.every(Number.isFinite)) throw err(p0 + 8, `origin [${origin.join(', ')}] is not finite`);
  if (code === 1 && !(Math.abs(origin[0]) <= 180 && Math.abs(origin[1]) <= 90)) throw err(p0 + 8, `longitude ${origin[0]} or latitude ${origin[1]} out of range`);
  const k = dv.getFloat64(p0 + 32, true);
  if (!(Number.isFinite(k) && k > 0)) throw err(p0 + 32, `metres per CRS unit ${k}`);
  const zScale = dv.getFloat64(p0 + 40, true);
  if (!(Number.isFinite(zScale) && zScale > 0)) throw err(p0 + 40, `z scale ${zScale}`);
  const len = u32(b, p0 + 48);
  if (len > MAX_TOOL) throw err(p0 + 48, `CRS string of ${len} bytes exceeds ${MAX_TOOL}`);
  const c0 = p0 + GEOR_FIXED;
  if (len > end - c0) throw err(c0, `needs ${len} more bytes, ${end - c0} left`);
  const crs = utf8(b, c0, c0 + len);
  if (crs === null) throw err(c0, 'string is not UTF-8');
  if (end - c0 - len > 0 && !newer) throw err(c0 + len, `${end - c0 - len} bytes after the CRS string`);
  return { frame: GEO_FRAMES[code], origin, metresPerCrsUnit: k, zScale, crs };
}

/**
 * Decode and check the skeleton from `bytes`, which hold at least [0, skeletonEnd) of a file of
 * `fileLength` bytes: the prologue, HEAD, skipped chunks and SKEL (from format 3 on with its coding
 * tables, `sk.code`; in format 4 with the DAG's groups, `sk.dag`, else null), every check of spec
 * §10 "To open" and of strata-v4.md §1.
 * With `opts.topFirst`, only the top two levels' node records are checked and decoded (nodes
 * [0, sk.decoded)); `completeSkeleton` does the rest before any other node is used, so a first
 * frame of the top level waits for none of it (selection.md §6).
 */
export function decodeSkeleton(bytes, fileLength, opts = {}) {
  let b = bytes;
  let prefixBytes = bytes;
  if (!(Number.isSafeInteger(fileLength) && fileLength >= 0)) throw fail(undefined, `file length ${fileLength} is not a byte count`);
  const have = (end) => {
    if (b.length < end) throw fail(Math.min(b.length, end), `needs the file's bytes up to offset ${end}; ${b.length} given`);
  };
  if (fileLength < PROLOGUE) throw fail(0, `a file of ${fileLength} bytes is too short for a strata file`);
  have(PROLOGUE);
  const { major, minor } = checkPrologue(b, fileLength);
  let dv = view(b);

  // HEAD
  have(PROLOGUE + FRAME);
  const head = checkHeadFrame(b, fileLength);
  const hp = PROLOGUE + FRAME;
  have(hp + head.size + TRAILER);
  const stored = u32(b, hp + head.size), actual = crc32(b, hp, hp + head.size);
  if (stored !== actual) throw chunkFail(hp + head.size, 'HEAD', PROLOGUE, `CRC ${hex(actual)} != stored ${hex(stored)}`);
  const header = decodeHead(b, dv, PROLOGUE, head.size, major, minor);
  if (header.fileSize !== fileLength) {
    const says = header.fileSize === Infinity ? 'more than 2^53' : header.fileSize;
    throw chunkFail(hp, 'HEAD', PROLOGUE, `the file is ${fileLength} bytes but HEAD says ${says}: truncated or extended`);
  }
  const zeroPadding = (from, to, id, at) => {
    have(to);
    for (let k = from; k < to; k++) if (b[k] !== 0) throw chunkFail(from, id, at, 'padding is not zero');
  };
  zeroPadding(hp + head.size + TRAILER, head.end, 'HEAD', PROLOGUE);

  // GEOR and unknown chunks up to SKEL.
  let pos = head.end;
  let georef = null;
  for (;;) {
    frameFits(pos, fileLength);
    have(pos + FRAME);
    const id = idStr(b, pos);
    if (id === 'SKEL') break;
    if (id === 'HEAD' || id === 'GEOM' || id === 'GEOS') throw chunkFail(pos, id, pos, 'expected the SKEL chunk before any other known chunk');
    const size = u64(b, pos + 8);
    if (id === 'GEOR' && size > MAX_HEAD_BYTES) throw chunkFail(pos + 8, id, pos, `size ${size === Infinity ? 'beyond 2^53' : size} exceeds the ${MAX_HEAD_BYTES}-byte limit`);
    const end = chunkEnd(pos, id, size, fileLength);
    if (id === 'GEOR') {
      if (georef) throw chunkFail(pos, id, pos, 'a second GEOR chunk');
      have(pos + FRAME + size + TRAILER);
      const stored = u32(b, pos + FRAME + size), actual = crc32(b, pos + FRAME, pos + FRAME + size);
      if (stored !== actual) throw chunkFail(pos + FRAME + size, id, pos, `CRC ${hex(actual)} != stored ${hex(stored)}`);
      georef = decodeGeoref(b, dv, pos, size, major, minor);
    }
    zeroPadding(pos + FRAME + size + TRAILER, end, id, pos);
    pos = end;
  }

  // SKEL
  const skelAt = pos;
  const skelSize = u64(b, pos + 8);
  const skeletonEnd = chunkEnd(pos, 'SKEL', skelSize, fileLength);
  const sp = pos + FRAME, se = sp + skelSize;
  const h = header;
  const L = h.levels, N = h.nodes;
  const v3 = major >= 3, paged = isPaged(major, minor), dagFile = major === 4;
  // Format 3.1 on, opened top first from a prefix (strata-v3.md §1.1): SKEL's sub-chunks up to the top
  // two levels' pages, each checked by its own CRC; SKEL's CRC and the rest by completeSkeleton.
  const partial = !!opts.topFirst && paged && L > 2 && b.length < skeletonEnd;
  const wholeSkel = () => {
    have(skeletonEnd);
    const stored = u32(b, se), actual = crc32(b, sp, se);
    if (stored !== actual) throw chunkFail(se, 'SKEL', skelAt, `CRC ${hex(actual)} != stored ${hex(stored)}`);
    zeroPadding(se + TRAILER, skeletonEnd, 'SKEL', skelAt);
    return subChunks(b, sp, se, sp, 'SKEL', skelAt);
  };
  let subs = partial ? skelPrefix(b, sp, se, skelAt, Math.min(L, 2), have) : wholeSkel();
  const find = (want) => {
    const found = subs.filter((s) => s.id === want);
    if (found.length === 0) throw chunkFail(skelAt, 'SKEL', skelAt, `has no ${want} chunk`);
    if (found.length > 1) throw chunkFail(found[1].at, 'SKEL', skelAt, `has a second ${want} chunk`);
    return found[0];
  };
  const levl = find('LEVL'), matl = find('MATL');

  // LEVL
  const lerr = (at, msg) => chunkFail(at, 'LEVL', levl.at, msg);
  if (levl.size !== L * LEVEL_BYTES) throw lerr(levl.ps, `holds ${levl.size} bytes; ${L} levels need ${L * LEVEL_BYTES}`);
  const levels = [];
  for (let l = 0; l < L; l++) {
    const o = levl.ps + l * LEVEL_BYTES;
    const rec = { firstNode: u32(b, o), nodes: u32(b, o + 4), faces: u64(b, o + 8), vertices: u64(b, o + 16), bytes: u64(b, o + 24) };
    if (rec.faces === Infinity || rec.vertices === Infinity || rec.bytes === Infinity) {
      throw lerr(o + 8, `level ${l}: a total beyond 2^53`);
    }
    levels.push(rec);
  }
  let expect = 0;
  for (let l = L - 1; l >= 0; l--) {
    const rec = levels[l];
    if (rec.firstNode !== expect || rec.nodes === 0) {
      throw lerr(levl.ps + l * LEVEL_BYTES, `level ${l} has nodes ${rec.firstNode}..+${rec.nodes}; expected a non-empty range from ${expect}`);
    }
    expect += rec.nodes;
  }
  if (expect !== N) throw lerr(levl.ps, `levels hold ${expect} nodes, HEAD says ${N}`);
  // Every node has a record inside SKEL: nothing is sized by a count SKEL could not hold (a prefix
  // has not seen the lower levels' pages yet).
  if (N * NODE_BYTES > skelSize) throw lerr(levl.ps, `${N} nodes need ${N * NODE_BYTES} bytes of node records; SKEL holds ${skelSize}`);
  if (v3 && !paged && subs.some((s) => s.id === 'NODL')) {
    throw chunkFail(subs.find((s) => s.id === 'NODL').at, 'SKEL', skelAt, 'holds a NODL page: format 3.0 keeps nodes in NODE and NBRS');
  }

  // The node records and neighbour lists as pages, one per level from the top: format 2's NODE
  // and NBRS hold every level (format 2 and 3.0), 3.1 has one NODL per level (of which a prefix
  // holds the first).
  let pages = paged ? pagesPaged(b, subs, levels, skelAt, partial, dagFile) : pagesWhole(find('NODE'), find('NBRS'), levels);
  const pageOf = (l) => pages[L - 1 - l];
  const { origin, step, bits: gbits } = h.grid;
  const last = 2 ** gbits - 1;
  const sk = new Skeleton();
  sk.major = major;
  sk.minor = minor;
  sk.header = header;
  sk.georef = georef;
  sk.levels = levels;
  sk.skeletonEnd = skeletonEnd;
  sk.nodeCount = N;
  const level = L <= 65536 ? new Uint16Array(N) : new Uint32Array(N);
  const parent = new Uint32Array(N).fill(NO_PARENT);
  const firstChild = new Uint32Array(N), childCount = new Uint32Array(N);
  const neighborFirst = new Uint32Array(N), neighborCount = new Uint32Array(N);
  const coneAxis = new Float32Array(3 * N), coneHalfAngle = new Float32Array(N);
  const center = new Float32Array(3 * N), radius = new Float32Array(N);
  const boxMin = new Float32Array(3 * N), boxMax = new Float32Array(3 * N);
  const error = new Float32Array(N);
  const faces = new Uint32Array(N), vertices = new Uint32Array(N);
  const offset = new Float64Array(N), size = new Uint32Array(N), crc = new Uint32Array(N);
  const totals = new Float64Array(3 * L);
  const entriesOf = (ps) => (ps.length ? ps[ps.length - 1].entryBase + ps[ps.length - 1].entryCount : 0);
  let neighborList = new Uint32Array(entriesOf(pages));
  const gl = [0, 0, 0], gh = [0, 0, 0], gc = [0, 0, 0];
  // Format 3: payloads back to back inside GEOS, unpadded, at least a byte each (strata-v3.md §1).
  const least = v3 ? 1 : FRAME + TRAILER;
  const boxMid = v3 ? new Uint32Array(3 * N) : null;
  let nbFirst = 0, geo = geometryStart(major, skeletonEnd), nextChild = 0, l = L - 1;
  // Check and decode level l's records (levels from the top down), then step to the level below.
  const decodeLevel = () => {
    const lev = levels[l], pg = pageOf(l);
    const nerr = (at, msg, i) => chunkFail(at, pg.id, pg.at, i === undefined ? msg : `node ${i}: ${msg}`, i);
    const end = lev.firstNode + lev.nodes;
    if (l + 1 < L && nextChild !== end && !dagFile) {
      throw nerr(pg.recordsAt, `the children of level ${l + 1} cover nodes up to ${nextChild}, level ${l} ends at ${end}`);
    }
    nextChild = end;
    for (let i = lev.firstNode; i < end; i++) {
      const at = pg.recordsAt + NODE_BYTES * (i - lev.firstNode);
      // Format 4: bytes 0–3 name the consumer (decodeDag); no children, no neighbours.
      const cc = dagFile ? 0 : u16(b, at), nc = dagFile ? 0 : u16(b, at + 2);
      const first = cc > 0 ? nextChild : 0;
      if (l === 0 && cc > 0) throw nerr(at, `a level-0 node with ${cc} children`, i);
      nextChild += cc;
      if (l > 0 && nextChild > end + levels[l - 1].nodes) throw nerr(at, `children ${first}..+${cc} run past level ${l - 1}`, i);
      if (nbFirst + nc > pg.entryBase + pg.entryCount) throw nerr(at, `neighbours run past the ${pg.entryCount} of ${pg.entriesId}`, i);
      if (!(unpack(b, at + 12, gl) && unpack(b, at + 20, gh) && unpack(b, at + 28, gc) && onGrid(gl, last) && onGrid(gh, last) && onGrid(gc, last))) {
        throw nerr(at, `box or sphere center off the ${gbits}-bit grid`, i);
      }
      if (gl[0] > gh[0] || gl[1] > gh[1] || gl[2] > gh[2]) throw nerr(at, `box min [${gl}] lies above its max [${gh}]`, i);
      const r = fr(radiusSteps(u16(b, at + 10)) * step);
      const e = dv.getFloat32(at + 36, true);
      if (!(e >= 0 && e <= F32_MAX && r <= F32_MAX)) {
        throw nerr(at, `geometric error ${e} and radius ${r} must be finite, the error not negative`, i);
      }
      const nf = u32(b, at + 40), nv = u32(b, at + 44), ns = u32(b, at + 48);
      const gend = geo + ns;
      const padded = v3 ? ns : ns + padding(gend);
      totals[3 * l] += nf;
      totals[3 * l + 1] += nv;
      totals[3 * l + 2] += padded;
      if (!(ns >= least && gend <= fileLength)) {
        throw nerr(at, `geometry ${ns} bytes at offset ${geo} runs past the end of the ${fileLength}-byte file`, i);
      }
      level[i] = l;
      firstChild[i] = first;
      childCount[i] = cc;
      for (let c = first; c < first + cc; c++) parent[c] = i;
      neighborFirst[i] = nbFirst;
      neighborCount[i] = nc;
      octaDecode(i16(b, at + 4), i16(b, at + 6), coneAxis, 3 * i);
      coneHalfAngle[i] = angleDecode(u16(b, at + 8));
      for (let k = 0; k < 3; k++) {
        center[3 * i + k] = gridDecode(origin[k], step, gc[k]);
        boxMin[3 * i + k] = gridDecode(origin[k], step, gl[k]);
        boxMax[3 * i + k] = gridDecode(origin[k], step, gh[k]);
        if (v3) boxMid[3 * i + k] = (gl[k] + gh[k]) >>> 1;
      }
      radius[i] = r;
      error[i] = e;
      faces[i] = nf;
      vertices[i] = nv;
      offset[i] = geo;
      size[i] = ns;
      crc[i] = u32(b, at + 52);
      nbFirst += nc;
      geo += padded;
    }
    l--;
  };
  // Level m's totals against LEVL, once its records are decoded.
  const levelTotals = (m) => {
    const rec = levels[m];
    const [tf, tv, tb] = [totals[3 * m], totals[3 * m + 1], totals[3 * m + 2]];
    if (rec.faces !== tf || rec.vertices !== tv || rec.bytes !== tb) {
      throw lerr(
        levl.ps + m * LEVEL_BYTES,
        `level ${m}: LEVL says ${rec.faces} faces, ${rec.vertices} vertices, ${rec.bytes} bytes; the nodes hold ${tf}, ${tv}, ${tb}`,
      );
    }
  };
  // With every level decoded: the geometry's end, the totals LEVL and HEAD state, the entries used.
  const finish = () => {
    if (geo > fileLength) throw chunkFail(skelAt, 'SKEL', skelAt, `geometry ends at ${geo}, past the end of the ${fileLength}-byte file`);
    for (let m = 0; m < L; m++) levelTotals(m);
    if (totals[0] !== h.inputFaces) throw lerr(levl.ps, `level 0's nodes hold ${totals[0]} faces, HEAD says the input has ${h.inputFaces}`);
    const all = entriesOf(pages);
    if (!paged && nbFirst !== all) throw chunkFail(pages[0].entriesAt, 'NBRS', pages[0].at, `holds ${all} neighbours, the nodes use ${nbFirst}`);
  };
  // Level m's neighbour entries (its records decoded): as many as its nodes use (format 3's
  // pages), each below the level's node count, made absolute node ids.
  const decodeEntries = (m) => {
    const lev = levels[m], pg = pageOf(m);
    const used = lev.nodes ? neighborFirst[lev.firstNode + lev.nodes - 1] + neighborCount[lev.firstNode + lev.nodes - 1] - neighborFirst[lev.firstNode] : 0;
    if (paged && used !== pg.entryCount) throw chunkFail(pg.entriesAt, 'NODL', pg.at, `holds ${pg.entryCount} neighbour entries, the level's nodes use ${used}`);
    for (let i = lev.firstNode, end = lev.firstNode + lev.nodes; i < end; i++) {
      for (let k = neighborFirst[i], e = k + neighborCount[i]; k < e; k++) {
        const o = pg.entriesAt + pg.width * (k - pg.entryBase);
        const x = pg.width === 2 ? u16(b, o) : u32(b, o);
        if (x >= lev.nodes) throw chunkFail(o, pg.entriesId, pg.entriesChunkAt, `node ${i}: neighbour ${x} of the ${lev.nodes} nodes of level ${m}`, i);
        neighborList[k] = x + lev.firstNode;
      }
    }
  };
  // Format 4 (strata-v4.md §1): the groups of the pages whose records are decoded (levels above
  // l, top first, numbered in file order), checked; each of those nodes' consumer and source; each
  // group's children, and their count checked where the page below is decoded too.
  const decodeDag = () => {
    const P = L - 1 - l;
    let G = 0;
    for (let k = 0; k < P; k++) G += pages[k].groupCount;
    const d = new Dag(N, G, L), gr = d.groups;
    let g = 0;
    for (let k = 0; k < P; k++) {
      const m = L - 1 - k, lev = levels[m], pg = pages[k], count = pg.groupCount;
      if ((m === 0) !== (count === 0)) {
        throw chunkFail(pg.groupsAt - 4, pg.id, pg.at, `level ${m} has ${count} groups; level 0 has none and every other level some`);
      }
      const first = g, end = lev.firstNode + lev.nodes;
      let next = lev.firstNode;
      for (let q = 0; q < count; q++, g++) {
        const at = pg.groupsAt + GROUP_BYTES * q;
        const bad = (msg) => chunkFail(at, pg.id, pg.at, `group ${q} of level ${m}: ${msg}`);
        const outputs = u32(b, at), children = u32(b, at + 4), e = dv.getFloat32(at + 8, true), reserved = u16(b, at + 14);
        if (outputs === 0 || children === 0 || reserved !== 0) {
          throw bad(`${outputs} outputs, ${children} children, reserved ${reserved}: outputs and children must be at least 1, reserved 0`);
        }
        if (!(unpack(b, at + 16, gc) && onGrid(gc, last))) throw bad(`sphere center off the ${gbits}-bit grid`);
        const r = fr(radiusSteps(u16(b, at + 12)) * step);
        if (!(e >= 0 && e <= F32_MAX && r <= F32_MAX)) throw bad(`geometric error ${e} and radius ${r} must be finite, the error not negative`);
        if (next + outputs > end) throw bad(`outputs ${next}..+${outputs} run past the level's ${lev.nodes} nodes`);
        gr.level[g] = m;
        gr.firstOutput[g] = next;
        gr.outputs[g] = outputs;
        gr.children[g] = children;
        gr.error[g] = e;
        gr.radius[g] = r;
        for (let c = 0; c < 3; c++) gr.center[3 * g + c] = gridDecode(origin[c], step, gc[c]);
        next += outputs;
      }
      if (next !== end && m > 0) {
        throw chunkFail(pg.groupsAt, pg.id, pg.at, `the outputs of level ${m}'s groups cover nodes up to ${next}; the level ends at ${end}`);
      }
      d.levelGroups[m] = [first, g];
    }
    const named = new Uint32Array(G + 1);
    for (let k = 0; k < P; k++) {
      const m = L - 1 - k, lev = levels[m], pg = pages[k];
      const [a0, a1] = m === L - 1 ? [0, 0] : d.levelGroups[m + 1];
      for (let i = lev.firstNode, end = lev.firstNode + lev.nodes; i < end; i++) {
        const at = pg.recordsAt + NODE_BYTES * (i - lev.firstNode);
        const stored = u32(b, at);
        if (m === L - 1 ? stored !== NO_PARENT : stored >= a1 - a0) {
          const why = m === L - 1 ? 'a top-level node has none (0xFFFFFFFF)' : `level ${m + 1} has ${a1 - a0} groups`;
          throw chunkFail(at, pg.id, pg.at, `node ${i}: consumer ${stored}; ${why}`, i);
        }
        if (m !== L - 1) {
          d.consumer[i] = a0 + stored;
          named[a0 + stored + 1]++;
        }
      }
    }
    for (let q = 0; q < G; q++) {
      const m = gr.level[q];
      if (m > L - P && named[q + 1] !== gr.children[q]) {
        const pg = pages[L - 1 - m], k = q - d.levelGroups[m][0];
        throw chunkFail(pg.groupsAt + GROUP_BYTES * k, pg.id, pg.at, `group ${k} of level ${m}: ${gr.children[q]} children stored, ${named[q + 1]} nodes name it`);
      }
      d.source.fill(q, gr.firstOutput[q], gr.firstOutput[q] + gr.outputs[q]);
    }
    for (let q = 0; q < G; q++) named[q + 1] += named[q];
    d.childOffsets = named;
    d.childItems = new Uint32Array(named[G]);
    const fill = named.slice(0, G);
    for (let i = 0, n = levels[L - P].firstNode + levels[L - P].nodes; i < n; i++) {
      const c = d.consumer[i];
      if (c !== NO_PARENT) d.childItems[fill[c]++] = i;
    }
    return d;
  };
  // The records of every level, the totals, then the neighbour entries, then format 4's groups
  // (the order of the checks, as in strata's reader); top first, the top level and the level below
  // that its nodes' rules are checked against, with their entries.
  const kept = opts.topFirst ? Math.min(L, 2) : L;
  for (let k = kept; k > 0; k--) decodeLevel();
  if (l < 0) finish();
  else if (paged) for (let m = L - 1; m > l; m--) levelTotals(m);
  for (let m = L - 1; m >= L - kept; m--) decodeEntries(m);
  sk.dag = dagFile ? decodeDag() : null;
  // Where the image levels start (§2): checked against the node table by finish().
  const levelsStart = geometryEnd(major, skeletonEnd, levels.reduce((sum, rec) => sum + rec.bytes, 0));

  // MATL
  const merr = (at, msg) => chunkFail(at, 'MATL', matl.at, msg);
  const materials = [];
  let m = matl.ps;
  const mend = matl.pe;
  for (let k = 0; k < h.materials; k++) {
    const str = (what) => {
      const at = m;
      if (mend - m < 4) throw merr(at, `material ${k}: needs 4 more bytes, ${mend - m} left`);
      const len = u32(b, m);
      const s = len <= mend - m - 4 ? utf8(b, m + 4, m + 4 + len) : null;
      if (s === null) throw merr(at, `material ${k}: ${what} of ${len} bytes runs past the chunk or is not UTF-8`);
      m += 4 + len;
      return s;
    };
    const name = str('name');
    if (mend - m < 16) throw merr(m, `material ${k}: needs 16 more bytes, ${mend - m} left`);
    const baseColor = [0, 1, 2, 3].map((c) => dv.getFloat32(m + 4 * c, true));
    m += 16;
    const tex = str('texture');
    materials.push({ name, baseColor, texture: tex === '' ? null : tex });
  }
  if (m < mend && minor <= knownMinor(major)) throw merr(m, `${mend - m} bytes after ${h.materials} materials`);

  // TEXR (2.2), optional: images, their levels after the geometry, material maps, node densities.
  const texrs = subs.filter((x) => x.id === 'TEXR');
  if (texrs.length > 1) throw chunkFail(texrs[1].at, 'SKEL', skelAt, 'has a second TEXR chunk');
  const textures = texrs.length ? decodeTexr(b, texrs[0], N, materials, levelsStart, fileLength) : { images: [], levels: [], uvDensity: new Float32Array(N) };

  // CODE (format 3), required: the coding tables of node payloads. A 2.x file's is ignored.
  const codes = subs.filter((x) => x.id === 'CODE');
  if (codes.length > 1) throw chunkFail(codes[1].at, 'SKEL', skelAt, 'has a second CODE chunk');
  if (v3 && codes.length === 0) throw chunkFail(skelAt, 'SKEL', skelAt, 'has no CODE chunk: format 3 needs its coding tables');
  const code = v3 ? decodeCode(b, codes[0], h.attributes) : null;

  Object.assign(sk, {
    materials,
    textures,
    code,
    boxMid,
    level,
    parent,
    firstChild,
    childCount,
    neighborFirst,
    neighborCount,
    neighborList,
    coneAxis,
    coneHalfAngle,
    center,
    radius,
    boxMin,
    boxMax,
    error,
    faces,
    vertices,
    offset,
    size,
    crc,
  });
  // Where each node's record lies, for errors naming it.
  Object.defineProperty(sk, '_recordAt', {
    value: (i) => {
      const m = level[i], pg = pageOf(m);
      return { id: pg.id, chunkAt: pg.at, at: pg.recordsAt + NODE_BYTES * (i - levels[m].firstNode) };
    },
    enumerable: false,
  });
  sk.decoded = l < 0 ? N : levels[l].firstNode;
  if (l >= 0) {
    // Holds the skeleton's bytes until the rest is decoded; a skeleton decoded from a prefix takes
    // the file's bytes up to skeletonEnd (the prefix's own bytes among them).
    Object.defineProperty(sk, '_rest', {
      value: (bytes) => {
        if (partial) {
          const prefix = subs;
          b = bytes;
          dv = view(b);
          subs = wholeSkel();
          for (let k = 0; k < prefix.length; k++) {
            const s = subs[k];
            if (!s || s.id !== prefix[k].id || s.at !== prefix[k].at || s.size !== prefix[k].size || u32(b, s.pe) !== u32(prefixBytes, s.pe)) {
              throw chunkFail(prefix[k].at, 'SKEL', skelAt, 'its sub-chunks differ from the ones read before (the file changed between reads)');
            }
          }
          pages = pagesPaged(b, subs, levels, skelAt, false, dagFile);
          const list = new Uint32Array(entriesOf(pages));
          list.set(neighborList);
          sk.neighborList = neighborList = list;
        }
        while (l >= 0) decodeLevel();
        finish();
        for (let m = L - kept - 1; m >= 0; m--) decodeEntries(m);
        if (dagFile) sk.dag = decodeDag();
        // The closures kept with the skeleton (_recordAt) share this scope: let the bytes go.
        b = dv = prefixBytes = null;
      },
      configurable: true,
    });
    Object.defineProperty(sk, '_needs', { value: partial ? skeletonEnd : 0, configurable: true });
  } else {
    b = dv = prefixBytes = null;
  }
  return sk;
}

/**
 * SKEL's sub-chunks from its payload's start [sp, se) up to and including the `want`-th NODL page,
 * read from a prefix of the file (strata-v3.md §1.1): each frame's bounds, CRC and padding checked.
 */
function skelPrefix(b, sp, se, skelAt, want, have) {
  const out = [];
  let pos = sp, pages = 0;
  while (pages < want) {
    if (pos + FRAME + TRAILER > se) throw chunkFail(Math.min(pos, se), 'SKEL', skelAt, `ends after ${pages} node pages (NODL); the top ${want} levels need theirs`);
    have(pos + FRAME);
    const e = pos + FRAME + u64(b, pos + 8) + TRAILER;
    const end = e >= se ? se : Math.min(e + padding(e), se);
    have(end);
    const [s] = subChunks(b, pos, end, pos, 'SKEL', skelAt);
    out.push(s);
    if (s.id === 'NODL') pages++;
    pos = end;
  }
  return out;
}

/** The pages of a node table in NODE and NBRS (format 2 and 3.0): each level's slice of NODE, the entries of all levels in NBRS. */
function pagesWhole(node, nbrs, levels) {
  const width = nbrs.flags;
  if (width !== 2 && width !== 4) throw chunkFail(nbrs.at + 4, 'NBRS', nbrs.at, `entry width ${width}; must be 2 or 4`);
  if (nbrs.size % width !== 0) throw chunkFail(nbrs.ps, 'NBRS', nbrs.at, `size ${nbrs.size} is not a multiple of ${width}`);
  const N = levels.reduce((n, lev) => n + lev.nodes, 0);
  if (node.size !== N * NODE_BYTES) throw chunkFail(node.ps, 'NODE', node.at, `holds ${node.size} bytes; ${N} nodes need ${N * NODE_BYTES}`);
  const entryCount = nbrs.size / width;
  return levels
    .map((lev) => ({ id: 'NODE', at: node.at, recordsAt: node.ps + NODE_BYTES * lev.firstNode, entriesId: 'NBRS', entriesChunkAt: nbrs.at, entriesAt: nbrs.ps, width, entryCount, entryBase: 0 }))
    .reverse();
}

/**
 * The pages of format 3.1 on (strata-v3.md §1.1): one NODL per level from the top, after every other
 * sub-chunk; all of them, or with `prefix` the first ones read (the top two levels'). In format 4
 * (`dag`, strata-v4.md §1) a page holds its level's group records before its node records and no
 * neighbour entries.
 */
function pagesPaged(b, subs, levels, skelAt, prefix, dag) {
  const old = subs.find((s) => s.id === 'NODE' || s.id === 'NBRS');
  if (old) throw chunkFail(old.at, 'SKEL', skelAt, `holds a ${old.id} chunk: format 3 keeps nodes in NODL pages`);
  let first = subs.findIndex((s) => s.id === 'NODL');
  if (first < 0) first = subs.length;
  const after = subs.slice(first).find((s) => s.id !== 'NODL');
  if (after) throw chunkFail(after.at, 'SKEL', skelAt, `has a ${after.id} chunk after the node pages`);
  const L = levels.length, count = subs.length - first;
  if (count < (prefix ? Math.min(L, 2) : L) || count > L) throw chunkFail(skelAt, 'SKEL', skelAt, `holds ${count} node pages (NODL) for ${L} levels`);
  const out = [];
  let base = 0;
  for (let k = 0; k < count; k++) {
    const s = subs[first + k], lev = levels[L - 1 - k];
    if (dag) {
      out.push(dagPage(b, s, lev));
      continue;
    }
    const width = s.flags;
    if (width !== 2 && width !== 4) throw chunkFail(s.at + 4, 'NODL', s.at, `entry width ${width}; must be 2 or 4`);
    const records = NODE_BYTES * lev.nodes;
    if (s.size < records || (s.size - records) % width !== 0) {
      throw chunkFail(s.ps, 'NODL', s.at, `holds ${s.size} bytes: ${lev.nodes} node records and whole ${width}-byte entries do not fill it`);
    }
    const entryCount = (s.size - records) / width;
    out.push({ id: 'NODL', at: s.at, recordsAt: s.ps, entriesId: 'NODL', entriesChunkAt: s.at, entriesAt: s.ps + records, width, entryCount, entryBase: base });
    base += entryCount;
  }
  return out;
}

/** A format-4 page (strata-v4.md §1): the group count G, G group records, the level's node records. */
function dagPage(b, s, lev) {
  if (s.flags !== 0) throw chunkFail(s.at + 4, 'NODL', s.at, `flags ${s.flags}; a format-4 page has 0`);
  if (s.size < 4) throw chunkFail(s.ps, 'NODL', s.at, `holds ${s.size} bytes, too few for its group count`);
  const groupCount = u32(b, s.ps);
  const want = 4 + GROUP_BYTES * groupCount + NODE_BYTES * lev.nodes;
  if (s.size !== want) throw chunkFail(s.ps, 'NODL', s.at, `holds ${s.size} bytes; ${groupCount} group records and ${lev.nodes} node records need ${want}`);
  const groupsAt = s.ps + 4;
  return { id: 'NODL', at: s.at, recordsAt: groupsAt + GROUP_BYTES * groupCount, entriesId: 'NODL', entriesChunkAt: s.at, entriesAt: s.pe, width: 2, entryCount: 0, entryBase: 0, groupsAt, groupCount };
}

// ---------------------------------------------------------------------------------------------
// Separating planes (§7.6, format 2.3).

/** Where the ORDR chunk starts if the file has one: after the last GEOM (or GEOS) or TEXL and its padding. */
export function planesOffset(sk) {
  let end = geometryEnd(sk.major, sk.skeletonEnd, sk.levels.reduce((a, l) => a + l.bytes, 0));
  for (const l of sk.textures.levels) end = Math.max(end, l.offset + l.size + ((8 - ((l.offset + l.size) % 8)) % 8));
  return end;
}

/**
 * The ORDR chunk from `bytes`, the file from planesOffset(sk) on (empty: no planes; chunks of newer minors may follow):
 * `{ starts, entries }`, starts[p]..starts[p+1] the entries of parent p (0 = the virtual root,
 * i + 1 = node i), each `{ first, second, normal, firstMax, secondMin }`.
 */
export function decodePlanes(sk, bytes) {
  if (bytes.length === 0) return { starts: [], entries: [] };
  const at = planesOffset(sk);
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const err = (o, msg) => chunkFail(at + o, 'ORDR', at, msg);
  if (bytes.length < FRAME + 4) throw err(0, `${bytes.length} bytes after the geometry, too few for a chunk`);
  const id = String.fromCharCode(...bytes.subarray(0, 4));
  if (id === 'ORDR' && sk.dag) throw err(0, 'an ORDR chunk in a format-4 file, which has no separating planes (strata-v4.md §0)');
  if (id !== 'ORDR') throw err(0, `${id} follows the geometry and images; only ORDR may`);
  const width = dv.getUint32(4, true);
  const size = Number(dv.getBigUint64(8, true));
  const end = FRAME + size + 4;
  if (!(end <= bytes.length)) throw err(8, `size ${size} runs past the end of the file`);
  const stored = dv.getUint32(FRAME + size, true), actual = crc32(bytes, FRAME, FRAME + size);
  if (stored !== actual) throw err(FRAME + size, `CRC ${hex(actual)} != stored ${hex(stored)}`);
  if (width !== 2 && width !== 4) throw err(4, `entry index width ${width}; must be 2 or 4`);
  const parents = sk.nodeCount + 1;
  if (size < 4 * parents) throw err(FRAME, `holds ${size} bytes; the counts of ${parents} parents need ${4 * parents}`);
  const starts = [0];
  let total = 0;
  for (let p = 0; p < parents; p++) starts.push((total += dv.getUint32(FRAME + 4 * p, true)));
  const entry = 2 * width + 12;
  if (size - 4 * parents !== total * entry) {
    throw err(FRAME, `${total} entries of ${entry} bytes need ${total * entry}; ${size - 4 * parents} follow the counts`);
  }
  const top = sk.levels[sk.levels.length - 1].nodes;
  const entries = [];
  let o = FRAME + 4 * parents;
  for (let p = 0; p < parents; p++) {
    const children = p === 0 ? top : sk.childCount[p - 1];
    const who = p === 0 ? 'the top level' : `node ${p - 1}`;
    let last = null;
    for (let k = starts[p]; k < starts[p + 1]; k++, o += entry) {
      const idx = (q) => (width === 2 ? dv.getUint16(q, true) : dv.getUint32(q, true));
      const first = idx(o), second = idx(o + width);
      const normal = [dv.getInt16(o + 2 * width, true), dv.getInt16(o + 2 * width + 2, true)];
      const firstMax = dv.getFloat32(o + 2 * width + 4, true), secondMin = dv.getFloat32(o + 2 * width + 8, true);
      const lo = Math.min(first, second), hi = Math.max(first, second);
      if (first === second || hi >= children) throw err(o, `${who}: a plane between children ${first} and ${second} of ${children}`);
      if (last && (last[0] > lo || (last[0] === lo && last[1] >= hi))) {
        throw err(o, `${who}: the plane between children ${lo} and ${hi} is out of order or repeated`);
      }
      if (!(Number.isFinite(firstMax) && Number.isFinite(secondMin))) throw err(o, `${who}: plane bounds ${firstMax} and ${secondMin} must be finite`);
      last = [lo, hi];
      entries.push({ first, second, normal, firstMax, secondMin });
    }
  }
  return { starts, entries };
}

// ---------------------------------------------------------------------------------------------
// Images (§7.5, format 2.2).

/** Map slots of a material, in TEXR's order. */
export const MAP_KINDS = ['baseColor', 'normal', 'metallicRoughness', 'occlusion', 'emissive'];
const LEVEL_ENTRY_BYTES = 24;
const MAX_IMAGE_LEVELS = 32;
const MAX_IMAGE_SIDE = 65536;
const MAX_IMAGE_PIXELS = 2 ** 28;
const MAX_IMAGE_NAME = 4096;
const NO_IMAGE = 0xffffffff;
/** Media types of the image codecs (1 PNG, 2 JPEG). */
export const IMAGE_MIME = { 1: 'image/png', 2: 'image/jpeg' };

/** UV units per model unit of a node's density code (0 for none). */
export function densityDecode(code) {
  return code === 0 ? 0 : fr(2 ** ((code - 32768) / 256));
}

/**
 * The TEXR sub-chunk `t`: image records, level entries with their TEXL offsets (back to back from
 * `levelsStart`, the end of the geometry), each material's maps (set on `materials[k].maps`) and
 * each node's UV density. Every count is checked against the payload before use.
 */
function decodeTexr(b, t, N, materials, levelsStart, fileLength) {
  const err = (at, msg) => chunkFail(at, 'TEXR', t.at, msg);
  const end = t.pe;
  let p = t.ps;
  const need = (n, what) => {
    if (end - p < n) throw err(p, `${what}: needs ${n} more bytes, ${end - p} left`);
  };
  need(8, 'counts');
  const count = u32(b, p), entries = u32(b, p + 4);
  p += 8;
  if (count === 0) throw err(t.ps, 'holds no image; a file without images has no TEXR chunk');
  // Every image record takes at least 8 bytes and every entry 24: refused before allocating.
  const least = count * 8 + entries * LEVEL_ENTRY_BYTES;
  if (least > end - p) throw err(t.ps, `${count} images and ${entries} level entries need at least ${least} bytes, ${end - p} left`);
  const images = [];
  let total = 0;
  for (let i = 0; i < count; i++) {
    const at = p;
    need(4, `image ${i}`);
    const len = u32(b, p);
    if (len > MAX_IMAGE_NAME) throw err(at, `image ${i}: a name of ${len} bytes (at most ${MAX_IMAGE_NAME})`);
    const name = len <= end - p - 4 ? utf8(b, p + 4, p + 4 + len) : null;
    if (name === null) throw err(at, `image ${i}: name of ${len} bytes runs past the chunk or is not UTF-8`);
    p += 4 + len;
    need(4, `image ${i}`);
    const codec = b[p], k = b[p + 1];
    if (codec !== 1 && codec !== 2) throw err(p, `image ${i}: unknown codec ${codec}`);
    if (k === 0 || k > MAX_IMAGE_LEVELS || b[p + 2] !== 0 || b[p + 3] !== 0) {
      throw err(p, `image ${i}: ${k} levels (1..=${MAX_IMAGE_LEVELS}) or non-zero reserved bytes`);
    }
    p += 4;
    total += k;
    if (total > entries) throw err(at, `image ${i}: images with more levels than the ${entries} level entries`);
    images.push({ name, codec, levels: new Array(k).fill(-1) });
  }
  if (entries !== total) throw err(t.ps + 4, `${entries} level entries for images with ${total} levels`);
  need(entries * LEVEL_ENTRY_BYTES, `${entries} level entries`);
  const levels = [];
  let offset = levelsStart;
  for (let e = 0; e < entries; e++) {
    const at = p;
    const [image, level, width, height, size, crc] = [0, 4, 8, 12, 16, 20].map((o) => u32(b, p + o));
    p += LEVEL_ENTRY_BYTES;
    const bad = (msg) => err(at, `level entry ${e}: ${msg}`);
    if (image >= count) throw bad(`image ${image} of ${count}`);
    const rec = images[image];
    if (level >= rec.levels.length) throw bad(`level ${level} of image ${image}'s ${rec.levels.length}`);
    if (rec.levels[level] !== -1) throw bad(`level ${level} of image ${image} a second time`);
    rec.levels[level] = e;
    if (width === 0 || height === 0 || width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE || width * height > MAX_IMAGE_PIXELS) {
      throw bad(`${width} × ${height} pixels (1..=${MAX_IMAGE_SIDE} a side, at most ${MAX_IMAGE_PIXELS} in all)`);
    }
    if (size < FRAME + TRAILER + 1) throw bad(`a chunk of ${size} bytes`);
    const stop = offset + size;
    if (stop > fileLength) throw bad(`its chunk at offset ${offset} (${size} bytes) runs past the end of the file (${fileLength} bytes)`);
    levels.push({ image, level, width, height, offset, size, crc });
    offset = stop + padding(stop);
  }
  images.forEach((rec, i) => {
    for (let l = 1; l < rec.levels.length; l++) {
      const a = levels[rec.levels[l - 1]], c = levels[rec.levels[l]];
      if (c.width !== Math.ceil(a.width / 2) || c.height !== Math.ceil(a.height / 2) || (a.width === 1 && a.height === 1)) {
        throw err(
          t.ps,
          `image ${i}: level ${a.level} is ${a.width} × ${a.height}, level ${c.level} ${c.width} × ${c.height}; each level must halve the one before, rounding up`,
        );
      }
    }
  });
  need(materials.length * 8 * MAP_KINDS.length, 'material maps');
  materials.forEach((mat, k) => {
    mat.maps = {};
    MAP_KINDS.forEach((kind, slot) => {
      const at = p;
      const image = u32(b, p), ws = b[p + 4], wt = b[p + 5];
      p += 8;
      if (b[at + 6] !== 0 || b[at + 7] !== 0) throw err(at, `material ${k} slot ${slot}: non-zero reserved bytes`);
      if (ws > 2 || wt > 2) throw err(at, `material ${k} slot ${slot}: unknown wrap modes ${ws} ${wt}`);
      if (image === NO_IMAGE) mat.maps[kind] = null;
      else if (image < count) mat.maps[kind] = { image, wrap: [ws, wt] };
      else throw err(at, `material ${k} slot ${slot}: image ${image} of ${count}`);
    });
  });
  need(2 * N, 'node densities');
  const uvDensity = new Float32Array(N);
  for (let i = 0; i < N; i++) uvDensity[i] = densityDecode(u16(b, p + 2 * i));
  p += 2 * N;
  if (p < end) throw err(p, `${end - p} bytes after the node densities`);
  return { images, levels, uvDensity };
}

/** Width and height a PNG or JPEG file's header states (codec 1 or 2), or a message why not. */
export function imageSize(codec, b) {
  if (codec === 1) {
    const sig = [0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a];
    if (b.length < 24 || sig.some((x, k) => b[k] !== x) || !isId(b, 12, 'IHDR')) return 'not a PNG file (no signature and IHDR)';
    const be = (o) => ((b[o] << 24) | (b[o + 1] << 16) | (b[o + 2] << 8) | b[o + 3]) >>> 0;
    return [be(16), be(20)];
  }
  if (b.length < 4 || b[0] !== 0xff || b[1] !== 0xd8) return 'not a JPEG file (no start-of-image marker)';
  let at = 2;
  while (at + 4 <= b.length) {
    if (b[at] !== 0xff) return `no JPEG marker at byte ${at}`;
    const marker = b[at + 1];
    if (marker === 0xff) {
      at += 1;
      continue;
    }
    const len = (b[at + 2] << 8) | b[at + 3];
    if (marker >= 0xc0 && marker <= 0xcf && marker !== 0xc4 && marker !== 0xc8 && marker !== 0xcc) {
      if (at + 9 > b.length) break;
      return [(b[at + 7] << 8) | b[at + 8], (b[at + 5] << 8) | b[at + 6]];
    }
    if (marker === 0xda || len < 2) break;
    at += 2 + len;
  }
  return 'no JPEG start-of-frame marker before the image data';
}

/**
 * Check the TEXL chunk `bytes` of level entry `e` of `skeleton` (its `size` bytes, ID through CRC):
 * ID, size, CRC against trailer and entry, and the image header's size. Returns the image file's
 * bytes (a view into `bytes`).
 */
export function decodeImageLevel(skeleton, e, bytes) {
  const lv = skeleton.textures.levels[e];
  if (!lv) throw fail(undefined, `no image level entry ${e}`);
  const rec = skeleton.textures.images[lv.image];
  const at = lv.offset;
  const bad = (o, msg) => chunkFail(o, 'TEXL', at, `image ${lv.image} level ${lv.level}: ${msg}`);
  if (bytes.length !== lv.size) throw bad(at, `${bytes.length} bytes, the entry says ${lv.size}`);
  if (!isId(bytes, 0, 'TEXL')) throw bad(at, `${idStr(bytes, 0)} where a TEXL chunk should be`);
  const size = u64(bytes, 8);
  if (size + FRAME + TRAILER !== lv.size) throw bad(at + 8, `payload size ${size} does not match the entry's ${lv.size} bytes`);
  const end = bytes.length - TRAILER;
  const stored = u32(bytes, end), actual = crc32(bytes, FRAME, end);
  if (stored !== actual || stored !== lv.crc) throw bad(at + end, `CRC ${hex(actual)}, stored ${hex(stored)}, table ${hex(lv.crc)}`);
  const file = bytes.subarray(FRAME, end);
  const dims = imageSize(rec.codec, file);
  if (typeof dims === 'string') throw bad(at + FRAME, dims);
  if (dims[0] !== lv.width || dims[1] !== lv.height) throw bad(at + FRAME, `the image is ${dims[0]} × ${dims[1]}, the entry says ${lv.width} × ${lv.height}`);
  return file;
}

// ---------------------------------------------------------------------------------------------
// Rules (§6, §10), as src/format/rules.rs checks them.

/** Angle between two directions, in f64 (atan2 of |a × b| and a·b). */
function angle(ax, ay, az, bx, by, bz) {
  const cx = ay * bz - by * az, cy = az * bx - bz * ax, cz = ax * by - bx * ay;
  return Math.atan2(Math.sqrt(cx * cx + cy * cy + cz * cz), ax * bx + ay * by + az * bz);
}

const coneCovers = (half, needed) => needed <= half + ANGLE_TOLERANCE || half >= Math.PI - ANGLE_TOLERANCE;

/** The squared reach of a sphere of radius r, with the tolerance of the stored radius, in f32. */
function sphereReach(r) {
  const x = fr(fr(r * RADIUS_FACTOR) + RADIUS_TINY);
  return fr(x * x);
}

/** Squared distance between f32 points, computed in f32 as glam does. */
function dist2(ax, ay, az, bx, by, bz) {
  const dx = fr(ax - bx), dy = fr(ay - by), dz = fr(az - bz);
  return fr(fr(fr(dx * dx) + fr(dy * dy)) + fr(dz * dz));
}

/**
 * A cone tested against many directions d (any length; zero holds): angle(axis, d) ≤ half + 1e-5
 * as (axis·d)·sin(reach) − |axis × d|·cos(reach) ≥ 0, in f64 (rules::ConeTest).
 */
class ConeTest {
  constructor(ax, ay, az, half) {
    this.ax = ax;
    this.ay = ay;
    this.az = az;
    this.all = half >= Math.PI - ANGLE_TOLERANCE;
    const reach = half + ANGLE_TOLERANCE;
    this.sin = Math.sin(reach);
    this.cos = Math.cos(reach);
  }
}

function coneHolds(t, dx, dy, dz) {
  if (t.all) return true;
  const ax = t.ax, ay = t.ay, az = t.az;
  const cx = ay * dz - dy * az, cy = az * dx - dz * ax, cz = ax * dy - dx * ay;
  return (ax * dx + ay * dy + az * dz) * t.sin - Math.sqrt(cx * cx + cy * cy + cz * cz) * t.cos >= 0;
}

/** Node i's rules on the skeleton: children, neighbours, HEAD bounds (rules::relations). */
function relations(s, i) {
  const rec = s._recordAt ? s._recordAt(i) : null;
  const problem = (msg) => (rec ? chunkFail(rec.at, rec.id, rec.chunkAt, `node ${i}: ${msg}`, i) : fail(undefined, `node ${i}: ${msg}`, i));
  const A = s.coneAxis, C = s.center, bmin = s.boxMin, bmax = s.boxMax;
  const i3 = 3 * i;
  const half = s.coneHalfAngle[i];
  const reach = fr(fr(s.radius[i] * RADIUS_FACTOR) + RADIUS_TINY);
  for (let c = s.firstChild[i], e = c + s.childCount[i]; c < e; c++) {
    const c3 = 3 * c;
    if (!coneCovers(half, angle(A[i3], A[i3 + 1], A[i3 + 2], A[c3], A[c3 + 1], A[c3 + 2]) + s.coneHalfAngle[c])) {
      throw problem(`cone does not contain child ${c}'s`);
    }
    for (let k = 0; k < 3; k++) {
      if (!(bmin[i3 + k] <= bmin[c3 + k] && bmax[c3 + k] <= bmax[i3 + k])) throw problem(`box does not contain child ${c}'s`);
    }
    const d = fr(Math.sqrt(dist2(C[i3], C[i3 + 1], C[i3 + 2], C[c3], C[c3 + 1], C[c3 + 2])));
    if (fr(d + s.radius[c]) > reach) throw problem(`sphere does not contain child ${c}'s`);
    if (s.error[c] > s.error[i]) throw problem(`error ${s.error[i]} is smaller than child ${c}'s ${s.error[c]}`);
  }
  const nb = s.neighbors(i);
  for (let k = 1; k < nb.length; k++) if (nb[k - 1] >= nb[k]) throw problem('neighbours are not strictly ascending');
  const l = s.level[i];
  const [lo, hi] = s.levelNodes(l);
  for (const j of nb) {
    if (j === i || j < lo || j >= hi || !s.neighbors(j).includes(i)) {
      throw problem(`neighbour ${j} is not a different node of level ${l} listing it back`);
    }
  }
  if (l === s.top()) {
    const { min, max } = s.header;
    for (let k = 0; k < 3; k++) {
      if (!(min[k] <= bmin[i3 + k] && bmax[i3 + k] <= max[k])) throw problem('box lies outside the HEAD bounds');
    }
  }
}

/** Whether face f's normal (b − a) × (c − a), in f64 from the f32 positions, lies in cone t. */
function faceInCone(P, I, f, t) {
  if (t.all) return true;
  const a = 3 * I[3 * f], b = 3 * I[3 * f + 1], c = 3 * I[3 * f + 2];
  const px = P[a], py = P[a + 1], pz = P[a + 2];
  const ux = P[b] - px, uy = P[b + 1] - py, uz = P[b + 2] - pz;
  const vx = P[c] - px, vy = P[c + 1] - py, vz = P[c + 2] - pz;
  return coneHolds(t, uy * vz - vy * uz, uz * vx - vz * ux, ux * vy - vx * uy);
}

/** Whether the three corners of face f lie within squared reach r of (ox, oy, oz), in f32. */
function faceInSphere(P, I, f, ox, oy, oz, r) {
  for (let k = 0; k < 3; k++) {
    const v = 3 * I[3 * f + k];
    if (dist2(ox, oy, oz, P[v], P[v + 1], P[v + 2]) > r) return false;
  }
  return true;
}

/** Every vertex inside the node's box and sphere. */
function vertexRules(s, i, P, problem) {
  const i3 = 3 * i;
  const x0 = s.boxMin[i3], y0 = s.boxMin[i3 + 1], z0 = s.boxMin[i3 + 2];
  const x1 = s.boxMax[i3], y1 = s.boxMax[i3 + 1], z1 = s.boxMax[i3 + 2];
  const V = P.length / 3;
  for (let k = 0; k < V; k++) {
    const x = P[3 * k], y = P[3 * k + 1], z = P[3 * k + 2];
    if (!(x0 <= x && x <= x1 && y0 <= y && y <= y1 && z0 <= z && z <= z1)) throw problem(`vertex ${k} lies outside the node's box`);
  }
  const cx = s.center[i3], cy = s.center[i3 + 1], cz = s.center[i3 + 2];
  const reach = sphereReach(s.radius[i]);
  // The f32 distance lies within 3·10⁻⁷ of the true one (five roundings) unless it underflows:
  // the f64 one decides away from the boundary, the f32 one as Rust computes it near it.
  const inside = reach * (1 - 1e-6), outside = Math.max(reach * (1 + 1e-6), 1e-30);
  for (let k = 0; k < V; k++) {
    const x = P[3 * k], y = P[3 * k + 1], z = P[3 * k + 2];
    const d = (cx - x) * (cx - x) + (cy - y) * (cy - y) + (cz - z) * (cz - z);
    if (d <= inside) continue;
    if (d > outside || !(dist2(cx, cy, cz, x, y, z) <= reach)) throw problem(`vertex ${k} lies outside the node's sphere`);
  }
}

/**
 * Every cluster's faces inside its cone and sphere (a problem thrown at the first cluster broken);
 * returns the first face whose normal lies outside the node's cone `cone`, or −1.
 */
function clusterRules(P, I, clusters, cone, half, problem) {
  let outsideCone = -1;
  for (let q = 0; q < clusters.length; q++) {
    const cl = clusters[q];
    const ax = cl.axis, o = cl.center;
    // A face within a cluster cone that lies inside the node's is within the node's too.
    const nested = angle(cone.ax, cone.ay, cone.az, ax[0], ax[1], ax[2]) + cl.halfAngle <= half;
    const clCone = new ConeTest(ax[0], ax[1], ax[2], cl.halfAngle);
    const r = sphereReach(cl.radius);
    for (let f = cl.firstFace, e = f + cl.faceCount; f < e; f++) {
      if (!faceInCone(P, I, f, clCone) || !faceInSphere(P, I, f, o[0], o[1], o[2], r)) {
        throw problem(`a face of the cluster at face ${cl.firstFace} lies outside its cone or sphere`);
      }
      if (outsideCone < 0 && !nested && !faceInCone(P, I, f, cone)) outsideCone = f;
    }
  }
  return outsideCone;
}

/** Node i's rules on its decoded geometry (rules::node), in the order Rust reports them. */
function nodeRules(s, i, g, problem) {
  const P = g.positions, I = g.indices, uvs = g.uvs;
  if (uvs !== null) {
    for (let k = 0; k < uvs.length; k++) if (!Number.isFinite(uvs[k])) throw problem(`UV ${k >> 1} is not finite`);
  }
  vertexRules(s, i, P, problem);
  const i3 = 3 * i;
  const half = s.coneHalfAngle[i];
  const cone = new ConeTest(s.coneAxis[i3], s.coneAxis[i3 + 1], s.coneAxis[i3 + 2], half);
  let outsideCone = -1;
  // Format 3's clusters have no cones (face ranges only): every face against the node's cone.
  if (g.clusters.length === 0 || g.clusters[0].axis === undefined) {
    for (let f = 0, F = I.length / 3; f < F; f++) {
      if (!faceInCone(P, I, f, cone)) {
        outsideCone = f;
        break;
      }
    }
  } else {
    outsideCone = clusterRules(P, I, g.clusters, cone, half, problem);
  }
  if (outsideCone >= 0) throw problem(`face ${outsideCone}'s normal lies outside the node's cone`);
}

// ---------------------------------------------------------------------------------------------
// A node's geometry (§8, §10 "To read a node").

const GEOM_KINDS = ['VPOS', 'VNRM', 'VTEX', 'VCOL', 'INDX', 'MATR', 'CLUS'];

/**
 * What the decoders of a node's sub-chunks share: its bytes (b[k] is at file offset at + k), counts
 * and grid. Each sub-chunk has its own small function, so that the JIT specializes each one.
 */
class NodeCtx {
  constructor(s, i, b) {
    this.i = i;
    this.b = b;
    this.at = s.offset[i];
    this.V = s.vertices[i];
    this.F = s.faces[i];
    const g = s.header.grid;
    this.origin = g.origin;
    this.step = g.step;
    this.bits = g.bits;
    this.last = 2 ** g.bits - 1;
    this.materials = s.header.materials;
  }

  /** An error at file offset `off` inside the node's GEOM chunk. */
  err(off, msg) {
    return chunkFail(off, 'GEOM', this.at, `node ${this.i}: ${msg}`, this.i);
  }

  /** Check that a per-vertex sub-chunk holds `per` bytes a vertex. */
  perVertex(sub, per, what) {
    const V = this.V;
    if (sub.size !== V * per) throw this.err(sub.at + 8, `${sub.id} holds ${sub.size} bytes; ${V} vertices need ${V * per} for ${what}`);
  }
}

/** VPOS (§8.1): the base and grid points, decoded to f32 positions (and to `local` if asked). */
function decodePositions(c, vp, localOrigin) {
  const { b, V, step, last } = c;
  const w = vp.flags;
  if (w !== 2 && w !== 3) throw c.err(vp.at + 4, `position width ${w}; must be 2 or 3`);
  if (vp.size !== 12 + 3 * w * V) throw c.err(vp.at + 8, `VPOS holds ${vp.size} bytes; ${V} vertices need ${12 + 3 * w * V} for positions`);
  const b0 = u32(b, vp.ps), b1 = u32(b, vp.ps + 4), b2 = u32(b, vp.ps + 8);
  c.base = [b0, b1, b2];
  const [o0, o1, o2] = c.origin;
  const positions = new Float32Array(3 * V);
  const local = localOrigin ? new Float32Array(3 * V) : null;
  const [s0, s1, s2] = localOrigin ? [o0 - localOrigin[0], o1 - localOrigin[1], o2 - localOrigin[2]] : [0, 0, 0];
  const p0 = vp.ps + 12;
  for (let k = 0, o = p0; k < V; k++) {
    let g0, g1, g2;
    if (w === 2) {
      g0 = b0 + (b[o] | (b[o + 1] << 8));
      g1 = b1 + (b[o + 2] | (b[o + 3] << 8));
      g2 = b2 + (b[o + 4] | (b[o + 5] << 8));
      o += 6;
    } else {
      g0 = b0 + (b[o] | (b[o + 1] << 8) | (b[o + 2] << 16));
      g1 = b1 + (b[o + 3] | (b[o + 4] << 8) | (b[o + 5] << 16));
      g2 = b2 + (b[o + 6] | (b[o + 7] << 8) | (b[o + 8] << 16));
      o += 9;
    }
    if (g0 > last || g1 > last || g2 > last) throw c.err(c.at + p0 + 3 * w * k, `vertex ${k} lies off the ${c.bits}-bit grid`);
    // A Float32Array store rounds to the nearest f32: one rounding of the f64 o + g·s.
    const k3 = 3 * k;
    positions[k3] = o0 + g0 * step;
    positions[k3 + 1] = o1 + g1 * step;
    positions[k3 + 2] = o2 + g2 * step;
    if (local) {
      local[k3] = s0 + g0 * step;
      local[k3 + 1] = s1 + g1 * step;
      local[k3 + 2] = s2 + g2 * step;
    }
  }
  return { positions, local };
}

/** VNRM (§8.2). */
function decodeNormals(c, sub) {
  c.perVertex(sub, 4, 'normals');
  const { b, V } = c;
  const normals = new Float32Array(3 * V);
  for (let k = 0, o = sub.ps; k < V; k++, o += 4) octaDecode(i16(b, o), i16(b, o + 2), normals, 3 * k);
  return normals;
}

/** VTEX (§8.5): f32 pairs, bit for bit. */
function decodeUvs(c, sub) {
  c.perVertex(sub, 8, 'UVs');
  const { b, V } = c;
  const uvs = new Float32Array(2 * V);
  const dv = view(b);
  for (let k = 0, o = sub.ps; k < 2 * V; k++, o += 4) uvs[k] = dv.getFloat32(o, true);
  return uvs;
}

/** VCOL (§8.5). */
function decodeColors(c, sub) {
  c.perVertex(sub, 4, 'colors');
  return new Uint8Array(c.b.subarray(sub.ps, sub.pe)); // a copy (a Node Buffer's slice would share memory)
}

/** INDX (§8.3): 3F indices, each below V. */
function decodeIndices(c, ix) {
  const { b, V, F } = c;
  const iw = ix.flags;
  const n = 3 * F;
  if (iw !== 2 && iw !== 4) throw c.err(ix.at + 4, `index width ${iw}; must be 2 or 4`);
  if (ix.size !== n * iw) throw c.err(ix.at + 8, `INDX holds ${ix.size} bytes; ${F} faces need ${n * iw}`);
  const indices = new Uint32Array(n);
  let bad = -1;
  if (iw === 2) {
    for (let k = 0, o = ix.ps; k < n; k++, o += 2) {
      const x = b[o] | (b[o + 1] << 8);
      if (x >= V) {
        bad = k;
        break;
      }
      indices[k] = x;
    }
  } else {
    for (let k = 0, o = ix.ps; k < n; k++, o += 4) {
      const x = u32(b, o);
      if (x >= V) {
        bad = k;
        break;
      }
      indices[k] = x;
    }
  }
  if (bad >= 0) {
    const x = iw === 2 ? u16(b, ix.ps + 2 * bad) : u32(b, ix.ps + 4 * bad);
    throw c.err(c.at + ix.ps + iw * bad, `index ${bad} is ${x} of ${V} vertices`);
  }
  return indices;
}

/** MATR (§8.4): ranges tiling the indices, of known materials. */
function decodeRanges(c, mr) {
  const b = c.b;
  const n = 3 * c.F;
  if (mr.size % RANGE_BYTES !== 0) throw c.err(mr.at + 8, `MATR size ${mr.size} is not a multiple of ${RANGE_BYTES}`);
  const ranges = [];
  let next = 0;
  for (let k = 0, o = mr.ps; o < mr.pe; k++, o += RANGE_BYTES) {
    const material = u32(b, o), first = u32(b, o + 4), count = u32(b, o + 8);
    if (first !== next || count === 0 || count % 3 !== 0 || material >= c.materials) {
      throw c.err(
        c.at + o,
        `material range ${k} (${material}, ${first}, ${count}) does not continue at index ${next} with a whole number of faces of a known material`,
      );
    }
    next += count;
    ranges.push([material, first, count]);
  }
  if (next !== n) throw c.err(mr.at, `material ranges cover ${next} of ${n} indices`);
  return ranges;
}

/** CLUS (§8.7): culling clusters tiling the faces. */
function decodeClusters(c, cs) {
  const { b, base, origin, step, last } = c;
  if (cs.size % CLUSTER_BYTES !== 0) throw c.err(cs.at + 8, `CLUS size ${cs.size} is not a multiple of ${CLUSTER_BYTES}`);
  const t = cs.flags;
  if (t > c.bits) throw c.err(cs.at + 4, `CLUS shift ${t} exceeds the ${c.bits} grid bits`);
  const scale = 2 ** t;
  const axis = new Float32Array(3);
  const clusters = [];
  let next = 0;
  for (let k = 0, o = cs.ps; o < cs.pe; k++, o += CLUSTER_BYTES) {
    const faceCount = u16(b, o + 6);
    const g0 = base[0] + u16(b, o + 8) * scale, g1 = base[1] + u16(b, o + 10) * scale, g2 = base[2] + u16(b, o + 12) * scale;
    if (faceCount === 0) throw c.err(c.at + o, `cluster ${k} has no faces`);
    if (g0 > last || g1 > last || g2 > last) throw c.err(c.at + o, `cluster ${k}'s center lies off the ${c.bits}-bit grid`);
    octaDecode(i16(b, o), i16(b, o + 2), axis, 0);
    clusters.push({
      axis: [axis[0], axis[1], axis[2]],
      halfAngle: angleDecode(u16(b, o + 4)),
      center: [gridDecode(origin[0], step, g0), gridDecode(origin[1], step, g1), gridDecode(origin[2], step, g2)],
      radius: fr(radiusSteps(u16(b, o + 14)) * step),
      firstFace: next,
      faceCount,
    });
    next += faceCount;
  }
  if (next !== c.F) throw c.err(cs.at, `clusters cover ${next} of ${c.F} faces`);
  return clusters;
}

/**
 * Decode and check node i's geometry: `bytes` are exactly the node's `size` bytes at
 * skeleton.offset[i], its GEOM chunk (format 2) or its payload inside GEOS (format 3). Returns
 * `{ positions, normals, uvs, colors, indices, materialRanges, clusters }` (typed arrays, null for
 * an attribute the file lacks; material ranges as [material, first index, index count]; clusters
 * with their cone and sphere in format 2, as `{ firstFace, faceCount }` only in format 3).
 * opts.localOrigin = [x, y, z] also returns `local`, positions relative to it computed in f64
 * before the one rounding to f32.
 */
export function decodeNode(skeleton, i, bytes, opts = {}) {
  const s = skeleton;
  const N = s.nodeCount;
  if (!(Number.isInteger(i) && i >= 0 && i < N)) throw fail(undefined, `node ${i}: no such node; the file has ${N}`);
  if (!isComplete(s) && !(i < s.decoded && s.firstChild[i] + s.childCount[i] <= s.decoded)) {
    throw fail(undefined, `node ${i}: its record or its children's are not decoded yet (completeSkeleton)`);
  }
  if (s.major >= 3) {
    const geometry = decodeNode3(s, i, bytes, opts);
    relations(s, i);
    nodeRules(s, i, geometry, (msg) => chunkFail(s.offset[i], 'GEOS', s.skeletonEnd, `node ${i}: ${msg}`, i));
    return geometry;
  }
  const b = bytes;
  const at = s.offset[i], size = s.size[i];
  if (b.length !== size || b.length < FRAME + TRAILER) {
    throw chunkFail(at, 'GEOM', at, `node ${i}'s geometry is ${b.length} bytes, its record says ${size}`, i);
  }
  const id = idStr(b, 0);
  if (id !== 'GEOM') throw chunkFail(at, id, at, `node ${i}'s geometry should be a GEOM chunk`, i);
  const psize = u64(b, 8);
  if (psize + FRAME + TRAILER !== size) throw chunkFail(at + 8, id, at, `size ${psize} does not match node ${i}'s ${size} bytes`, i);
  const end = size - TRAILER;
  const stored = u32(b, end), actual = crc32(b, FRAME, end);
  if (stored !== actual || stored !== s.crc[i]) {
    throw chunkFail(at + end, id, at, `CRC ${hex(actual)}, stored ${hex(stored)}, node table ${hex(s.crc[i])}`, i);
  }
  const c = new NodeCtx(s, i, b);
  const subs = subChunks(b, FRAME, end, at + FRAME, 'GEOM', at, i);
  const found = [null, null, null, null, null, null, null];
  for (const sub of subs) {
    const k = GEOM_KINDS.indexOf(sub.id);
    if (k < 0) continue;
    if (found[k]) throw c.err(sub.at, `a second ${sub.id} chunk`);
    found[k] = sub;
  }
  const attrs = s.header.attributes;
  const wanted = [true, attrs.normals, attrs.uvs, attrs.colors, true, true, s.level[i] === 0];
  for (let k = 0; k < 7; k++) {
    if (!!found[k] !== wanted[k]) throw c.err(at, `${wanted[k] ? 'lacks' : 'should not have'} a ${GEOM_KINDS[k]} chunk`);
  }
  const { positions, local } = decodePositions(c, found[0], opts.localOrigin);
  const normals = found[1] ? decodeNormals(c, found[1]) : null;
  const uvs = found[2] ? decodeUvs(c, found[2]) : null;
  const colors = found[3] ? decodeColors(c, found[3]) : null;
  const indices = decodeIndices(c, found[4]);
  const materialRanges = decodeRanges(c, found[5]);
  const clusters = found[6] ? decodeClusters(c, found[6]) : [];
  const geometry = { positions, normals, uvs, colors, indices, materialRanges, clusters };
  if (local) geometry.local = local;
  relations(s, i);
  nodeRules(s, i, geometry, (msg) => c.err(at, msg));
  return geometry;
}

// ---------------------------------------------------------------------------------------------
// Format 3 (format-spec/strata-v3.md): the coding tables (§3) and a node's payload (§4, §5), as
// src/format/geom/v3.rs, rans.rs and bits.rs decode them.

const ALPHABETS = 64;
const PROB_BITS = 11;
const PROB_SCALE = 1 << PROB_BITS;
const SLOT_MASK = PROB_SCALE - 1;
const MAX_FREQ = PROB_SCALE - PROB_SCALE / 64;
const MAX_SYMBOLS = 256;
/** Symbols of a value alphabet (§4.3). */
const BUCKETS = 64;
/** The rANS state lies in RANS_L .. 256·RANS_L between symbols; the writer starts from RANS_L. */
const RANS_L = 1 << 23;
/** No stream of L bytes holds more than 353·(L + 4) symbols (no frequency above MAX_FREQ). */
const SYMBOLS_PER_BYTE = 353;
/** A decoding table entry: symbol | (frequency − 1) << 8 | offset in the symbol's slots << 19. */
const OFFSET_SHIFT = 8 + PROB_BITS;
// Alphabets (§4.2).
const A_CONN = 0, A_START = 8, A_CORNER = 9, A_SPLIT = 10, A_COUNT = 11, A_SHIFT = 12, A_POS_JUMP = 13;
const A_NORMAL = 14, A_NORMAL_BORDER = 15, A_COLOR_Y = 16, A_COLOR_C = 17, A_COLOR_A = 18, A_UV = 19;
const A_POS_INNER = 20, A_POS_BORDER = 42;
const ALPHABET_NAMES = ['conn/vertex', 'conn/left', 'conn/right', 'conn/end', 'conn/split', 'conn/boundary', 'conn/skip', 'conn/first', 'start', 'corner',
  'split', 'count', 'shift', 'pos/jump', 'normal', 'normal/border', 'color/y', 'color/c', 'color/a', 'uv'];
const alphabetName = (k) => (k >= A_POS_BORDER ? `pos/border/${k - A_POS_BORDER}` : k >= A_POS_INNER ? `pos/inner/${k - A_POS_INNER}` : ALPHABET_NAMES[k]);
// Connectivity symbols (§5.3) and edge states.
const VERTEX = 0, LEFT = 1, RIGHT = 2, END = 3, SPLIT = 4, BOUNDARY = 5, SKIP = 6;
const SYMBOL_NAMES = ['vertex', 'left', 'right', 'end', 'split', 'boundary', 'skip'];
const OPEN = 0, ZIPPED = 1, CLOSED = 2;
/** Quantized UVs lie strictly within ±2^30 steps. */
const UV_LIMIT = 2 ** 30;

/**
 * SKEL's CODE sub-chunk `c` (§3), checked against HEAD's attributes: normal and colour bits, each
 * alphabet's frequencies, and the decoding tables built from them (64 × 2048 entries, once a file).
 */
function decodeCode(b, c, attrs) {
  const p0 = c.ps, n = c.size;
  const err = (o, msg) => chunkFail(p0 + o, 'CODE', c.at, msg);
  if (n < 8) throw err(0, `${n} bytes; at least 8`);
  const nb = b[p0], cb = b[p0 + 1];
  if (attrs.normals !== (nb !== 0) || (attrs.normals && !(nb >= 2 && nb <= 16))) {
    throw err(0, `normal bits ${nb}; the file ${attrs.normals ? 'has' : 'has no'} normals (2..=16 bits)`);
  }
  if (attrs.colors !== (cb !== 0) || cb > 8) throw err(1, `colour bits ${cb}; the file ${attrs.colors ? 'has' : 'has no'} colours (1..=8 bits)`);
  if (b[p0 + 2] !== 0 || b[p0 + 3] !== 0) throw err(2, 'reserved bytes are not zero');
  const count = u32(b, p0 + 4);
  if (count !== ALPHABETS) throw err(4, `${count} alphabets; format 3 has ${ALPHABETS}`);
  const table = new Int32Array(ALPHABETS << PROB_BITS);
  const freqs = [];
  let o = 8;
  for (let k = 0; k < ALPHABETS; k++) {
    const start = o;
    if (n - o < 2) throw err(o, 'ends early');
    const m = u16(b, p0 + o);
    o += 2;
    const name = `alphabet ${k} (${alphabetName(k)})`;
    if (m > MAX_SYMBOLS) throw err(start, `${name}: ${m} symbols, at most ${MAX_SYMBOLS}`);
    if (n - o < 2 * m) throw err(o, `${name} ends early`);
    const f = [];
    let sum = 0;
    for (let s = 0; s < m; s++) {
      const x = u16(b, p0 + o + 2 * s);
      if (x > MAX_FREQ) throw err(start, `${name}: symbol ${s} has frequency ${x}, more than ${MAX_FREQ}`);
      f.push(x);
      sum += x;
    }
    if (m > 0 && sum !== PROB_SCALE) throw err(start, `${name}: frequencies add up to ${sum}, not ${PROB_SCALE}`);
    o += 2 * m;
    freqs.push(f);
    // An alphabet without symbols decodes every slot as symbol 255 of frequency 2048 (the state
    // stays), which no caller accepts.
    const base = k << PROB_BITS;
    if (m === 0) for (let slot = 0; slot < PROB_SCALE; slot++) table[base + slot] = 0xff | ((PROB_SCALE - 1) << 8) | (slot << OFFSET_SHIFT);
    for (let s = 0, slot = base; s < m; s++) {
      for (let j = 0; j < f[s]; j++) table[slot++] = s | ((f[s] - 1) << 8) | (j << OFFSET_SHIFT);
    }
  }
  if (o !== n) throw err(o, `${n - o} bytes after the last alphabet`);
  return { normalBits: nb, colorBits: cb, freqs, table };
}

/**
 * A node's payload being read (§4): the rANS state `x` (the u32 state's bits in an int32), the
 * symbol stream's next byte `pos` (it ends at `end`), and the raw bits after it, most significant
 * first, `bp` the next one's offset in bits from the payload's start. Reading past either end
 * throws at once: strata reads zeros there and refuses the node at its end, so the same nodes
 * fail, sooner. The hot loops (connectivity3, positions3, normals3) keep this state in local
 * variables and decode symbols inline, as sym() and value() here do; they store it back after.
 */
class Payload {
  constructor(b, table, start, end, fail) {
    this.b = b;
    this.T = table;
    this.start = start;
    this.end = end;
    this.fail = fail;
    if (end - start < 4) throw this.ended();
    this.x = b[start] | (b[start + 1] << 8) | (b[start + 2] << 16) | (b[start + 3] << 24);
    this.pos = start + 4;
    this.bp = 8 * end;
  }

  /** An error at byte `at` of the symbol stream (the current one by default). */
  error(msg, at = this.pos) {
    return this.fail(at, msg);
  }

  /** The symbol stream runs out. */
  ended() {
    return this.fail(this.end, `the symbol stream of ${this.end - this.start} bytes ends early`);
  }

  /** Raw bits run out. */
  overrun() {
    return this.fail(this.b.length, `raw bits run past the payload's ${this.b.length} bytes`);
  }

  /** A symbol of a value alphabet that is not a value. */
  notValue(s, al, at) {
    return this.fail(at, `symbol ${s} of alphabet ${alphabetName(al)} is not a value`);
  }

  /** The next symbol, of alphabet `al` (§4.1). */
  sym(al) {
    const e = this.T[(al << PROB_BITS) | (this.x & SLOT_MASK)];
    // f·(x >> 11) + offset < 2^32: Math.imul's low 32 bits are exact.
    let x = (Math.imul(((e >>> 8) & SLOT_MASK) + 1, this.x >>> PROB_BITS) + (e >>> OFFSET_SHIFT)) | 0;
    if (x >>> 23 === 0) {
      if (this.pos >= this.end) throw this.ended();
      x = (x << 8) | this.b[this.pos++];
      if (x >>> 23 === 0) {
        if (this.pos >= this.end) throw this.ended();
        x = (x << 8) | this.b[this.pos++];
      }
    }
    this.x = x;
    return e & 0xff;
  }

  /** A value of alphabet `al` (§4.3): up to 2^32 − 1. */
  value(al) {
    const s = this.sym(al);
    if (s < 4) return s;
    if (s >= BUCKETS) throw this.notValue(s, al, this.pos);
    return this.rest(s);
  }

  /** The value of symbol `s` (4..63) of a value alphabet, its raw bits read. */
  rest(s) {
    const k = s - 4, e = (k >> 1) + 1;
    return (2 + (k & 1)) * (1 << e) + (e > 24 ? this.raw(e - 16) * 65536 + this.raw(16) : this.raw(e));
  }

  /** A signed value of alphabet `al` (zigzag): an int32. */
  signed(al) {
    const u = this.value(al);
    return (u >>> 1) ^ ((u << 31) >> 31);
  }

  /**
   * The next `e` (1..=24) raw bits as an unsigned integer, first bit highest (§4.4): from the 32
   * bits at the byte holding the first (zeros past the end), which hold them all.
   */
  raw(e) {
    const b = this.b, bp = this.bp, n = b.length;
    if (bp + e > 8 * n) throw this.overrun();
    const k = bp >> 3;
    const w = (b[k] << 24) | ((k + 1 < n ? b[k + 1] : 0) << 16) | ((k + 2 < n ? b[k + 2] : 0) << 8) | (k + 3 < n ? b[k + 3] : 0);
    this.bp = bp + e;
    return (w << (bp & 7)) >>> (32 - e);
  }
}

// The format-3 decoder's working arrays, reused from node to node (one decode runs at a time) and
// grown as faces come, never beyond what the payload has decoded. Edges (at most 3 a face) are
// records of 8 ints in `edges`, an edge named by its offset there: start, end, far corner, the
// offsets of the edges before and after it along its loop, its state. The queue and the skipped
// edges hold offsets. Per vertex its prediction, 3 ints in `preds` (pa, pb, pc: the parallelogram
// pa + pb − pc; pc = −1: the vertex pa before, −1 for none). Per vertex after connectivity: grid
// points, border flags, normal sums, colours (YCoCg-R) and UVs in steps.
const E_V0 = 0, E_V1 = 1, E_OPP = 2, E_PREV = 3, E_NEXT = 4, E_STATE = 5, E_INTS = 8;
const W3 = {
  cap: 0,
  edges: new Int32Array(0),
  queue: new Int32Array(0),
  skipped: new Int32Array(0),
  preds: new Int32Array(0),
  idx: new Uint32Array(0),
  vcap: 0,
  points: new Int32Array(0),
  border: new Uint8Array(0),
  sums: new Float64Array(0),
  ys: new Int32Array(0),
  uvq: new Int32Array(0),
};

/** Room in W3 for `faces` faces (3 edges, vertices and corners each), contents kept. */
function growFaces(faces) {
  const n = 3 * faces + 3;
  if (n <= W3.cap) return;
  const m = Math.max(n, 2 * W3.cap, 3072);
  const more = (a, per) => {
    const c = new a.constructor(per * m);
    c.set(a);
    return c;
  };
  W3.edges = more(W3.edges, E_INTS);
  W3.queue = more(W3.queue, 1);
  W3.skipped = more(W3.skipped, 1);
  W3.preds = more(W3.preds, 3);
  W3.idx = more(W3.idx, 1);
  W3.cap = m;
}

/** Room in W3 for `n` vertices' attributes. */
function growVertices(n) {
  if (n <= W3.vcap) return;
  const m = Math.max(n, 2 * W3.vcap, 1024);
  Object.assign(W3, { vcap: m, points: new Int32Array(3 * m), border: new Uint8Array(m), sums: new Float64Array(3 * m), ys: new Int32Array(4 * m), uvq: new Int32Array(2 * m) });
}

/**
 * Connectivity (§5.3): the faces of runs between `cuts` by traversal, their corners into W3.idx,
 * and each vertex's prediction; then W3.border, whether each vertex lies on an edge not zipped.
 * The connectivity symbols are decoded inline (Payload.sym), the rare values through `r`.
 */
function connectivity3(r, cuts, nf, nv) {
  // Room for what a plausible payload holds, more as faces come.
  growFaces(Math.min(nf, 16 * (r.end - r.start) + 256));
  let limit = 3 * Math.floor((W3.cap - 3) / 3);
  let E = W3.edges, queue = W3.queue, skipped = W3.skipped, preds = W3.preds, idx = W3.idx;
  const T = r.T, b = r.b, end = r.end;
  let x = r.x, pos = r.pos;
  // ne: the next edge's offset; nvd: vertices so far; ni: corners so far.
  // ctx: the table offset of CONN + the previous symbol (7 before the first).
  let ne = 0, nvd = 0, ni = 0, nsk = 0, ctx = (A_CONN + 7) << PROB_BITS;
  for (let w = 0; w + 1 < cuts.length; w++) {
    let left = cuts[w + 1] - cuts[w];
    let qn = 0, head = 0, pending = -1;
    while (left > 0) {
      if (ni >= limit) {
        // More faces than the first guess: grow toward the node's count.
        growFaces(Math.min(nf, (2 * limit) / 3));
        limit = 3 * Math.floor((W3.cap - 3) / 3);
        ({ edges: E, queue, skipped, preds, idx } = W3);
      }
      let e, sy = -1;
      if (pending >= 0) {
        e = pending;
        pending = -1;
      } else if (head < qn) {
        e = queue[head++];
      } else {
        // Restart: a new triangle, or a skipped edge.
        r.x = x;
        r.pos = pos;
        const t = r.value(A_START);
        if (t === 0) {
          for (let k = 0; k < 3; k++) {
            const c = r.value(A_CORNER);
            if (c === 0) {
              if (nvd >= nv) throw r.error(`more than ${nv} vertices`);
              preds[3 * nvd] = nvd - 1;
              preds[3 * nvd + 2] = -1;
              idx[ni + k] = nvd++;
            } else {
              if (c > nvd) throw r.error(`a corner ${c - 1} vertices back of ${nvd}`);
              idx[ni + k] = nvd - c;
            }
          }
          x = r.x;
          pos = r.pos;
          const c0 = idx[ni], c1 = idx[ni + 1], c2 = idx[ni + 2];
          const e1 = ne + E_INTS, e2 = ne + 2 * E_INTS;
          E[ne] = c0, E[ne + 1] = c1, E[ne + 2] = c2, E[ne + 3] = e2, E[ne + 4] = e1, E[ne + 5] = OPEN;
          E[e1] = c1, E[e1 + 1] = c2, E[e1 + 2] = c0, E[e1 + 3] = ne, E[e1 + 4] = e2, E[e1 + 5] = OPEN;
          E[e2] = c2, E[e2 + 1] = c0, E[e2 + 2] = c1, E[e2 + 3] = e1, E[e2 + 4] = ne, E[e2 + 5] = OPEN;
          queue[qn++] = ne, queue[qn++] = e1, queue[qn++] = e2;
          ne += 3 * E_INTS;
          ni += 3;
          left--;
          continue;
        }
        if (t > nsk) throw r.error(`start from skipped edge ${t - 1} of ${nsk}`);
        e = skipped[nsk - t];
        if (E[e + E_STATE] !== OPEN) throw r.error('start from an edge that is closed');
        // The gate must make a triangle.
        sy = r.sym(ctx >> PROB_BITS);
        x = r.x;
        pos = r.pos;
        if (sy > SPLIT) throw r.error(`a run starts with ${SYMBOL_NAMES[sy] ?? 'an unknown symbol'}`);
      }
      if (sy < 0) {
        if (E[e + E_STATE] !== OPEN) continue;
        // A symbol of CONN + ctx (Payload.sym).
        const t = T[ctx | (x & SLOT_MASK)];
        x = (Math.imul(((t >>> 8) & SLOT_MASK) + 1, x >>> PROB_BITS) + (t >>> OFFSET_SHIFT)) | 0;
        if (x >>> 23 === 0) {
          if (pos >= end) throw r.ended();
          x = (x << 8) | b[pos++];
          if (x >>> 23 === 0) {
            if (pos >= end) throw r.ended();
            x = (x << 8) | b[pos++];
          }
        }
        sy = t & 0xff;
        if (sy > SPLIT) {
          if (sy === BOUNDARY) E[e + E_STATE] = CLOSED;
          else if (sy === SKIP) skipped[nsk++] = e;
          else throw r.error(`connectivity symbol ${sy}`, pos);
          ctx = (A_CONN + sy) << PROB_BITS;
          continue;
        }
      }
      ctx = (A_CONN + sy) << PROB_BITS;
      // Triangle (b, a, x) across gate e = (a → b), then the front around it (Front::across).
      const va = E[e + E_V0], vb = E[e + E_V1], p = E[e + E_PREV], n = E[e + E_NEXT];
      let vx;
      if (sy === VERTEX) {
        if (nvd >= nv) throw r.error(`more than ${nv} vertices`, pos);
        preds[3 * nvd] = va;
        preds[3 * nvd + 1] = vb;
        preds[3 * nvd + 2] = E[e + E_OPP];
        vx = nvd++;
      } else if (sy === LEFT) {
        if (E[p + E_STATE] !== OPEN || p === e) throw r.error('LEFT of a closed edge', pos);
        vx = E[p + E_V0];
      } else if (sy === RIGHT) {
        if (E[n + E_STATE] !== OPEN || n === e) throw r.error('RIGHT of a closed edge', pos);
        vx = E[n + E_V1];
      } else if (sy === END) {
        if (E[p + E_STATE] !== OPEN || E[n + E_STATE] !== OPEN || p === n || p === e || E[p + E_V0] !== E[n + E_V1]) {
          throw r.error('END where the loop does not close', pos);
        }
        vx = E[p + E_V0];
      } else {
        r.x = x;
        r.pos = pos;
        const back = r.value(A_SPLIT);
        x = r.x;
        pos = r.pos;
        if (back >= nvd) throw r.error(`a split ${back} vertices back of ${nvd}`, pos);
        vx = nvd - 1 - back;
      }
      if (vx === va || vx === vb) throw r.error(`a triangle across edge (${va}, ${vb}) repeats a corner`, pos);
      idx[ni] = vb, idx[ni + 1] = va, idx[ni + 2] = vx;
      ni += 3;
      left--;
      E[e + E_STATE] = ZIPPED;
      if (sy === LEFT) {
        E[p + E_STATE] = ZIPPED;
        const pp = E[p + E_PREV];
        E[ne] = vx, E[ne + 1] = vb, E[ne + 2] = va, E[ne + 3] = pp, E[ne + 4] = n, E[ne + 5] = OPEN;
        E[pp + E_NEXT] = ne;
        E[n + E_PREV] = ne;
        pending = ne;
        ne += E_INTS;
      } else if (sy === RIGHT) {
        E[n + E_STATE] = ZIPPED;
        const nn = E[n + E_NEXT];
        E[ne] = va, E[ne + 1] = vx, E[ne + 2] = vb, E[ne + 3] = p, E[ne + 4] = nn, E[ne + 5] = OPEN;
        E[p + E_NEXT] = ne;
        E[nn + E_PREV] = ne;
        pending = ne;
        ne += E_INTS;
      } else if (sy === END) {
        E[p + E_STATE] = ZIPPED;
        E[n + E_STATE] = ZIPPED;
        const pp = E[p + E_PREV], nn = E[n + E_NEXT];
        E[pp + E_NEXT] = nn;
        E[nn + E_PREV] = pp;
      } else {
        const e2 = ne + E_INTS;
        E[ne] = va, E[ne + 1] = vx, E[ne + 2] = vb, E[ne + 3] = p, E[ne + 4] = e2, E[ne + 5] = OPEN;
        E[e2] = vx, E[e2 + 1] = vb, E[e2 + 2] = va, E[e2 + 3] = ne, E[e2 + 4] = n, E[e2 + 5] = OPEN;
        E[p + E_NEXT] = ne;
        E[n + E_PREV] = e2;
        pending = ne;
        queue[qn++] = e2;
        ne += 2 * E_INTS;
      }
    }
  }
  r.x = x;
  r.pos = pos;
  if (nvd !== nv) throw r.error(`${nvd} vertices, the node record says ${nv}`);
  growVertices(nv);
  const border = W3.border;
  border.fill(0, 0, nv);
  for (let e = 0; e < ne; e += E_INTS) {
    if (E[e + E_STATE] !== ZIPPED) {
      border[E[e + E_V0]] = 1;
      border[E[e + E_V1]] = 1;
    }
  }
}

/**
 * Positions (§5.4) into W3.points, and as f32 into `out` (and `local`, relative to `lo`), each
 * the f64 origin + g·step rounded once. Values are decoded inline (Payload.value: raw values of up
 * to 24 bits here, longer ones through `r`), the three coordinates written out one by one.
 */
function positions3(r, nv, shift, bits, mid, grid, out, local, lo) {
  const { preds, points: q, border } = W3;
  const T = r.T, b = r.b, end = r.end, blen = b.length;
  let x = r.x, pos = r.pos, bp = r.bp;
  const top = (1 << bits) - 1, topLattice = top >> shift;
  const half = (1 << shift) >> 1;
  const step = grid.step;
  const [o0, o1, o2] = grid.origin;
  const [l0, l1, l2] = local ? [o0 - lo[0], o1 - lo[1], o2 - lo[2]] : [0, 0, 0];
  for (let v = 0; v < nv; v++) {
    const v3 = 3 * v, c = preds[v3 + 2];
    const bd = border[v];
    // On the lattice: vertices inside a coarse node.
    const lat = shift > 0 && bd === 0;
    let al, p0, p1, p2;
    if (c >= 0) {
      const a3 = 3 * preds[v3], b3 = 3 * preds[v3 + 1], c3 = 3 * c;
      const ax = q[a3], ay = q[a3 + 1], az = q[a3 + 2];
      const bx = q[b3], by = q[b3 + 1], bz = q[b3 + 2];
      const cx = q[c3], cy = q[c3 + 1], cz = q[c3 + 2];
      p0 = ax + bx - cx;
      p1 = ay + by - cy;
      p2 = az + bz - cz;
      p0 = p0 < 0 ? 0 : p0 > top ? top : p0;
      p1 = p1 < 0 ? 0 : p1 > top ? top : p1;
      p2 = p2 < 0 ? 0 : p2 > top ? top : p2;
      // The alphabet: the bit length of the gate triangle's largest extent (position_alphabet).
      let ext = Math.max(ax, bx, cx) - Math.min(ax, bx, cx);
      const ey = Math.max(ay, by, cy) - Math.min(ay, by, cy), ez = Math.max(az, bz, cz) - Math.min(az, bz, cz);
      if (ey > ext) ext = ey;
      if (ez > ext) ext = ez;
      if (lat) ext >>= shift;
      const k = 32 - Math.clz32(ext);
      al = (bd ? A_POS_BORDER : A_POS_INNER) + (k > 21 ? 21 : k);
    } else {
      const u3 = 3 * preds[v3];
      if (u3 < 0) {
        p0 = mid[0];
        p1 = mid[1];
        p2 = mid[2];
      } else {
        p0 = q[u3];
        p1 = q[u3 + 1];
        p2 = q[u3 + 2];
      }
      al = A_POS_JUMP;
    }
    const tb = al << PROB_BITS;
    {
      // A signed value of alphabet al (Payload.sym, value, signed), then coordinate 0.
      const t = T[tb | (x & SLOT_MASK)];
      x = (Math.imul(((t >>> 8) & SLOT_MASK) + 1, x >>> PROB_BITS) + (t >>> OFFSET_SHIFT)) | 0;
      if (x >>> 23 === 0) {
        if (pos >= end) throw r.ended();
        x = (x << 8) | b[pos++];
        if (x >>> 23 === 0) {
          if (pos >= end) throw r.ended();
          x = (x << 8) | b[pos++];
        }
      }
      let u = t & 0xff;
      if (u >= 4) {
        if (u < 52) {
          // Raw bits as Payload.raw reads them: the 32 at bp's byte, here without a check while
          // the payload holds them.
          const j = u - 4, n = (j >> 1) + 1, k = bp >> 3;
          let raw;
          if (k + 3 < blen) {
            raw = (((b[k] << 24) | (b[k + 1] << 16) | (b[k + 2] << 8) | b[k + 3]) << (bp & 7)) >>> (32 - n);
            bp += n;
          } else {
            r.bp = bp;
            raw = r.raw(n);
            bp = r.bp;
          }
          u = ((2 | (j & 1)) << n) | raw;
        } else if (u < BUCKETS) {
          r.bp = bp;
          u = r.rest(u);
          bp = r.bp;
        } else {
          throw r.notValue(u, al, pos);
        }
      }
      // Zigzag, int32 throughout (-(u & 1) would make -0).
      const res = (u >>> 1) ^ ((u << 31) >> 31);
      let g;
      if (lat) {
        // Lattice steps, (P + 2^sh/2) >> sh, checked before the shift back.
        const l = ((p0 + half) >> shift) + res;
        if (!(l >= 0 && l <= topLattice)) throw r.error(`vertex ${v} lies off the ${bits}-bit grid`, pos);
        g = l << shift;
      } else {
        g = p0 + res;
        if (!(g >= 0 && g <= top)) throw r.error(`vertex ${v} lies off the ${bits}-bit grid`, pos);
      }
      q[v3 + 0] = g;
      out[v3 + 0] = o0 + g * step;
      if (local) local[v3 + 0] = l0 + g * step;
    }
    {
      // A signed value of alphabet al (Payload.sym, value, signed), then coordinate 1.
      const t = T[tb | (x & SLOT_MASK)];
      x = (Math.imul(((t >>> 8) & SLOT_MASK) + 1, x >>> PROB_BITS) + (t >>> OFFSET_SHIFT)) | 0;
      if (x >>> 23 === 0) {
        if (pos >= end) throw r.ended();
        x = (x << 8) | b[pos++];
        if (x >>> 23 === 0) {
          if (pos >= end) throw r.ended();
          x = (x << 8) | b[pos++];
        }
      }
      let u = t & 0xff;
      if (u >= 4) {
        if (u < 52) {
          // Raw bits as Payload.raw reads them: the 32 at bp's byte, here without a check while
          // the payload holds them.
          const j = u - 4, n = (j >> 1) + 1, k = bp >> 3;
          let raw;
          if (k + 3 < blen) {
            raw = (((b[k] << 24) | (b[k + 1] << 16) | (b[k + 2] << 8) | b[k + 3]) << (bp & 7)) >>> (32 - n);
            bp += n;
          } else {
            r.bp = bp;
            raw = r.raw(n);
            bp = r.bp;
          }
          u = ((2 | (j & 1)) << n) | raw;
        } else if (u < BUCKETS) {
          r.bp = bp;
          u = r.rest(u);
          bp = r.bp;
        } else {
          throw r.notValue(u, al, pos);
        }
      }
      // Zigzag, int32 throughout (-(u & 1) would make -0).
      const res = (u >>> 1) ^ ((u << 31) >> 31);
      let g;
      if (lat) {
        // Lattice steps, (P + 2^sh/2) >> sh, checked before the shift back.
        const l = ((p1 + half) >> shift) + res;
        if (!(l >= 0 && l <= topLattice)) throw r.error(`vertex ${v} lies off the ${bits}-bit grid`, pos);
        g = l << shift;
      } else {
        g = p1 + res;
        if (!(g >= 0 && g <= top)) throw r.error(`vertex ${v} lies off the ${bits}-bit grid`, pos);
      }
      q[v3 + 1] = g;
      out[v3 + 1] = o1 + g * step;
      if (local) local[v3 + 1] = l1 + g * step;
    }
    {
      // A signed value of alphabet al (Payload.sym, value, signed), then coordinate 2.
      const t = T[tb | (x & SLOT_MASK)];
      x = (Math.imul(((t >>> 8) & SLOT_MASK) + 1, x >>> PROB_BITS) + (t >>> OFFSET_SHIFT)) | 0;
      if (x >>> 23 === 0) {
        if (pos >= end) throw r.ended();
        x = (x << 8) | b[pos++];
        if (x >>> 23 === 0) {
          if (pos >= end) throw r.ended();
          x = (x << 8) | b[pos++];
        }
      }
      let u = t & 0xff;
      if (u >= 4) {
        if (u < 52) {
          // Raw bits as Payload.raw reads them: the 32 at bp's byte, here without a check while
          // the payload holds them.
          const j = u - 4, n = (j >> 1) + 1, k = bp >> 3;
          let raw;
          if (k + 3 < blen) {
            raw = (((b[k] << 24) | (b[k + 1] << 16) | (b[k + 2] << 8) | b[k + 3]) << (bp & 7)) >>> (32 - n);
            bp += n;
          } else {
            r.bp = bp;
            raw = r.raw(n);
            bp = r.bp;
          }
          u = ((2 | (j & 1)) << n) | raw;
        } else if (u < BUCKETS) {
          r.bp = bp;
          u = r.rest(u);
          bp = r.bp;
        } else {
          throw r.notValue(u, al, pos);
        }
      }
      // Zigzag, int32 throughout (-(u & 1) would make -0).
      const res = (u >>> 1) ^ ((u << 31) >> 31);
      let g;
      if (lat) {
        // Lattice steps, (P + 2^sh/2) >> sh, checked before the shift back.
        const l = ((p2 + half) >> shift) + res;
        if (!(l >= 0 && l <= topLattice)) throw r.error(`vertex ${v} lies off the ${bits}-bit grid`, pos);
        g = l << shift;
      } else {
        g = p2 + res;
        if (!(g >= 0 && g <= top)) throw r.error(`vertex ${v} lies off the ${bits}-bit grid`, pos);
      }
      q[v3 + 2] = g;
      out[v3 + 2] = o2 + g * step;
      if (local) local[v3 + 2] = l2 + g * step;
    }
  }
  Object.assign(r, { x, pos, bp });
}

/** Octahedral decodes at scale S, memoized by code (NaN: not yet), for S ≤ 255: at most 3 MB. */
function octaTable(code, S) {
  if (S > 255) return null;
  if (!code.octa) code.octa = new Float32Array(3 * (2 * S + 1) * (2 * S + 1)).fill(NaN);
  return code.octa;
}

/**
 * Normals (§5.5): each vertex's face normals summed in f64 in face order, its octahedral code at
 * scale S predicted from the sum (predict_octa), plus two residuals decoded inline; decoded into
 * `out` as octa::decode_at does.
 */
function normals3(r, nv, nf, idx, code, out) {
  const { points: p, sums, border } = W3;
  const nb = code.normalBits;
  const S = 2 ** (nb - 1) - 1, side = 2 * S + 1;
  const memo = octaTable(code, S);
  sums.fill(0, 0, 3 * nv);
  for (let f = 0, n = 3 * nf; f < n; f += 3) {
    const i0 = 3 * idx[f], i1 = 3 * idx[f + 1], i2 = 3 * idx[f + 2];
    const x0 = p[i0], y0 = p[i0 + 1], z0 = p[i0 + 2];
    const ux = p[i1] - x0, uy = p[i1 + 1] - y0, uz = p[i1 + 2] - z0;
    const wx = p[i2] - x0, wy = p[i2 + 1] - y0, wz = p[i2 + 2] - z0;
    // Products below 2^42: exact in f64, as their differences.
    const nx = uy * wz - uz * wy, ny = uz * wx - ux * wz, nz = ux * wy - uy * wx;
    sums[i0] += nx;
    sums[i0 + 1] += ny;
    sums[i0 + 2] += nz;
    sums[i1] += nx;
    sums[i1 + 1] += ny;
    sums[i1 + 2] += nz;
    sums[i2] += nx;
    sums[i2 + 1] += ny;
    sums[i2 + 2] += nz;
  }
  const T = r.T, b = r.b, end = r.end, blen = b.length;
  let x = r.x, pos = r.pos, bp = r.bp;
  for (let v = 0; v < nv; v++) {
    const sx = sums[3 * v], sy = sums[3 * v + 1], sz = sums[3 * v + 2];
    const l1 = Math.abs(sx) + Math.abs(sy) + Math.abs(sz);
    let q0 = 0, q1 = 0;
    if (l1 !== 0) {
      let px = sx / l1, py = sy / l1;
      if (sz < 0) {
        const tx = (1 - Math.abs(py)) * (px >= 0 ? 1 : -1);
        py = (1 - Math.abs(px)) * (py >= 0 ? 1 : -1);
        px = tx;
      }
      q0 = Math.floor(px * S + 0.5);
      q1 = Math.floor(py * S + 0.5);
    }
    const al = border[v] ? A_NORMAL_BORDER : A_NORMAL, tb = al << PROB_BITS;
    {
      // A signed value of alphabet al, as in positions3, added to coordinate 0.
      const t = T[tb | (x & SLOT_MASK)];
      x = (Math.imul(((t >>> 8) & SLOT_MASK) + 1, x >>> PROB_BITS) + (t >>> OFFSET_SHIFT)) | 0;
      if (x >>> 23 === 0) {
        if (pos >= end) throw r.ended();
        x = (x << 8) | b[pos++];
        if (x >>> 23 === 0) {
          if (pos >= end) throw r.ended();
          x = (x << 8) | b[pos++];
        }
      }
      let u = t & 0xff;
      if (u >= 4) {
        if (u < 52) {
          // Raw bits as Payload.raw reads them: the 32 at bp's byte, here without a check while
          // the payload holds them.
          const j = u - 4, n = (j >> 1) + 1, k = bp >> 3;
          let raw;
          if (k + 3 < blen) {
            raw = (((b[k] << 24) | (b[k + 1] << 16) | (b[k + 2] << 8) | b[k + 3]) << (bp & 7)) >>> (32 - n);
            bp += n;
          } else {
            r.bp = bp;
            raw = r.raw(n);
            bp = r.bp;
          }
          u = ((2 | (j & 1)) << n) | raw;
        } else if (u < BUCKETS) {
          r.bp = bp;
          u = r.rest(u);
          bp = r.bp;
        } else {
          throw r.notValue(u, al, pos);
        }
      }
      q0 += (u >>> 1) ^ ((u << 31) >> 31);
      if (q0 > S || q0 < -S) throw r.error(`normal ${v} exceeds the ${nb}-bit scale`, pos);
    }
    {
      // A signed value of alphabet al, as in positions3, added to coordinate 1.
      const t = T[tb | (x & SLOT_MASK)];
      x = (Math.imul(((t >>> 8) & SLOT_MASK) + 1, x >>> PROB_BITS) + (t >>> OFFSET_SHIFT)) | 0;
      if (x >>> 23 === 0) {
        if (pos >= end) throw r.ended();
        x = (x << 8) | b[pos++];
        if (x >>> 23 === 0) {
          if (pos >= end) throw r.ended();
          x = (x << 8) | b[pos++];
        }
      }
      let u = t & 0xff;
      if (u >= 4) {
        if (u < 52) {
          // Raw bits as Payload.raw reads them: the 32 at bp's byte, here without a check while
          // the payload holds them.
          const j = u - 4, n = (j >> 1) + 1, k = bp >> 3;
          let raw;
          if (k + 3 < blen) {
            raw = (((b[k] << 24) | (b[k + 1] << 16) | (b[k + 2] << 8) | b[k + 3]) << (bp & 7)) >>> (32 - n);
            bp += n;
          } else {
            r.bp = bp;
            raw = r.raw(n);
            bp = r.bp;
          }
          u = ((2 | (j & 1)) << n) | raw;
        } else if (u < BUCKETS) {
          r.bp = bp;
          u = r.rest(u);
          bp = r.bp;
        } else {
          throw r.notValue(u, al, pos);
        }
      }
      q1 += (u >>> 1) ^ ((u << 31) >> 31);
      if (q1 > S || q1 < -S) throw r.error(`normal ${v} exceeds the ${nb}-bit scale`, pos);
    }
    const v3 = 3 * v;
    if (memo) {
      const m = 3 * ((q1 + S) * side + q0 + S);
      if (memo[m] !== memo[m]) octaDecode(q0, q1, memo, m, S);
      out[v3] = memo[m];
      out[v3 + 1] = memo[m + 1];
      out[v3 + 2] = memo[m + 2];
    } else {
      octaDecode(q0, q1, out, v3, S);
    }
  }
  Object.assign(r, { x, pos, bp });
}

/** Colours (§5.6): YCoCg-R at `cb` bits, predicted as positions are, as RGBA bytes into `out`. */
function colors3(r, nv, cb, out) {
  const { preds, ys } = W3;
  const m = 2 ** cb - 1;
  const value = new Uint8Array(m + 1);
  for (let q = 0; q <= m; q++) value[q] = Math.floor((q * 255 + (m >> 1)) / m);
  for (let v = 0; v < nv; v++) {
    const c = preds[3 * v + 2], pa = preds[3 * v];
    let y0 = 0, y1 = 0, y2 = 0, y3 = 0;
    if (c >= 0) {
      const a4 = 4 * pa, b4 = 4 * preds[3 * v + 1], c4 = 4 * c;
      y0 = Math.min(Math.max(ys[a4] + ys[b4] - ys[c4], -m), m);
      y1 = Math.min(Math.max(ys[a4 + 1] + ys[b4 + 1] - ys[c4 + 1], -m), m);
      y2 = Math.min(Math.max(ys[a4 + 2] + ys[b4 + 2] - ys[c4 + 2], -m), m);
      y3 = Math.min(Math.max(ys[a4 + 3] + ys[b4 + 3] - ys[c4 + 3], -m), m);
    } else if (pa >= 0) {
      const u4 = 4 * pa;
      y0 = ys[u4];
      y1 = ys[u4 + 1];
      y2 = ys[u4 + 2];
      y3 = ys[u4 + 3];
    }
    y0 += r.signed(A_COLOR_Y);
    y1 += r.signed(A_COLOR_C);
    y2 += r.signed(A_COLOR_C);
    y3 += r.signed(A_COLOR_A);
    // Co and Cg first, so that the shifts below act on small integers.
    if (!(Math.abs(y1) <= m && Math.abs(y2) <= m)) throw r.error(`colour of vertex ${v} beyond ${cb} bits`);
    const t = y0 - (y2 >> 1), g = y2 + t, bl = t - (y1 >> 1), rd = bl + y1;
    if (!(rd >= 0 && rd <= m && g >= 0 && g <= m && bl >= 0 && bl <= m && y3 >= 0 && y3 <= m)) throw r.error(`colour of vertex ${v} beyond ${cb} bits`);
    const v4 = 4 * v;
    ys[v4] = y0;
    ys[v4 + 1] = y1;
    ys[v4 + 2] = y2;
    ys[v4 + 3] = y3;
    out[v4] = value[rd];
    out[v4 + 1] = value[g];
    out[v4 + 2] = value[bl];
    out[v4 + 3] = value[y3];
  }
}

/** UVs (§5.7): steps of 2^−uvBits predicted as colours are, as f32 into `out`. */
function uvs3(r, nv, uvBits, out) {
  const { preds, uvq } = W3;
  const lim = UV_LIMIT - 1, unit = 2 ** uvBits;
  for (let v = 0; v < nv; v++) {
    const c = preds[3 * v + 2], pa = preds[3 * v];
    let u0 = 0, u1 = 0;
    if (c >= 0) {
      const a2 = 2 * pa, b2 = 2 * preds[3 * v + 1], c2 = 2 * c;
      u0 = Math.min(Math.max(uvq[a2] + uvq[b2] - uvq[c2], -lim), lim);
      u1 = Math.min(Math.max(uvq[a2 + 1] + uvq[b2 + 1] - uvq[c2 + 1], -lim), lim);
    } else if (pa >= 0) {
      u0 = uvq[2 * pa];
      u1 = uvq[2 * pa + 1];
    }
    u0 += r.signed(A_UV);
    u1 += r.signed(A_UV);
    if (!(Math.abs(u0) < UV_LIMIT && Math.abs(u1) < UV_LIMIT)) throw r.error(`UV ${v} exceeds ±2^30 steps`);
    uvq[2 * v] = u0;
    uvq[2 * v + 1] = u1;
    out[2 * v] = u0 / unit;
    out[2 * v + 1] = u1 / unit;
  }
}

/**
 * Check and decode node i's format-3 payload (strata-v3.md §5): its size and CRC against the node
 * table, then header, connectivity, positions, normals, colours and UVs, and the ends of the
 * symbol stream and the raw bits. Clusters come back as face ranges only.
 */
function decodeNode3(s, i, b, opts) {
  const at = s.offset[i], size = s.size[i], geos = s.skeletonEnd;
  if (b.length !== size) throw chunkFail(at, 'GEOS', geos, `node ${i}'s geometry is ${b.length} bytes, its record says ${size}`, i);
  const actual = crc32(b, 0, size);
  if (actual !== s.crc[i]) throw chunkFail(at, 'GEOS', geos, `node ${i}'s geometry: CRC ${hex(actual)}, node table ${hex(s.crc[i])}`, i);
  const fail = (o, msg) => chunkFail(at + o, 'GEOS', geos, `node ${i}'s geometry: ${msg}`, i);
  const h = s.header, attrs = h.attributes, code = s.code;
  const nf = s.faces[i], nv = s.vertices[i], level = s.level[i];
  // The symbol stream's length, LEB128 (§5.1).
  let len = 0, o = 0;
  for (;;) {
    if (o >= b.length) throw fail(o, "the payload ends in its symbol stream's length");
    if (o === 9) throw fail(o, "the symbol stream's length runs past 10 bytes");
    const x = b[o];
    len += (x & 0x7f) * 2 ** (7 * o);
    o++;
    if (!(x & 0x80)) break;
  }
  const end = o + len;
  if (!(end <= b.length)) throw fail(0, `a symbol stream of ${len} bytes runs past the payload's ${b.length}`);
  // Each face takes a symbol, and a stream of L bytes holds at most 353·(L + 4): bounded work.
  if ((nf > 0 && nv === 0) || nv > 3 * nf || nf > SYMBOLS_PER_BYTE * (len + 4)) throw fail(0, `${nf} faces and ${nv} vertices cannot fit in ${b.length} bytes`);
  const r = new Payload(b, code.table, o, end, fail);
  const bits = h.grid.bits;

  // Header (§5.2): lattice shift, UV bits, material ranges, clusters; the runs between them.
  let shift = 0, uvBits = 0;
  if (level > 0) {
    shift = r.sym(A_SHIFT);
    if (shift >= bits) throw r.error(`lattice shift ${shift} on a ${bits}-bit grid`);
  }
  if (attrs.uvs) {
    uvBits = r.value(A_COUNT);
    if (!(uvBits >= 1 && uvBits <= 24)) throw r.error(`UV bits ${uvBits} (1..=24)`);
  }
  const ranges = r.value(A_COUNT) + 1;
  if (ranges > Math.max(nf, 1)) throw r.error(`${ranges} material ranges for ${nf} faces`);
  const materialRanges = [];
  const cuts = [];
  for (let k = 0, first = 0; k < ranges; k++) {
    const material = r.value(A_COUNT);
    if (material >= h.materials) throw r.error(`material ${material} of ${h.materials}`);
    const faces = k + 1 === ranges ? nf - first : r.value(A_COUNT) + 1;
    if (first + faces > nf || faces === 0) throw r.error(`material ranges cover more than ${nf} faces`);
    materialRanges.push([material, 3 * first, 3 * faces]);
    cuts.push(first);
    first += faces;
  }
  const clusters = [];
  if (level === 0) {
    const count = r.value(A_COUNT) + 1;
    if (count > Math.max(nf, 1)) throw r.error(`${count} clusters for ${nf} faces`);
    for (let k = 0, covered = 0; k < count; k++) {
      const faces = k + 1 === count ? nf - covered : r.value(A_COUNT) + 1;
      if (covered + faces > nf || faces === 0) throw r.error(`clusters cover more than ${nf} faces`);
      clusters.push({ firstFace: covered, faceCount: faces });
      cuts.push(covered);
      covered += faces;
    }
  }
  cuts.push(nf);
  cuts.sort((a, b) => a - b);
  const runs = [cuts[0]];
  for (let k = 1; k < cuts.length; k++) if (cuts[k] !== cuts[k - 1]) runs.push(cuts[k]);

  connectivity3(r, runs, nf, nv);
  // The arrays in two buffers, one allocation each: what a viewer keeps after upload (indices and
  // the positions it draws), and the rest.
  const lo = opts.localOrigin;
  const kept = new ArrayBuffer(12 * nf + 12 * nv);
  const indices = new Uint32Array(kept, 0, 3 * nf);
  indices.set(W3.idx.subarray(0, 3 * nf));
  const drawn = new Float32Array(kept, 12 * nf, 3 * nv);
  const restBytes = (lo ? 12 : 0) + (attrs.normals ? 12 : 0) + (attrs.uvs ? 8 : 0) + (attrs.colors ? 4 : 0);
  const rest = new ArrayBuffer(restBytes * nv);
  let filled = 0;
  const part = (T, per) => {
    const a = new T(rest, filled, per * nv);
    filled += per * nv * T.BYTES_PER_ELEMENT;
    return a;
  };
  const positions = lo ? part(Float32Array, 3) : drawn;
  const local = lo ? drawn : null;
  const normals = attrs.normals ? part(Float32Array, 3) : null;
  const uvs = attrs.uvs ? part(Float32Array, 2) : null;
  const colors = attrs.colors ? part(Uint8Array, 4) : null;
  const mid = [s.boxMid[3 * i], s.boxMid[3 * i + 1], s.boxMid[3 * i + 2]];
  positions3(r, nv, shift, bits, mid, h.grid, positions, local, lo);
  if (normals) normals3(r, nv, nf, indices, code, normals);
  if (colors) colors3(r, nv, code.colorBits, colors);
  if (uvs) uvs3(r, nv, uvBits, uvs);
  // The ends (§4.1, §4.4): every byte of the stream read, the state back at RANS_L, the raw bits
  // ending in the payload's last byte.
  if (r.pos !== end) throw fail(end, `${end - r.pos} bytes after the symbol stream's end`);
  if (r.x !== RANS_L) throw fail(end, `the symbol stream ends in state 0x${(r.x >>> 0).toString(16)}, not 0x${RANS_L.toString(16)}`);
  const used = Math.ceil((r.bp - 8 * end) / 8);
  if (used !== b.length - end) throw fail(b.length, `raw bits end at byte ${end + used} of ${b.length}`);
  const geometry = { positions, normals, uvs, colors, indices, materialRanges, clusters };
  if (local) geometry.local = local;
  return geometry;
}
