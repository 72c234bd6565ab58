// Byte sources the viewer reads a chunk file from: a URL read by HTTP range requests (any static
// host that answers them), or a local file read by slices. Each counts its requests and bytes.

/** A read that takes longer fails (and is tried again by the streamer). */
const READ_TIMEOUT_MS = 60000;
/** The largest file read whole when a server ignores Range. */
const WHOLE_FILE_LIMIT = 1 << 30;
/** Requests kept in `log` (the most recent). */
const LOG_LIMIT = 10000;

/** A URL read with `Range` requests; a server that ignores Range is read whole, once, with a warning. */
export class HttpSource {
  constructor(url) {
    this.url = url;
    const last = new URL(url, globalThis.location?.href).pathname.split('/').pop() || url;
    try {
      this.name = decodeURIComponent(last);
    } catch {
      this.name = last;
    }
    this.length = undefined;
    this.whole = null;
    this.warning = null;
    this.requests = 0;
    this.bytes = 0;
    /** Every request made: `{start, end, status, bytes, ms}` (end exclusive). */
    this.log = [];
  }

  /** Bytes `[start, end)`, fewer if the file ends first. */
  async read(start, end) {
    if (this.whole) return this.whole.subarray(start, Math.min(end, this.whole.length));
    const t0 = performance.now();
    this.requests++;
    let res;
    try {
      res = await fetch(this.url, { headers: { Range: `bytes=${start}-${end - 1}` }, signal: AbortSignal.timeout(READ_TIMEOUT_MS) });
    } catch (e) {
      throw new Error(`${this.url}: the request failed (${e.message}); is the server running and does it allow this origin (CORS)?`);
    }
    const entry = { start, end, status: res.status, bytes: 0, ms: 0 };
    this.log.push(entry);
    if (this.log.length > LOG_LIMIT) this.log.splice(0, this.log.length - LOG_LIMIT);
    if (res.status === 206) {
      const range = /^bytes (\d+)-(\d+)\/(\d+)$/.exec(res.headers.get('Content-Range') ?? '');
      if (!range) throw new Error(`${this.url}: a 206 answer without a readable Content-Range (a cross-origin server must expose it)`);
      const [first, last, total] = range.slice(1).map(Number);
      const body = new Uint8Array(await res.arrayBuffer());
      this.note(entry, body.length, t0);
      const want = Math.min(end, total);
      if (first !== start || last + 1 < want || body.length !== last + 1 - first) {
        throw new Error(`${this.url}: asked for bytes ${start}-${end - 1}, the server sent ${first}-${last} (${body.length} bytes)`);
      }
      if (this.length !== undefined && this.length !== total) throw new Error(`${this.url}: the file changed size while it was read (${this.length} → ${total} bytes)`);
      this.length = total;
      return body.subarray(0, want - start);
    }
    if (res.status === 200) {
      const size = Number(res.headers.get('Content-Length') ?? NaN);
      if (size > WHOLE_FILE_LIMIT) {
        await res.body?.cancel();
        throw new Error(`${this.url}: the server ignores Range requests (it answered 200, not 206), and the file is ${size.toLocaleString()} bytes, too large to download whole; serve it with strata serve or any server that answers ranges`);
      }
      this.warning = 'The server ignores Range requests (it answered 200, not 206): downloading the whole file.';
      const body = new Uint8Array(await res.arrayBuffer());
      this.note(entry, body.length, t0);
      this.whole = body;
      this.length = body.length;
      this.warning = `The server ignored the Range request (it answered 200, not 206): the whole file (${body.length.toLocaleString()} bytes) was downloaded instead of the parts needed.`;
      return body.subarray(start, Math.min(end, body.length));
    }
    this.note(entry, 0, t0);
    if (res.status === 416) throw new Error(`${this.url}: bytes ${start}-${end - 1} are past the end of the file (416): it is shorter than its header says`);
    throw new Error(`${this.url}: HTTP ${res.status} ${res.statusText}`);
  }

  note(entry, bytes, t0) {
    entry.bytes = bytes;
    entry.ms = performance.now() - t0;
    this.bytes += bytes;
  }
}

/** A local file (dropped or chosen), read by slices: nothing is uploaded. */
export class FileSource {
  constructor(file) {
    this.file = file;
    this.name = file.name;
    this.length = file.size;
    this.warning = null;
    this.requests = 0;
    this.bytes = 0;
    this.log = [];
  }

  async read(start, end) {
    const t0 = performance.now();
    this.requests++;
    const body = new Uint8Array(await this.file.slice(start, Math.min(end, this.length)).arrayBuffer());
    this.bytes += body.length;
    this.log.push({ start, end, status: 0, bytes: body.length, ms: performance.now() - t0 });
    return body;
  }
}
