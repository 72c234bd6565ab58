// A Worker that decodes and checks nodes off the main thread (decoder.js starts it). It keeps its
// own copy of the skeleton, decoded from the same bytes the main thread decoded it from, so that
// only a node's bytes go in and its arrays come back (transferred, not copied).
//
// Messages in: {op: 'open', bytes, length, localOrigin} (the bytes decodeSkeleton read, top pages
// first), {op: 'complete', bytes} (the skeleton's bytes once the main thread completed its own),
// {op: 'decode', id, node, bytes}. Out: {id, geometry} (with the node's open border for the seams
// between levels, `geometry.border`, made here too, but for a format-4 file) or {id, error:
// {message, name, offset, node}}.

import { FormatError, completeSkeleton, decodeNode, decodeSkeleton } from './format.js';
import { border } from './seams.js';

/** The worker's state and its answer to each message: `{reply, transfer}` or null (no answer). */
export function decodeHandler() {
  let skeleton = null, localOrigin = null, broken = null;
  return (msg) => {
    try {
      if (msg.op === 'open') {
        broken = null;
        skeleton = decodeSkeleton(msg.bytes, msg.length, { topFirst: true });
        localOrigin = msg.localOrigin;
        return null;
      }
      if (msg.op === 'complete') {
        if (skeleton) completeSkeleton(skeleton, msg.bytes);
        return null;
      }
    } catch (e) {
      // The main thread decoded the same bytes: a failure here is reported with each node asked.
      broken = e;
      return null;
    }
    if (msg.op !== 'decode') return null;
    try {
      if (broken) throw broken;
      if (!skeleton) throw new Error('the decoder has no skeleton (no open message)');
      const geometry = decodeNode(skeleton, msg.node, msg.bytes, { localOrigin });
      // A DAG's nodes meet edge for edge: no seams, no borders (selection.md §9).
      if (!skeleton.dag) geometry.border = border(skeleton.level[msg.node], skeleton.error[msg.node], geometry);
      return { reply: { id: msg.id, geometry }, transfer: buffersOf(geometry, geometry.border ?? {}) };
    } catch (e) {
      const error = { message: e?.message ?? String(e), name: e?.name ?? 'Error', format: e instanceof FormatError, offset: e?.offset, node: e?.node };
      return { reply: { id: msg.id, error }, transfer: [] };
    }
  };
}

/** The distinct buffers under the typed arrays of `objects` (a geometry, its border). */
export function buffersOf(...objects) {
  const seen = new Set();
  for (const o of objects) for (const v of Object.values(o)) if (ArrayBuffer.isView(v)) seen.add(v.buffer);
  return [...seen];
}

if (typeof WorkerGlobalScope !== 'undefined' && globalThis instanceof WorkerGlobalScope) {
  const handle = decodeHandler();
  globalThis.onmessage = (e) => {
    const r = handle(e.data);
    if (r) globalThis.postMessage(r.reply, r.transfer);
  };
  // A message that cannot be read leaves a decode unanswered: the pool's timeout hands its work back.
  globalThis.onmessageerror = () => globalThis.close();
}
