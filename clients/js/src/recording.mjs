// recording.mjs - reads and writes clothd recordings (CLR1; layout in PROTOCOL.md, "Recordings"),
// in the browser and in node, no dependencies but frame.mjs beside it. A recording is one scene's stream written down:
// its hello, then its events (text records) and every frame it published (binary CLF1 frames, as
// frame.mjs decodes them), in order; a finished one ends with an index of its frames and texts and
// a 16-byte tail pointing at it, so frame k is found at once. A file without a valid tail (still
// being recorded, or cut by a crash) is read by scanning its records up to the last complete one.
//
//   const r = readRecording(bytes);     // throws RecordingError(message, offset)
//   readRecording(bytes, { salvage: true }) // an exporter's reading: a file corrupt past its hello
//                                       // keeps the frames before the damage; r.problem says what
//   r.frames[k] -> {offset, length, simTime, key, textsBefore}; r.frame(k) -> the CLF1 bytes;
//   r.text(k) -> text record k parsed (0 is the hello); r.seek(t) -> the frame at t s.

import { ENCODINGS, isDeltaKeyKind } from './frame.mjs';

export const REC_MAGIC = 'CLR1';
export const TAIL_MAGIC = 'CLRX';
export const REC_VERSION = 1;
export const FILE_HEADER = 16;
export const RECORD_HEAD = 8;
export const TAIL_SIZE = 16;
export const INDEX_FRAME_SIZE = 24;
export const INDEX_TEXT_SIZE = 8;
export const REC_TEXT = 1, REC_FRAME = 2, REC_INDEX = 3;
/** The most records a reader takes. */
export const MAX_RECORDS = 1 << 24;

const CLF_MAGIC = 'CLF1', CLF_HEADER = 72, CLF_DELTA = 3, CLF_MAX_VERTICES = 4096 * 4096;
const align4 = (n) => (n + 3) & ~3;
const magicAt = (b, at) => String.fromCharCode(b[at], b[at + 1], b[at + 2], b[at + 3]);

/** A file that is not a recording, or a corrupt one; `offset` is where the reader found it wrong. */
export class RecordingError extends Error {
  constructor(message, offset) {
    super(offset === undefined ? message : `${message} (at byte ${offset})`);
    this.name = 'RecordingError';
    this.offset = offset;
  }
}

/**
 * @param {ArrayBuffer|ArrayBufferView} data a whole .clr file, or as much of it as there is
 * @param {{salvage?: boolean}} [options] salvage: a bad index is ignored (the records are scanned)
 *   and a bad record after the hello ends the frames before it, instead of throwing; `problem`
 *   then says what was wrong (null when nothing was)
 * @returns {{complete: boolean, problem: string|null, hello: object, info: object, frames: {offset: number, length: number,
 *   simTime: number, key: number, textsBefore: number}[], texts: {offset: number, length: number}[],
 *   frame: (k: number) => Uint8Array, text: (k: number) => object, duration: number,
 *   seek: (t: number) => number, bytes: number}}
 */
