// The web viewer's reader of the strata chunk file, format 2.x (format-spec/strata-v2.md).
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
//   decodeSkeleton(bytes, fileLength) the header, levels, node table, neighbours and materials
//                                     (with { topFirst: true } the top two levels' records only,
//                                     completeSkeleton(skeleton) the rest, isComplete(skeleton));
//   decodeNode(skeleton, i, bytes)    one node's GEOM chunk, checked and decoded;
//   decodeImageLevel(skeleton, e, b)  one image level's TEXL chunk (2.2), checked: the PNG or JPEG
//                                     file inside, for the browser to decode.
//
// Hostile input never hangs the reader nor makes it throw anything but a FormatError: every read is
// bounds-checked first, every size taken from the file is checked against counts and lengths before
// anything is allocated with it, and u64 fields beyond 2^53 are refused.

export const MAJOR = 2, MINOR = 3;

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
 * (src/format/octa.rs and glam's Vec3::normalize) one by one.
 */
export function octaDecode(qx, qy, out, o) {
  let x = fr(qx / 32767);
  if (x < -1) x = -1;
  else if (x > 1) x = 1;
  let y = fr(qy / 32767);
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
  if (major > MAJOR) throw fail(8, `format version ${major}.${minor} is newer than this reader's ${MAJOR}.${MINOR}: a newer strata viewer is needed`);
  if (major < MAJOR) throw fail(8, `format version ${major}.${minor} is not supported (this reader reads ${MAJOR}.x)`);
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
 * short to tell (the prefix length needed to learn more), else `{ skeletonEnd, topEnd }`, topEnd
 * being undefined unless SKEL's LEVL sub-chunk lies in the prefix.
 */
export function openingRange(prefix, fileLength) {
  const b = prefix;
  const n = b.length;
  if (fileLength !== undefined && fileLength < PROLOGUE) throw fail(0, `a file of ${fileLength} bytes is too short for a strata file`);
  if (n < PROLOGUE) return { need: PROLOGUE };
  checkPrologue(b, fileLength);
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
    if (id === 'HEAD' || id === 'GEOM') throw chunkFail(pos, id, pos, 'expected the SKEL chunk before any other known chunk');
    pos = chunkEnd(pos, id, size, fileLength);
  }
  const skelSize = u64(b, pos + 8);
  const skeletonEnd = chunkEnd(pos, 'SKEL', skelSize, fileLength);
  let topEnd;
  // A hint: the top level's bytes from LEVL, if its record lies in the prefix; decodeSkeleton checks it.
  const payloadEnd = Math.min(pos + FRAME + skelSize, n);
  let s = pos + FRAME;
  while (levels !== undefined && s + FRAME <= payloadEnd) {
    const size = u64(b, s + 8);
    if (size === Infinity) break;
    if (isId(b, s, 'LEVL')) {
      const rec = s + FRAME + (levels - 1) * LEVEL_BYTES;
      if (levels >= 1 && size === levels * LEVEL_BYTES && rec + LEVEL_BYTES <= payloadEnd) {
        const bytes = u64(b, rec + 24);
        const end = skeletonEnd + bytes;
        if (bytes !== Infinity && (fileLength === undefined || end <= fileLength)) topEnd = end;
      }
      break;
    }
    const e = s + FRAME + size + TRAILER;
    s = e + padding(e);
  }
  return { skeletonEnd, topEnd };
}

// ---------------------------------------------------------------------------------------------
// The skeleton (§5, §7, §10 "To open").

const onGrid = (g, last) => g[0] <= last && g[1] <= last && g[2] <= last;

/** Whether every node record of `sk` is decoded (a skeleton without `decoded` counts as whole). */
export function isComplete(sk) {
  return !(sk.decoded < sk.nodeCount);
}

/** Check and decode the node records `decodeSkeleton(…, { topFirst: true })` left; throws a FormatError as it would have. */
export function completeSkeleton(sk) {
  if (isComplete(sk)) return;
  if (sk._failed) throw sk._failed;
  if (typeof sk._rest !== 'function') throw new Error('completeSkeleton: not a skeleton decodeSkeleton returned (a copy?)');
  try {
    sk._rest();
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

function decodeHead(b, dv, pos, size, minor) {
  const p0 = pos + FRAME;
  const end = p0 + size;
  const newer = minor > MINOR;
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
function decodeGeoref(b, dv, pos, size, minor) {
  const p0 = pos + FRAME, end = p0 + size;
  const err = (at, msg) => chunkFail(at, 'GEOR', pos, msg);
  const newer = minor > MINOR;
  if (size < GEOR_FIXED) throw err(p0, `${size} bytes, fewer than the ${GEOR_FIXED} of its fixed fields`);
  const code = u32(b, p0);
  if (code >= GEO_FRAMES.length) throw err(p0, newer ? `frame ${code} is newer than this reader (format ${MAJOR}.${MINOR})` : `unknown frame ${code}`);
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
 * `fileLength` bytes: the prologue, HEAD, skipped chunks and SKEL, every check of spec §10 "To open".
 * With `opts.topFirst`, only the top two levels' node records are checked and decoded (nodes
 * [0, sk.decoded)); `completeSkeleton` does the rest before any other node is used, so a first
 * frame of the top level waits for none of it (selection.md §6).
 */
export function decodeSkeleton(bytes, fileLength, opts = {}) {
  const b = bytes;
  if (!(Number.isSafeInteger(fileLength) && fileLength >= 0)) throw fail(undefined, `file length ${fileLength} is not a byte count`);
  const have = (end) => {
    if (b.length < end) throw fail(Math.min(b.length, end), `needs the file's bytes up to offset ${end}; ${b.length} given`);
  };
  if (fileLength < PROLOGUE) throw fail(0, `a file of ${fileLength} bytes is too short for a strata file`);
  have(PROLOGUE);
  const { major, minor } = checkPrologue(b, fileLength);
  const dv = view(b);

  // HEAD
  have(PROLOGUE + FRAME);
  const head = checkHeadFrame(b, fileLength);
  const hp = PROLOGUE + FRAME;
  have(hp + head.size + TRAILER);
  const stored = u32(b, hp + head.size), actual = crc32(b, hp, hp + head.size);
  if (stored !== actual) throw chunkFail(hp + head.size, 'HEAD', PROLOGUE, `CRC ${hex(actual)} != stored ${hex(stored)}`);
  const header = decodeHead(b, dv, PROLOGUE, head.size, minor);
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
    if (id === 'HEAD' || id === 'GEOM') throw chunkFail(pos, id, pos, 'expected the SKEL chunk before any other known chunk');
    const size = u64(b, pos + 8);
    if (id === 'GEOR' && size > MAX_HEAD_BYTES) throw chunkFail(pos + 8, id, pos, `size ${size === Infinity ? 'beyond 2^53' : size} exceeds the ${MAX_HEAD_BYTES}-byte limit`);
    const end = chunkEnd(pos, id, size, fileLength);
    if (id === 'GEOR') {
      if (georef) throw chunkFail(pos, id, pos, 'a second GEOR chunk');
      have(pos + FRAME + size + TRAILER);
      const stored = u32(b, pos + FRAME + size), actual = crc32(b, pos + FRAME, pos + FRAME + size);
      if (stored !== actual) throw chunkFail(pos + FRAME + size, id, pos, `CRC ${hex(actual)} != stored ${hex(stored)}`);
      georef = decodeGeoref(b, dv, pos, size, minor);
    }
    zeroPadding(pos + FRAME + size + TRAILER, end, id, pos);
    pos = end;
  }

  // SKEL
  const skelAt = pos;
  const skelSize = u64(b, pos + 8);
  const skeletonEnd = chunkEnd(pos, 'SKEL', skelSize, fileLength);
  const sp = pos + FRAME, se = sp + skelSize;
  have(skeletonEnd);
  {
    const stored = u32(b, se), actual = crc32(b, sp, se);
    if (stored !== actual) throw chunkFail(se, 'SKEL', skelAt, `CRC ${hex(actual)} != stored ${hex(stored)}`);
  }
  zeroPadding(se + TRAILER, skeletonEnd, 'SKEL', skelAt);
  const subs = subChunks(b, sp, se, sp, 'SKEL', skelAt);
  const find = (want) => {
    const found = subs.filter((s) => s.id === want);
    if (found.length === 0) throw chunkFail(skelAt, 'SKEL', skelAt, `has no ${want} chunk`);
    if (found.length > 1) throw chunkFail(found[1].at, 'SKEL', skelAt, `has a second ${want} chunk`);
    return found[0];
  };
  const levl = find('LEVL'), node = find('NODE'), nbrs = find('NBRS'), matl = find('MATL');
  const h = header;
  const L = h.levels, N = h.nodes;

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

  // NBRS (entries are read after the node table, which says whose they are)
  const width = nbrs.flags;
  if (width !== 2 && width !== 4) throw chunkFail(nbrs.at + 4, 'NBRS', nbrs.at, `entry width ${width}; must be 2 or 4`);
  if (nbrs.size % width !== 0) throw chunkFail(nbrs.ps, 'NBRS', nbrs.at, `size ${nbrs.size} is not a multiple of ${width}`);
  const nbEntries = nbrs.size / width;

  // NODE
  const nerr = (at, msg, i) => chunkFail(at, 'NODE', node.at, i === undefined ? msg : `node ${i}: ${msg}`, i);
  if (node.size !== N * NODE_BYTES) throw nerr(node.ps, `holds ${node.size} bytes; ${N} nodes need ${N * NODE_BYTES}`);
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
  const neighborList = new Uint32Array(nbEntries);
  const gl = [0, 0, 0], gh = [0, 0, 0], gc = [0, 0, 0];
  let nbFirst = 0, geo = skeletonEnd, nextChild = 0, l = L - 1;
  // Check and decode level l's records and neighbour lists (levels from the top down), then step
  // to the level below.
  const decodeLevel = () => {
    const lev = levels[l];
    const end = lev.firstNode + lev.nodes;
    if (l + 1 < L && nextChild !== end) {
      throw nerr(node.ps + NODE_BYTES * lev.firstNode, `the children of level ${l + 1} cover nodes up to ${nextChild}, level ${l} ends at ${end}`);
    }
    nextChild = end;
    for (let i = lev.firstNode; i < end; i++) {
      const at = node.ps + NODE_BYTES * i;
      const cc = u16(b, at), nc = u16(b, at + 2);
      const first = cc > 0 ? nextChild : 0;
      if (l === 0 && cc > 0) throw nerr(at, `a level-0 node with ${cc} children`, i);
      nextChild += cc;
      if (l > 0 && nextChild > end + levels[l - 1].nodes) throw nerr(at, `children ${first}..+${cc} run past level ${l - 1}`, i);
      if (nbFirst + nc > nbEntries) throw nerr(at, `neighbours run past the ${nbEntries} of NBRS`, i);
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
      const padded = ns + padding(gend);
      totals[3 * l] += nf;
      totals[3 * l + 1] += nv;
      totals[3 * l + 2] += padded;
      if (!(ns >= FRAME + TRAILER && gend <= fileLength)) {
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
  // Check level m's neighbour entries (its records decoded) and make them absolute node ids.
  const decodeEntries = (m) => {
    const lev = levels[m];
    for (let i = lev.firstNode, end = lev.firstNode + lev.nodes; i < end; i++) {
      for (let k = neighborFirst[i], e = k + neighborCount[i]; k < e; k++) {
        const o = nbrs.ps + width * k;
        const x = width === 2 ? u16(b, o) : u32(b, o);
        if (x >= lev.nodes) throw chunkFail(o, 'NBRS', nbrs.at, `node ${i}: neighbour ${x} of the ${lev.nodes} nodes of level ${m}`, i);
        neighborList[k] = x + lev.firstNode;
      }
    }
  };
  // With every level decoded: the totals LEVL states.
  const finish = () => {
    if (geo > fileLength) throw nerr(node.ps, `geometry chunks end at ${geo}, past the end of the ${fileLength}-byte file`);
    for (let l = 0; l < L; l++) {
      const rec = levels[l];
      const [tf, tv, tb] = [totals[3 * l], totals[3 * l + 1], totals[3 * l + 2]];
      if (rec.faces !== tf || rec.vertices !== tv || rec.bytes !== tb) {
        throw lerr(
          levl.ps + l * LEVEL_BYTES,
          `level ${l}: LEVL says ${rec.faces} faces, ${rec.vertices} vertices, ${rec.bytes} bytes; the nodes hold ${tf}, ${tv}, ${tb}`,
        );
      }
    }
    if (totals[0] !== h.inputFaces) throw lerr(levl.ps, `level 0's nodes hold ${totals[0]} faces, HEAD says the input has ${h.inputFaces}`);
    if (nbFirst !== nbEntries) throw chunkFail(nbrs.ps, 'NBRS', nbrs.at, `holds ${nbEntries} neighbours, the nodes use ${nbFirst}`);
  };
  // The records of every level, the totals, then the neighbour entries (the order of the checks,
  // as in strata's reader); top first, the top level and the level below that its nodes' rules
  // are checked against, with their entries.
  const kept = opts.topFirst ? Math.min(L, 2) : L;
  for (let k = kept; k > 0; k--) decodeLevel();
  if (l < 0) finish();
  for (let m = L - 1; m >= L - kept; m--) decodeEntries(m);
  // Where the image levels start (§2): checked against the node table by finish().
  const levelsStart = levels.reduce((sum, rec) => sum + rec.bytes, skeletonEnd);

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
  if (m < mend && minor <= MINOR) throw merr(m, `${mend - m} bytes after ${h.materials} materials`);

  // TEXR (2.2), optional: images, their levels after the geometry, material maps, node densities.
  const texrs = subs.filter((x) => x.id === 'TEXR');
  if (texrs.length > 1) throw chunkFail(texrs[1].at, 'SKEL', skelAt, 'has a second TEXR chunk');
  const textures = texrs.length ? decodeTexr(b, texrs[0], N, materials, levelsStart, fileLength) : { images: [], levels: [], uvDensity: new Float32Array(N) };

  Object.assign(sk, {
    materials,
    textures,
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
  // Where the node table lies, for errors naming a node's record.
  Object.defineProperty(sk, '_nodeTable', { value: { at: node.at, ps: node.ps }, enumerable: false });
  sk.decoded = l < 0 ? N : levels[l].firstNode;
  if (l >= 0) {
    // Holds the skeleton's bytes until the rest is decoded.
    Object.defineProperty(sk, '_rest', {
      value: () => {
        while (l >= 0) decodeLevel();
        finish();
        for (let m = L - kept - 1; m >= 0; m--) decodeEntries(m);
      },
      configurable: true,
    });
  }
  return sk;
}

// ---------------------------------------------------------------------------------------------
// Separating planes (§7.6, format 2.3).

/** Where the ORDR chunk starts if the file has one: after the last GEOM or TEXL and its padding. */
export function planesOffset(sk) {
  let end = sk.skeletonEnd + sk.levels.reduce((a, l) => a + l.bytes, 0);
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
  const table = s._nodeTable;
  const at = table ? table.ps + NODE_BYTES * i : undefined;
  const problem = (msg) => (table ? chunkFail(at, 'NODE', table.at, `node ${i}: ${msg}`, i) : fail(undefined, `node ${i}: ${msg}`, i));
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
  if (s.parent[i] === NO_PARENT) {
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
  for (let k = 0; k < V; k++) {
    if (!(dist2(cx, cy, cz, P[3 * k], P[3 * k + 1], P[3 * k + 2]) <= reach)) throw problem(`vertex ${k} lies outside the node's sphere`);
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
  if (g.clusters.length === 0) {
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
 * Decode and check node i's GEOM chunk: `bytes` are exactly the node's `size` bytes at
 * skeleton.offset[i]. opts.localOrigin = [x, y, z] also returns `local`, positions relative to it
 * computed in f64 before the one rounding to f32.
 */
export function decodeNode(skeleton, i, bytes, opts = {}) {
  const s = skeleton;
  const N = s.nodeCount;
  if (!(Number.isInteger(i) && i >= 0 && i < N)) throw fail(undefined, `node ${i}: no such node; the file has ${N}`);
  if (!isComplete(s) && !(i < s.decoded && s.firstChild[i] + s.childCount[i] <= s.decoded)) {
    throw fail(undefined, `node ${i}: its record or its children's are not decoded yet (completeSkeleton)`);
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
