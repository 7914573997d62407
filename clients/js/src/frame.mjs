// frame.mjs - decodes the binary frames of the clothd stream (layout in clothd_frame.h and
// PROTOCOL.md), in the browser and in node. No dependencies: meshopt frames need the decoder of
// the npm package `meshoptimizer`, passed in (`import { MeshoptDecoder } from 'meshoptimizer';
// await MeshoptDecoder.ready; decodeFrame(data, { meshopt: MeshoptDecoder })`).
//
// delta frames (encoding 3) refer to the newest keyframe, so they need a decoder that keeps it:
// `createDecoder({ zstd, meshopt })` returns `{ decode(data) }`, which decodes every encoding; zstd
// is the decoder of the npm package `zstddec` (`const zstd = new ZSTDDecoder(); await zstd.init()`).
//
// A viewer decoding 60 frames a second passes its own arrays (options.positions, .scalar,
// .scratch), which are used when large enough: nothing is allocated per frame then but the
// result object.
//
// A delta frame's inner loops (kinds 2 and 3: counting escapes, the prediction's inverse) run in
// WebAssembly with SIMD where the engine has it (delta-wasm.mjs, built from proto/delta_inverse.c), in a
// memory of each decoder's own that also holds its keyframe; elsewhere, or with
// `createDecoder({ wasm: false })`, in the JavaScript below. Both give the same positions, bit for
// bit.
import { DELTA_WASM } from './delta-wasm.mjs';

export const MAGIC = 'CLF1';
export const HEADER_SIZE = 72;
export const ENCODINGS = ['f32', 'q16', 'meshopt', 'delta'];
export const ROCK_SIZE = 36;
export const MESHOPT_STRIDE = 8;
export const FLAG_SCALAR = 4;
/** Flag bits 3-15: 0 in every frame (bit 3 is kept for the encoding's third bit, later). */
export const FLAG_RESERVED = 0xfff8;
/** The most vertices a frame may claim: clothd's largest cloth, 4096 x 4096. */
export const MAX_VERTICES = 4096 * 4096;
/** The delta positions section's head: kind, keyframe id and frame, quantum, origin, row, length. */
export const DELTA_HEAD = 44;
/** Whether a delta section's kind is a keyframe's: 2, or 0 (the first, byte-plane layout). */
export const isDeltaKeyKind = (kind) => kind === 2 || kind === 0;

const align4 = (n) => (n + 3) & ~3;

/**
 * A decoded frame (a delta frame decoded by createDecoder's decoder also has `delta`).
 * @typedef {{frame: number, step: number, simTime: number, wallNs: bigint, encoding: string,
 *   nVertices: number, nRocks: number, bboxMin: number[], bboxMax: number[],
 *   positions: Float32Array, scalar: Uint8Array|null, bytes: number,
 *   rocks: {id: number, position: number[], radius: number, orientation: number[]}[],
 *   delta?: {keyframe: boolean, keyId: number, keyFrame: number, quantum: number}}} Frame
 */

/**
 * @param {ArrayBuffer|ArrayBufferView} data one binary message
 * @param {{meshopt?: {decodeVertexBuffer: Function}, positions?: Float32Array, scalar?: Uint8Array,
 *   scratch?: Uint8Array}} [options] the decoder for meshopt frames; arrays to decode into
 * @returns {Frame}
 */
export function decodeFrame(data, options = {}) {
  return decode(data, options, null);
}

/**
 * A decoder that keeps the newest keyframe of a delta stream, for every encoding.
 * @param {{zstd?: {decode: Function}, meshopt?: {decodeVertexBuffer: Function}, wasm?: boolean,
 *   positions?: Float32Array, scalar?: Uint8Array, scratch?: Uint8Array}} [options] zstd: the
 *   decoder of delta frames (zstddec's ZSTDDecoder, initialised); wasm: false decodes delta frames
 *   in JavaScript only (else WebAssembly SIMD where available); the rest as decodeFrame's
 * @returns {{decode: (data: ArrayBuffer|ArrayBufferView) => Frame,
 *   keyframe: () => {id: number, frame: number, quantum: number, nVertices: number}|null,
 *   wasm: () => boolean|null}}
 *   decode gives decodeFrame's result; for a delta frame also `delta: {keyframe: boolean, keyId,
 *   keyFrame, quantum}`. A delta whose keyframe this decoder has not seen throws (and changes
 *   nothing): the server sends every client the keyframe first; `{"type": "keyframe"}` asks for
 *   a new one.
 */