export function readRecording(data, options = {}) {
  const b = data instanceof ArrayBuffer ? new Uint8Array(data) : new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
  const dv = new DataView(b.buffer, b.byteOffset, b.byteLength);
  if (b.length < FILE_HEADER) throw new RecordingError(`a recording is at least ${FILE_HEADER} bytes, this is ${b.length}`, 0);
  if (magicAt(b, 0) !== REC_MAGIC) throw new RecordingError(`not a clothd recording (magic ${JSON.stringify(magicAt(b, 0))})`, 0);
  const version = dv.getUint32(4, true);
  if (version !== REC_VERSION) throw new RecordingError(`recording version ${version}, this reader knows ${REC_VERSION}`, 4);
  if (dv.getUint32(8, true) !== 0) throw new RecordingError('recording flags this reader does not know', 8);

  const salvage = options.salvage ? { problem: null } : null;
  let fromIndex;
  try {
    fromIndex = readIndex(b, dv);
  } catch (e) {
    if (!salvage || !(e instanceof RecordingError)) throw e;
    salvage.problem = `${e.message}; its records were scanned instead`;
    fromIndex = null;
  }
  const { frames, texts } = fromIndex ?? scan(b, dv, salvage);
  const complete = !!fromIndex;
  if (texts.length === 0 || texts[0].offset !== FILE_HEADER)
    throw new RecordingError('the first record of a recording is its hello (text)', FILE_HEADER);
  const utf8 = new TextDecoder('utf-8', { fatal: true });
  const text = (k) => {
    const t = texts[k];
    let json;
    try {
      json = JSON.parse(utf8.decode(b.subarray(t.offset + RECORD_HEAD, t.offset + RECORD_HEAD + t.length)));
    } catch (e) {
      throw new RecordingError(`text record ${k} is not JSON: ${e.message}`, t.offset);
    }
    if (!json || typeof json !== 'object' || Array.isArray(json)) throw new RecordingError(`text record ${k} is not a JSON object`, t.offset);
    return json;
  };
  const hello = text(0);
  if (hello.type !== 'hello' || !hello.scene || typeof hello.scene !== 'object')
    throw new RecordingError('the first record is not a hello with its scene', FILE_HEADER);
  try {
    checkFrames(b, dv, frames, texts, hello, text);
  } catch (e) {
    if (!salvage || !(e instanceof RecordingError) || e.frame === undefined) throw e;
    frames.length = e.frame; // the frames before the bad one
    salvage.problem = `${e.message}: the ${e.frame} frames before it are kept`;
  }
  const frame = (k) => {
    const f = frames[k];
    if (!f) throw new RangeError(`no frame ${k} in a recording of ${frames.length}`);
    return b.subarray(f.offset + RECORD_HEAD, f.offset + RECORD_HEAD + f.length);
  };
  const t0 = frames.length ? frames[0].simTime : 0;
  const seek = (t) => {
    let lo = 0, hi = frames.length - 1;
    if (hi < 0) return -1;
    while (lo < hi) {
      const mid = (lo + hi + 1) >> 1;
      if (frames[mid].simTime - t0 <= t + 1e-9) lo = mid; // a nanosecond's slack for t0 + k / frame_rate
      else hi = mid - 1;
    }
    return lo;
  };
  return {
    complete, problem: salvage?.problem ?? null, hello, info: hello.recording ?? {}, frames, texts, frame, text, seek, bytes: b.length,
    duration: frames.length ? frames[frames.length - 1].simTime - t0 : 0,
  };
}

// The index of a finished file, checked against the records it points at; null when the file
// has no valid tail (then it is scanned).
function readIndex(b, dv) {
  if (b.length < FILE_HEADER + RECORD_HEAD + 8 + TAIL_SIZE) return null;
  const tail = b.length - TAIL_SIZE;
  if (magicAt(b, tail) !== TAIL_MAGIC || dv.getUint32(tail + 4, true) !== 0) return null;
  const at = Number(dv.getBigUint64(tail + 8, true));
  const bad = (what, where = tail + 8) => { throw new RecordingError(`the recording's index: ${what}`, where); };
  if (at < FILE_HEADER || at % 4 || at + RECORD_HEAD + 8 > tail) bad(`its offset ${at} is not inside the file`);
  if (dv.getUint32(at, true) !== REC_INDEX) bad('the tail points at a record that is not the index', at);
  const len = dv.getUint32(at + 4, true);
  if (at + RECORD_HEAD + align4(len) !== tail) bad(`a payload of ${len} bytes does not end at the tail`, at + 4);
  const nf = dv.getUint32(at + 8, true), nt = dv.getUint32(at + 12, true);
  if (nf + nt > MAX_RECORDS) bad(`${nf + nt} records, more than ${MAX_RECORDS}`, at + 8);
  if (len !== 8 + INDEX_FRAME_SIZE * nf + INDEX_TEXT_SIZE * nt) bad(`${nf} frames and ${nt} texts do not take ${len} bytes`, at + 8);
  const record = (off, type, k, what) => {
    if (off < FILE_HEADER || off % 4 || off + RECORD_HEAD > at || dv.getUint32(off, true) !== type)
      bad(`${what} ${k} does not point at a ${type === REC_TEXT ? 'text' : 'frame'} record`, off);
    const length = dv.getUint32(off + 4, true);
    if (off + RECORD_HEAD + length > at) bad(`${what} ${k} runs past the index`, off);
    return length;
  };
  const frames = [], texts = [];
  let p = at + 16;
  for (let k = 0; k < nf; k++, p += INDEX_FRAME_SIZE) {
    const offset = Number(dv.getBigUint64(p, true));
    const f = { offset, length: record(offset, REC_FRAME, k, 'frame'), simTime: dv.getFloat64(p + 8, true),
      key: dv.getUint32(p + 16, true), textsBefore: dv.getUint32(p + 20, true) };
    if (k && offset <= frames[k - 1].offset) bad(`frame ${k} is not after frame ${k - 1}`, p);
    if (f.key > k || f.textsBefore > nt) bad(`frame ${k}'s keyframe or text count is out of range`, p + 16);
    frames.push(f);
  }
  for (let k = 0; k < nt; k++, p += INDEX_TEXT_SIZE) {
    const offset = Number(dv.getBigUint64(p, true));
    texts.push({ offset, length: record(offset, REC_TEXT, k, 'text') });
    if (k && offset <= texts[k - 1].offset) bad(`text ${k} is not after text ${k - 1}`, p);
  }
  // texts_before must say where each frame sits among the texts.
  for (let k = 0, t = 0; k < nf; k++) {
    while (t < nt && texts[t].offset < frames[k].offset) t++;
    if (frames[k].textsBefore !== t) bad(`frame ${k} says ${frames[k].textsBefore} texts come before it, there are ${t}`, at + 16 + INDEX_FRAME_SIZE * k + 20);
  }
  return { frames, texts };
}

