// frame.mjs - decodes the binary frames of the clothd stream (layout in clothd_frame.h and
// PROTOCOL.md), in the browser and in node. No dependencies: meshopt frames need the decoder of
// the npm package `meshoptimizer`, passed in (`import { MeshoptDecoder } from 'meshoptimizer';
// await MeshoptDecoder.ready; decodeFrame(data, { meshopt: MeshoptDecoder })`).
//
// A viewer decoding 60 frames a second passes its own arrays (options.positions, .scalar,
// .scratch), which are used when large enough: nothing is allocated per frame then but the
// result object.

export const MAGIC = 'CLF1';
export const HEADER_SIZE = 72;
export const ENCODINGS = ['f32', 'q16', 'meshopt'];
export const ROCK_SIZE = 36;
export const MESHOPT_STRIDE = 8;
export const FLAG_SCALAR = 4;
/** The most vertices a frame may claim: clothd's largest cloth, 4096 x 4096. */
export const MAX_VERTICES = 4096 * 4096;

const align4 = (n) => (n + 3) & ~3;

/**
 * @param {ArrayBuffer|ArrayBufferView} data one binary message
 * @param {{meshopt?: {decodeVertexBuffer: Function}, positions?: Float32Array, scalar?: Uint8Array,
 *   scratch?: Uint8Array}} [options] the decoder for meshopt frames; arrays to decode into
 * @returns {{frame: number, step: number, simTime: number, wallNs: bigint, encoding: string,
 *   nVertices: number, nRocks: number, bboxMin: number[], bboxMax: number[],
 *   positions: Float32Array, scalar: Uint8Array|null, bytes: number,
 *   rocks: {id: number, position: number[], radius: number, orientation: number[]}[]}}
 */
export function decodeFrame(data, options = {}) {
  const bytes = data instanceof ArrayBuffer ? new Uint8Array(data)
    : new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  if (bytes.length < HEADER_SIZE) throw new Error(`frame of ${bytes.length} bytes is shorter than its header`);
  const magic = String.fromCharCode(bytes[0], bytes[1], bytes[2], bytes[3]);
  if (magic !== MAGIC) throw new Error(`not a clothd frame (magic ${JSON.stringify(magic)})`);
  const headerSize = dv.getUint16(4, true);
  const flags = dv.getUint16(6, true);
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
  need(encoding === 'f32' ? 12 * n : encoding === 'q16' ? 6 * n : 4, 'positions');
  const positions = reuse(options.positions, 3 * n, Float32Array);

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
  return {
    frame: Number(dv.getBigUint64(8, true)),
    step: Number(dv.getBigUint64(16, true)),
    simTime: dv.getFloat64(24, true),
    wallNs: dv.getBigUint64(32, true),
    encoding, nVertices: n, nRocks, bboxMin, bboxMax, positions, scalar, rocks, bytes: bytes.length,
  };
}