export function createDecoder(options = {}) {
  const state = { key: null };
  return {
    decode: (data) => decode(data, options, state),
    keyframe: () => (state.key ? { id: state.key.id, frame: state.key.frame, quantum: state.key.quantum, nVertices: state.key.n } : null),
    /** Whether delta frames are decoded in WebAssembly (after the first one; null before). */
    wasm: () => (state.inverse === undefined ? null : state.inverse !== null),
  };
}

function decode(data, options, state) {
  const bytes = data instanceof ArrayBuffer ? new Uint8Array(data)
    : new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  if (bytes.length < HEADER_SIZE) throw new Error(`frame of ${bytes.length} bytes is shorter than its header`);
  const magic = String.fromCharCode(bytes[0], bytes[1], bytes[2], bytes[3]);
  if (magic !== MAGIC) throw new Error(`not a clothd frame (magic ${JSON.stringify(magic)})`);
  const headerSize = dv.getUint16(4, true);
  const flags = dv.getUint16(6, true);
  if (flags & FLAG_RESERVED) throw new Error(`frame flags 0x${flags.toString(16)} set bits this reader does not know`);
  const encoding = ENCODINGS[flags & 3];
  if (!encoding) throw new Error(`unknown encoding ${flags & 3}`);
  const n = dv.getUint32(40, true);
  const nRocks = dv.getUint32(44, true);
  const bboxMin = [0, 1, 2].map((c) => dv.getFloat32(48 + 4 * c, true));
  const bboxMax = [0, 1, 2].map((c) => dv.getFloat32(60 + 4 * c, true));
  const reuse = (given, length, Type) => (given && given.length >= length ? given.subarray(0, length) : new Type(length));
  let at = headerSize;
  const need = (count, what) => {
    if (at + count > bytes.length) throw new Error(`frame of ${bytes.length} bytes is truncated: its ${what} need ${at + count}`);
  };
  if (n > MAX_VERTICES) throw new Error(`frame claims ${n} vertices, more than ${MAX_VERTICES}`);
  need(encoding === 'f32' ? 12 * n : encoding === 'q16' ? 6 * n : encoding === 'meshopt' ? 4 : DELTA_HEAD, 'positions');
  const positions = reuse(options.positions, 3 * n, Float32Array);
  let delta = null;

  // q16: bbox min .. max mapped to 0 .. 65535 per axis; a flat axis is all 0.
  const ext = [0, 1, 2].map((c) => bboxMax[c] - bboxMin[c]);
  const step = ext.map((e) => (e >= 1e-9 ? e / 65535 : 0));
  const dequantize = (q, stride) => {
    for (let v = 0; v < n; v++)
      for (let c = 0; c < 3; c++) positions[3 * v + c] = bboxMin[c] + q[stride * v + c] * step[c];
  };

  if (encoding === 'f32') {
    for (let k = 0; k < 3 * n; k++) positions[k] = dv.getFloat32(at + 4 * k, true);
    at += 12 * n;
  } else if (encoding === 'q16') {
    for (let v = 0; v < n; v++)
      for (let c = 0; c < 3; c++) positions[3 * v + c] = bboxMin[c] + dv.getUint16(at + 6 * v + 2 * c, true) * step[c];
    at += 6 * n;
  } else if (encoding === 'delta') {
    if (!state) throw new Error('a delta frame needs the decoder of createDecoder(), which keeps its keyframe');
    delta = decodeDelta(bytes, dv, at, n, positions, options, state);
    at += DELTA_HEAD + delta.length;
  } else {
    if (!options.meshopt) throw new Error('a meshopt frame needs options.meshopt (MeshoptDecoder of the meshoptimizer package)');
    const len = dv.getUint32(at, true);
    need(4 + len, 'positions');
    const target = reuse(options.scratch && options.scratch.byteOffset % 2 === 0 ? options.scratch : null,
      n * MESHOPT_STRIDE, Uint8Array);
    options.meshopt.decodeVertexBuffer(target, n, MESHOPT_STRIDE, bytes.subarray(at + 4, at + 4 + len));
    const q = new Uint16Array(target.buffer, target.byteOffset, 4 * n); // little-endian hosts
    dequantize(q, 4);
    at += 4 + len;
  }
  at = align4(at);

  let scalar = null;
  if (flags & FLAG_SCALAR) {
    need(n, 'scalars');
    scalar = reuse(options.scalar, n, Uint8Array);
    scalar.set(bytes.subarray(at, at + n));
    at = align4(at + n);
  }
  need(ROCK_SIZE * nRocks, 'rocks');
  const rocks = [];
  for (let r = 0; r < nRocks; r++, at += ROCK_SIZE) {
    const f = (k) => dv.getFloat32(at + 4 * k, true);
    rocks.push({ id: dv.getUint32(at, true), position: [f(1), f(2), f(3)], radius: f(4), orientation: [f(5), f(6), f(7), f(8)] });
  }
  if (at !== bytes.length) throw new Error(`frame has ${bytes.length} bytes, its sections ${at}`);
  const out = {
    frame: Number(dv.getBigUint64(8, true)),
    step: Number(dv.getBigUint64(16, true)),
    simTime: dv.getFloat64(24, true),
    wallNs: dv.getBigUint64(32, true),
    encoding, nVertices: n, nRocks, bboxMin, bboxMax, positions, scalar, rocks, bytes: bytes.length,
  };
  if (delta) {
    if (delta.newKey) { // only a frame that decoded whole replaces the keyframe
      state.spareG = state.key && !state.key.slot ? state.key.g : null;
      state.key = delta.newKey;
    }
    out.delta = { keyframe: delta.keyframe, keyId: delta.keyId, keyFrame: delta.keyFrame, quantum: delta.quantum };
  }
  return out;
}