// A file without its index: its records in order, up to the last complete one.
function scan(b, dv, salvage = null) {
  const frames = [], texts = [];
  let keyOrdinal = -1;
  for (let at = FILE_HEADER; at + RECORD_HEAD <= b.length;) {
    if (frames.length + texts.length >= MAX_RECORDS) throw new RecordingError(`more than ${MAX_RECORDS} records`, at);
    const type = dv.getUint32(at, true), length = dv.getUint32(at + 4, true);
    if (type < REC_TEXT || type > REC_INDEX) {
      if (!salvage) throw new RecordingError(`record of unknown type ${type}`, at);
      salvage.problem = `record of unknown type ${type} at byte ${at}: the records before it are kept`;
      break;
    }
    if (at + RECORD_HEAD + length > b.length) break; // cut mid-record: what came before counts
    if (type === REC_TEXT) texts.push({ offset: at, length });
    else if (type === REC_FRAME) {
      const p = at + RECORD_HEAD;
      const isKey = length < CLF_HEADER + 4 || (dv.getUint16(p + 6, true) & 3) !== CLF_DELTA || isDeltaKeyKind(dv.getUint32(p + CLF_HEADER, true));
      if (isKey) keyOrdinal = frames.length;
      frames.push({ offset: at, length, simTime: length >= CLF_HEADER ? dv.getFloat64(p + 24, true) : NaN,
        key: Math.max(keyOrdinal, 0), textsBefore: texts.length });
    } else break; // an index without a valid tail: the recording ended here, the index is not trusted
    at += RECORD_HEAD + align4(length);
  }
  return { frames, texts };
}

// Every frame record holds a CLF1 frame: the recording's encoding, as many vertices as the frame
// before (the hello's nx x ny for the first; any number after a `scene` or `snapshot_restored`
// event, which may change the layout), a finite sim time (the index's), and, for a delta frame,
// the keyframe its index entry names, the last one before it.
function checkFrames(b, dv, frames, texts, hello, text) {
  const enc = hello.recording?.encoding;
  const encodings = ENCODINGS;
  const relayout = new Set(['scene', 'snapshot_restored']);
  let n = (hello.scene.nx | 0) * (hello.scene.ny | 0);
  let textsSeen = 1, keyId = -1;
  frames.forEach((f, k) => {
    const p = f.offset + RECORD_HEAD;
    const bad = (what) => { throw Object.assign(new RecordingError(`frame ${k}: ${what}`, f.offset), { frame: k }); };
    if (f.length < CLF_HEADER || magicAt(b, p) !== CLF_MAGIC || dv.getUint16(p + 4, true) !== CLF_HEADER) bad('not a clothd frame (CLF1)');
    const e = dv.getUint16(p + 6, true) & 3, nv = dv.getUint32(p + 40, true);
    if (enc !== undefined && encodings[e] !== enc) bad(`a ${encodings[e]} frame in a ${enc} recording`);
    try {
      for (; textsSeen < f.textsBefore; textsSeen++) if (relayout.has(text(textsSeen).event)) n = -1; // any size after
    } catch (e) {
      throw Object.assign(e, { frame: k });
    }

    if (nv > CLF_MAX_VERTICES || (n >= 0 && nv !== n)) bad(`${nv} vertices, the cloth has ${n}`);
    n = nv;
    if (!Number.isFinite(f.simTime) || f.simTime !== dv.getFloat64(p + 24, true)) bad('its sim time is not the frame\'s');
    if (e === CLF_DELTA) {
      if (f.length < CLF_HEADER + 44) bad('a delta frame shorter than its head');
      const kind = dv.getUint32(p + CLF_HEADER, true), id = dv.getUint32(p + CLF_HEADER + 4, true);
      if (isDeltaKeyKind(kind)) {
        if (f.key !== k) bad(`a keyframe whose index names frame ${f.key} as its keyframe`);
        keyId = id;
      } else if ((kind !== 1 && kind !== 3) || id !== keyId || f.key >= k || dv.getUint32(frames[f.key].offset + RECORD_HEAD + CLF_HEADER + 4, true) !== id) {
        bad(`a delta of keyframe ${id} that the recording does not hold before it`);
      }
    } else if (f.key !== k) bad('a frame that needs no keyframe names another');
  });
}

/**
 * A recording from messages as a stream sends them (tests, and files made in a page): strings or
 * objects (text; the first is the hello) and ArrayBuffer/ArrayBufferView (CLF1 frames), in order.
 * @param {(string|object|ArrayBuffer|ArrayBufferView)[]} messages
 * @param {{recording?: object, index?: boolean}} [options] `recording` becomes the hello's
 *   `.recording`; `index: false` leaves out the index and tail (as a file cut by a crash)
 * @returns {Uint8Array}
 */
export function buildRecording(messages, options = {}) {
  const enc = new TextEncoder();
  const parts = [];
  let size = FILE_HEADER;
  const frames = [], texts = [];
  let keyOrdinal = 0;
  const record = (type, payload) => {
    const head = new Uint8Array(RECORD_HEAD);
    const hv = new DataView(head.buffer);
    hv.setUint32(0, type, true);
    hv.setUint32(4, payload.length, true);
    parts.push(head, payload, new Uint8Array(align4(payload.length) - payload.length));
    const at = size;
    size += RECORD_HEAD + align4(payload.length);
    return at;
  };
  messages.forEach((m, k) => {
    if (typeof m === 'string' || (m && !(m instanceof ArrayBuffer) && !ArrayBuffer.isView(m))) {
      let json = typeof m === 'string' ? JSON.parse(m) : m;
      if (k === 0 && options.recording) json = { ...json, recording: options.recording };
      texts.push(record(REC_TEXT, enc.encode(k === 0 || typeof m !== 'string' ? JSON.stringify(json) : m)));
    } else {
      const p = m instanceof ArrayBuffer ? new Uint8Array(m) : new Uint8Array(m.buffer, m.byteOffset, m.byteLength);
      const dv = new DataView(p.buffer, p.byteOffset, p.byteLength);
      const delta = (dv.getUint16(6, true) & 3) === CLF_DELTA;
      if (!delta || isDeltaKeyKind(dv.getUint32(CLF_HEADER, true))) keyOrdinal = frames.length;
      frames.push({ offset: record(REC_FRAME, p.slice()), simTime: dv.getFloat64(24, true), key: keyOrdinal, textsBefore: texts.length });
    }
  });
  if (options.index !== false) {
    const payload = new Uint8Array(8 + INDEX_FRAME_SIZE * frames.length + INDEX_TEXT_SIZE * texts.length);
    const pv = new DataView(payload.buffer);
    pv.setUint32(0, frames.length, true);
    pv.setUint32(4, texts.length, true);
    let p = 8;
    for (const f of frames) {
      pv.setBigUint64(p, BigInt(f.offset), true);
      pv.setFloat64(p + 8, f.simTime, true);
      pv.setUint32(p + 16, f.key, true);
      pv.setUint32(p + 20, f.textsBefore, true);
      p += INDEX_FRAME_SIZE;
    }
    for (const t of texts) pv.setBigUint64(p, BigInt(t), true), (p += INDEX_TEXT_SIZE);
    const at = record(REC_INDEX, payload);
    const tail = new Uint8Array(TAIL_SIZE);
    const tv = new DataView(tail.buffer);
    tail.set([...TAIL_MAGIC].map((c) => c.charCodeAt(0)));
    tv.setBigUint64(8, BigInt(at), true);
    parts.push(tail);
    size += TAIL_SIZE;
  }
  const out = new Uint8Array(size);
  out.set([...REC_MAGIC].map((c) => c.charCodeAt(0)));
  new DataView(out.buffer).setUint32(4, REC_VERSION, true);
  let at = FILE_HEADER;
  for (const p of parts) out.set(p, at), (at += p.length);
  return out;
}