// The delta positions section at `at` (layout in clothd_frame.h): per axis, a zstd frame of the
// int8 residuals (int32 escapes) of the parallelogram prediction of a = g - origin (basis 0) or
// g - g of the keyframe (basis 1), kinds 2 and 3; or (kinds 0 and 1, the first layout) zstd frames of
// the byte planes of the zigzagged residuals. All integer arithmetic is mod 2^32 (| 0).
function decodeDelta(bytes, dv, at, n, positions, options, state) {
  const kind = dv.getUint32(at, true);
  const keyId = dv.getUint32(at + 4, true);
  const keyFrame = Number(dv.getBigUint64(at + 8, true));
  const quantum = dv.getFloat64(at + 16, true);
  const origin = [0, 1, 2].map((c) => dv.getInt32(at + 24 + 4 * c, true));
  const row = dv.getUint32(at + 36, true);
  const length = dv.getUint32(at + 40, true);
  if (kind > 3) throw new Error(`unknown delta kind ${kind}`);
  const isKey = isDeltaKeyKind(kind);
  if (!(quantum > 0 && quantum < Infinity)) throw new Error(`delta quantum ${quantum} is not a positive number`);
  if (row < 1) throw new Error('delta row of 0 vertices');
  if (at + DELTA_HEAD + length > bytes.length) throw new Error(`frame of ${bytes.length} bytes is truncated: its positions need ${at + DELTA_HEAD + length}`);
  const key = state.key;
  if (!isKey && !(key && key.id === keyId && key.n === n && key.quantum === quantum))
    throw new Error(`delta of keyframe ${keyId} (frame ${keyFrame}), and this decoder holds ${key ? `keyframe ${key.id}` : 'no keyframe'}`);
  if (!options.zstd) throw new Error('a delta frame needs options.zstd (ZSTDDecoder of the zstddec package, initialised)');
  if (kind >= 2) return decodeAxes(bytes, dv, at, n, row, length, positions, options, state, { isKey, keyId, keyFrame, quantum, origin, key });
  return decodeDeltaPlanes(bytes, at, n, row, length, positions, options, state, kind, key, origin, quantum, keyId, keyFrame);
}

function decodeDeltaPlanes(bytes, at, n, row, length, positions, options, state, kind, key, origin, quantum, keyId, keyFrame) {
  const raw = options.zstd.decode(bytes.subarray(at + DELTA_HEAD, at + DELTA_HEAD + length), 12 * n);
  if (raw.length !== 12 * n) throw new Error(`delta values of ${raw.length} bytes, not ${12 * n}`);
  const g = kind === 0 ? new Int32Array(3 * n) : null;
  // Per axis, into a plane of n values (contiguous), row by row: the first row sums its left
  // neighbours, every later row starts from the value below and adds left + below - below-left.
  const a = state.scratch && state.scratch.length >= n ? state.scratch : (state.scratch = new Int32Array(n));
  const w = Math.min(row, n);
  for (let c = 0; c < 3; c++) {
    const p0 = 4 * c * n, p1 = p0 + n, p2 = p1 + n, p3 = p2 + n;
    for (let j0 = 0; j0 < n; j0 += w) {
      const end = Math.min(j0 + w, n);
      let left = 0, v = j0;
      if (j0 === 0) {
        for (; v < end; v++) {
          const z = raw[p0 + v] | (raw[p1 + v] << 8) | (raw[p2 + v] << 16) | (raw[p3 + v] << 24);
          left = (left + ((z >>> 1) ^ -(z & 1))) | 0;
          a[v] = left;
        }
      } else {
        let diag = 0; // a[v - w - 1], 0 at the first column
        for (; v < end; v++) {
          const z = raw[p0 + v] | (raw[p1 + v] << 8) | (raw[p2 + v] << 16) | (raw[p3 + v] << 24);
          const below = a[v - w];
          left = (((z >>> 1) ^ -(z & 1)) + left + below - diag) | 0;
          diag = below;
          a[v] = left;
        }
      }
    }
    if (kind === 0) {
      const o = origin[c];
      for (let v = 0, k = c; v < n; v++, k += 3) {
        const gk = (a[v] + o) | 0;
        g[k] = gk;
        positions[k] = gk * quantum;
      }
    } else {
      const kg = key.g;
      for (let v = 0, k = c; v < n; v++, k += 3) positions[k] = ((kg[k] + a[v]) | 0) * quantum;
    }
  }
  return {
    length: (length + 3) & ~3, keyframe: kind === 0, keyId, keyFrame, quantum,
    newKey: kind === 0 ? { id: keyId, frame: keyFrame, n, quantum, g } : null,
  };
}

// Kinds 2 and 3: three axis blocks. Every block is checked and decompressed before any position
// is written, so a frame that fails changes nothing.
function decodeAxes(bytes, dv, at, n, row, length, positions, options, state, h) {
  const end = at + DELTA_HEAD + length;
  const w = Math.min(row, n);
  // The WebAssembly memory is laid out (grown) for n only once a block has decompressed to its n
  // residuals: a frame that merely claims a large cloth grows nothing.
  let m = options.wasm === false ? (state.inverse = null) : undefined, u8 = null;
  const axes = [];
  let p = at + DELTA_HEAD;
  for (let c = 0; c < 3; c++) {
    if (p + 12 > end) throw new Error(`delta axis ${c} block at byte ${p} runs past the positions (${end})`);
    const basis = bytes[p], escapes = dv.getUint32(p + 4, true), len = dv.getUint32(p + 8, true);
    if (basis > 1 || (basis === 1 && h.isKey)) throw new Error(`delta axis ${c} of basis ${basis} in a ${h.isKey ? 'keyframe' : 'delta'}`);
    if (escapes > n) throw new Error(`delta axis ${c} claims ${escapes} escapes for ${n} vertices`);
    if (p + 12 + len > end) throw new Error(`delta axis ${c} zstd frame of ${len} bytes runs past the positions`);
    const size = n + 4 * escapes;
    const raw = options.zstd.decode(bytes.subarray(p + 12, p + 12 + len), size);
    if (raw.length !== size) throw new Error(`delta axis ${c} values of ${raw.length} bytes, not ${size}`);
    let found;
    if (m === undefined) {
      m = inverse(state, n);
      u8 = m && new Uint8Array(m.memory.buffer);
    }
    if (m) {
      u8.set(raw, m.res[c]);
      found = m.exports.count_escapes(m.res[c], n);
      axes.push({ basis });
    } else {
      const r8 = new Int8Array(raw.buffer, raw.byteOffset, n);
      found = countEscapes(r8);
      axes.push({ basis, r8, esc: new DataView(raw.buffer, raw.byteOffset + n, 4 * escapes) });
    }
    if (found !== escapes) throw new Error(`delta axis ${c} has ${found} escapes, its head says ${escapes}`);
    p += align4(12 + len);
  }
  if (p !== align4(end)) throw new Error(`delta axis blocks end at byte ${p}, the positions at ${align4(end)}`);
  const done = (g) => ({
    length: align4(length), keyframe: h.isKey, keyId: h.keyId, keyFrame: h.keyFrame, quantum: h.quantum,
    newKey: h.isKey ? { id: h.keyId, frame: h.keyFrame, n, quantum: h.quantum, g } : null,
  });
  if (m) {
    // A keyframe's g goes into the slot the held keyframe is not in; a delta reads the held one's
    // (copied in first if it came from the first layout's JavaScript decoder).
    const held = h.key && h.key.slot && h.key.slot.m === m ? h.key.slot.i : -1;
    let slot = held;
    if (h.isKey) slot = held === 0 ? 1 : 0;
    else if (held < 0) {
      slot = 0;
      new Int32Array(m.memory.buffer, m.keys[0], 3 * n).set(h.key.g);
    }
    const onKey = axes.reduce((bits, a, c) => bits | (a.basis << c), 0);
    m.exports.undo(n, w, m.res[0], m.res[1], m.res[2], onKey, h.origin[0], h.origin[1], h.origin[2], h.quantum,
      m.keys[slot], m.pos, m.prev, h.isKey ? 1 : 0);
    positions.set(new Float32Array(m.memory.buffer, m.pos, 3 * n));
    const out = done(null);
    if (out.newKey) wasmKey(out.newKey, m, slot);
    if (!h.isKey && held < 0) wasmKey(h.key, m, 0); // the same values, in slot 0 from now on
    return out;
  }
  // A keyframe's g goes into the array of the keyframe before the one held (kept for this), so
  // that a keyframe a second allocates nothing; the held one is replaced only on success.
  let g = null;
  if (h.isKey) {
    const spare = state.spareG;
    g = spare && spare.length === 3 * n && spare !== (h.key && h.key.g) ? spare : new Int32Array(3 * n);
  }
  const prev = state.rowScratch && state.rowScratch.length >= 3 * w ? state.rowScratch : (state.rowScratch = new Int32Array(3 * w));
  undoAxes(axes, n, w, h.key ? h.key.g : null, h.origin, h.quantum, positions, g, prev);
  return done(g);
}

// The WebAssembly module of delta_inverse.c, compiled once (null where the engine lacks
// WebAssembly or its SIMD).
let wasmModule;
function inverseModule() {
  if (wasmModule === undefined) {
    wasmModule = null;
    try {
      const bin = atob(DELTA_WASM), code = new Uint8Array(bin.length);
      for (let i = 0; i < bin.length; i++) code[i] = bin.charCodeAt(i);
      if (typeof WebAssembly === 'object' && WebAssembly.validate(code)) wasmModule = new WebAssembly.Module(code);
    } catch {
      wasmModule = null;
    }
  }
  return wasmModule;
}

const align16 = (n) => (n + 15) & ~15;

// This decoder's instance of the module, its memory laid out for n vertices or more: two keyframe
// slots (3 n int32 each), the positions (3 n float32), each axis's residuals and escapes (5 n
// bytes at most) and three rows of scratch; null without WebAssembly SIMD. A memory grown for a
// larger cloth moves the regions, so a keyframe held in a slot is copied out to JavaScript first.
function inverse(state, n) {
  let m = state.inverse;
  if (m === undefined) {
    const mod = inverseModule();
    if (!mod) return (state.inverse = null);
    const memory = new WebAssembly.Memory({ initial: 2 });
    const { exports } = new WebAssembly.Instance(mod, { env: { memory } });
    m = state.inverse = { memory, exports, base: align16(exports.__heap_base.value), cap: -1 };
  }
  if (!m || n <= m.cap) return m;
  const cap = Math.max(n, 1024);
  const key = state.key;
  if (key && key.slot && key.slot.m === m) {
    const g = Int32Array.from(key.g);
    delete key.slot;
    Object.defineProperty(key, 'g', { value: g, writable: true, enumerable: true, configurable: true });
  }
  const keys = [m.base, m.base + 12 * cap], pos = m.base + 24 * cap;
  const res = [0, 1, 2].map((c) => pos + 12 * cap + c * align16(5 * cap));
  const prev = res[2] + align16(5 * cap), need = prev + 12 * cap;
  const have = m.memory.buffer.byteLength;
  if (need > have) m.memory.grow(Math.ceil((need - have) / 65536));
  Object.assign(m, { cap, keys, pos, res, prev });
  return m;
}

// A keyframe held in slot i of m: its g is a view of that slot (made anew, as the memory's buffer
// changes when it grows).
function wasmKey(key, m, i) {
  key.slot = { m, i };
  Object.defineProperty(key, 'g', { get: () => new Int32Array(m.memory.buffer, m.keys[i], 3 * key.n), enumerable: true, configurable: true });
}

// How many bytes of r8 are -128 (escapes): four at a time where the bytes are aligned, a word
// with no 0x80 byte skipped at once (the test is exact for "none": x ^ 0x80808080 has a zero byte).
function countEscapes(r8) {
  const n = r8.length;
  let found = 0, v = 0;
  const head = (4 - (r8.byteOffset & 3)) & 3;
  for (; v < head && v < n; v++) if (r8[v] === -128) found++;
  const words = (n - v) >> 2;
  if (words > 0) {
    const u = new Uint32Array(r8.buffer, r8.byteOffset + v, words);
    for (let i = 0; i < words; i++) {
      const x = u[i] ^ 0x80808080;
      if (((x - 0x01010101) & ~x & 0x80808080) !== 0) {
        const at = v + 4 * i;
        for (let b = 0; b < 4; b++) if (r8[at + b] === -128) found++;
      }
    }
    v += 4 * words;
  }
  for (; v < n; v++) if (r8[v] === -128) found++;
  return found;
}

// The positions from the three axes' residuals, vertex by vertex (so positions and the
// keyframe's g are read and written in order): the parallelogram's inverse row by row (prev
// holds the row before, 3 values a vertex; the first row's are 0), plus the keyframe's g (basis
// 1) or the origin (basis 0); g (keyframes) keeps the grid values.
function undoAxes(axes, n, w, keyG, origin, quantum, positions, g, prev) {
  const [ax, ay, az] = axes;
  const rx = ax.r8, ry = ay.r8, rz = az.r8;
  const kx = ax.basis === 1, ky = ay.basis === 1, kz = az.basis === 1;
  const [ox, oy, oz] = origin;
  let ex = 0, ey = 0, ez = 0;
  prev.fill(0);
  for (let j0 = 0; j0 < n; j0 += w) {
    const end = j0 + Math.min(w, n - j0);
    let lx = 0, ly = 0, lz = 0, dx = 0, dy = 0, dz = 0;
    for (let v = j0, i = 0, k = 3 * j0; v < end; v++, i += 3, k += 3) {
      let r = rx[v];
      if (r === -128) r = ax.esc.getInt32(4 * ex++, true);
      let b = prev[i];
      lx = (r + lx + b - dx) | 0;
      dx = b;
      prev[i] = lx;
      r = ry[v];
      if (r === -128) r = ay.esc.getInt32(4 * ey++, true);
      b = prev[i + 1];
      ly = (r + ly + b - dy) | 0;
      dy = b;
      prev[i + 1] = ly;
      r = rz[v];
      if (r === -128) r = az.esc.getInt32(4 * ez++, true);
      b = prev[i + 2];
      lz = (r + lz + b - dz) | 0;
      dz = b;
      prev[i + 2] = lz;
      const gx = ((kx ? keyG[k] : ox) + lx) | 0, gy = ((ky ? keyG[k + 1] : oy) + ly) | 0, gz = ((kz ? keyG[k + 2] : oz) + lz) | 0;
      positions[k] = gx * quantum;
      positions[k + 1] = gy * quantum;
      positions[k + 2] = gz * quantum;
      if (g) {
        g[k] = gx;
        g[k + 1] = gy;
        g[k + 2] = gz;
      }
    }
  }
}
