// frame.test.mjs - unit tests of decodeFrame (proto/frame.mjs) against frames built by hand from
// the "Binary frames" table of proto/PROTOCOL.md, never by an encoder under test: a literal f32
// frame, q16 quantization, a meshopt payload made once with Debian's libmeshoptimizer, the scalar
// section and its padding, caller-supplied arrays, and malformed input.
// Run: node --test tests/web/frame.test.mjs
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { MeshoptDecoder } from 'meshoptimizer';
import { ZSTDDecoder } from 'zstddec';
import { createDecoder, decodeFrame } from '../../proto/frame.mjs';

await MeshoptDecoder.ready;
const zstd = new ZSTDDecoder();
await zstd.init();

// "43 4c // comment" lines -> bytes.
const hex = (s) => Uint8Array.from(s.replace(/\/\/.*$/gm, '').match(/[0-9a-f]{2}/gi).map((b) => parseInt(b, 16)));
const near = (a, b, tol = 1e-6 * Math.max(1, Math.abs(b))) => Math.abs(a - b) <= tol;
const assertNear = (actual, expected, tol) => {
  assert.equal(actual.length, expected.length);
  for (let k = 0; k < expected.length; k++)
    assert.ok(near(actual[k], expected[k], tol), `[${k}]: ${actual[k]} vs ${expected[k]}`);
};

// The 72-byte header, field by field at the offsets of the spec table.
function header({ encoding, scalar = false, frame = 1, step = 2, simTime = 0.5, wallNs = 3n, n, nRocks = 0, min, max }) {
  const dv = new DataView(new ArrayBuffer(72));
  [...'CLF1'].forEach((ch, k) => dv.setUint8(k, ch.charCodeAt(0)));
  dv.setUint16(4, 72, true);
  dv.setUint16(6, encoding | (scalar ? 4 : 0), true);
  dv.setBigUint64(8, BigInt(frame), true);
  dv.setBigUint64(16, BigInt(step), true);
  dv.setFloat64(24, simTime, true);
  dv.setBigUint64(32, wallNs, true);
  dv.setUint32(40, n, true);
  dv.setUint32(44, nRocks, true);
  for (let c = 0; c < 3; c++) dv.setFloat32(48 + 4 * c, min[c], true), dv.setFloat32(60 + 4 * c, max[c], true);
  return new Uint8Array(dv.buffer);
}
// Sections in order, each zero-padded to a 4-byte boundary.
function frameOf(...sections) {
  const out = new Uint8Array(sections.reduce((s, b) => s + ((b.length + 3) & ~3), 0));
  let at = 0;
  for (const b of sections) out.set(b, at), (at += (b.length + 3) & ~3);
  return out;
}
const u16s = (values) => new Uint8Array(Uint16Array.from(values).buffer); // little-endian host
const f32s = (values) => new Uint8Array(Float32Array.from(values).buffer);
const rockBytes = (rocks) => frameOf(...rocks.map((r) => {
  const b = new Uint8Array(36), dv = new DataView(b.buffer);
  dv.setUint32(0, r.id, true);
  [...r.position, r.radius, ...r.orientation].forEach((v, k) => dv.setFloat32(4 + 4 * k, v, true));
  return b;
}));

// A complete f32 frame, 2 vertices + 1 rock, written out byte by byte (132 bytes).
const F32_FRAME = hex(`
  43 4c 46 31                          // 0   magic "CLF1"
  48 00                                // 4   header size 72
  00 00                                // 6   flags: encoding 0 (f32), no scalar
  07 00 00 00 00 00 00 00              // 8   frame 7
  2c 01 00 00 00 00 00 00              // 16  step 300
  00 00 00 00 00 00 f8 3f              // 24  sim_time 1.5 (f64 0x3ff8000000000000)
  15 cd 85 3d fe 9c 97 17              // 32  wall ns 1700000000123456789 (0x17979cfe3d85cd15, > 2^53)
  02 00 00 00                          // 40  n_vertices 2
  01 00 00 00                          // 44  n_rocks 1
  00 00 80 bf 00 00 00 00 00 00 00 3f  // 48  bbox min (-1, 0, 0.5)
  00 00 80 3f 00 00 00 40 00 00 40 3f  // 60  bbox max (1, 2, 0.75)
  00 00 80 bf 00 00 00 00 00 00 40 3f  // 72  vertex 0 (-1, 0, 0.75)
  00 00 80 3e 00 00 00 40 00 00 00 3f  // 84  vertex 1 (0.25, 2, 0.5)
  09 00 00 00                          // 96  rock id 9
  00 00 00 00 00 00 00 bf 00 00 80 40  // 100 position (0, -0.5, 4)
  00 00 80 3e                          // 112 radius 0.25
  00 00 00 3f 00 00 00 bf 00 00 00 3f 00 00 00 3f  // 116 orientation (0.5, -0.5, 0.5, 0.5)
`);                                    // 132 end

test('f32: a literal frame decodes field by field', () => {
  assert.equal(F32_FRAME.length, 132);
  const unaligned = new Uint8Array(3 + 132);
  unaligned.set(F32_FRAME, 3); // a view at an odd byte offset, as a pooled node Buffer may be
  for (const data of [F32_FRAME, F32_FRAME.slice().buffer, unaligned.subarray(3)]) {
    const f = decodeFrame(data);
    assert.equal(f.frame, 7);
    assert.equal(f.step, 300);
    assert.equal(f.simTime, 1.5);
    assert.equal(f.wallNs, 1700000000123456789n);
    assert.equal(f.encoding, 'f32');
    assert.equal(f.nVertices, 2);
    assert.equal(f.nRocks, 1);
    assert.deepEqual(f.bboxMin, [-1, 0, 0.5]);
    assert.deepEqual(f.bboxMax, [1, 2, 0.75]);
    assert.ok(f.positions instanceof Float32Array);
    assert.deepEqual(f.positions, Float32Array.from([-1, 0, 0.75, 0.25, 2, 0.5]));
    assert.equal(f.scalar, null);
    assert.deepEqual(f.rocks, [{ id: 9, position: [0, -0.5, 4], radius: 0.25, orientation: [0.5, -0.5, 0.5, 0.5] }]);
    assert.equal(f.bytes, 132);
  }
  // The same frame from the DataView helper: the helper follows the table too.
  const built = frameOf(header({ encoding: 0, frame: 7, step: 300, simTime: 1.5, wallNs: 1700000000123456789n,
    n: 2, nRocks: 1, min: [-1, 0, 0.5], max: [1, 2, 0.75] }), f32s([-1, 0, 0.75, 0.25, 2, 0.5]),
  rockBytes([{ id: 9, position: [0, -0.5, 4], radius: 0.25, orientation: [0.5, -0.5, 0.5, 0.5] }]));
  assert.deepEqual(built, F32_FRAME);
});

test('q16: hand-quantized values, a flat axis, and the half-step bound', () => {
  // x in 0..10, y in -1..1, z flat at 2: (2.5, 0.3, 2) and (10, -1, 2).
  // x: 2.5/10*65535 = 16383.75 -> 16384; y: 1.3/2*65535 = 42597.75 -> 42598; z: flat -> 0.
  const min = [0, -1, 2], max = [10, 1, 2];
  const q = [16384, 42598, 0, 65535, 0, 0];
  const f = decodeFrame(frameOf(header({ encoding: 1, n: 2, min, max }), u16s(q)));
  assert.equal(f.encoding, 'q16');
  assert.equal(f.bytes, 72 + 12);
  assertNear(f.positions, q.map((v, k) => (max[k % 3] - min[k % 3] >= 1e-9 ? min[k % 3] + v * (max[k % 3] - min[k % 3]) / 65535 : min[k % 3])));
  assertNear(f.positions, [2.5, 0.3, 2, 10, -1, 2], 10 / 65535 / 2 + 1e-6);
  assert.equal(f.positions[2], 2); // flat axis: exactly min
  // An extent below 1e-9 m (but not 0) is flat too.
  const tiny = decodeFrame(frameOf(header({ encoding: 1, n: 1, min: [0, 0, 0], max: [5e-10, 1, 1] }), u16s([0, 0, 65535])));
  assert.deepEqual(tiny.positions, Float32Array.from([0, 0, 1]));

  // Property: random positions in a bbox, quantized per the spec formula, decode to within half a step.
  let seed = 12345; // mulberry32
  const rand = () => { seed = (seed + 0x6d2b79f5) | 0; let t = Math.imul(seed ^ (seed >>> 15), 1 | seed);
    t = (t + Math.imul(t ^ (t >>> 7), 61 | t)) ^ t; return ((t ^ (t >>> 14)) >>> 0) / 4294967296; };
  const bmin = [-3.2, 0.1, -0.7].map(Math.fround), bmax = [4.9, 2.6, 0.3].map(Math.fround);
  const n = 1000, xs = [], qs = [];
  for (let k = 0; k < 3 * n; k++) {
    const c = k % 3, x = Math.fround(bmin[c] + rand() * (bmax[c] - bmin[c]));
    xs.push(x);
    qs.push(Math.round((x - bmin[c]) / (bmax[c] - bmin[c]) * 65535));
  }
  const g = decodeFrame(frameOf(header({ encoding: 1, n, min: bmin, max: bmax }), u16s(qs)));
  for (let k = 0; k < 3 * n; k++) {
    const c = k % 3, half = (bmax[c] - bmin[c]) / 65535 / 2;
    assert.ok(Math.abs(g.positions[k] - xs[k]) <= half + 1e-6, `[${k}] ${g.positions[k]} vs ${xs[k]}`);
  }
});

// MESHOPT_Q (5 vertices, x, y, z, 0 as uint16_t q[5][4]) encoded once by a small C program
// against Debian's libmeshoptimizer 0.18 (gcc enc.c -lmeshoptimizer -lstdc++ -lm):
//   meshopt_encodeVertexVersion(0); len = meshopt_encodeVertexBuffer(out, 256, q, 5, 8);
// which gave 82 bytes, printed with printf("%02x") and pasted here.
const MESHOPT_Q = [0, 0, 65535, 0, 65535, 32768, 0, 0, 1000, 65535, 300, 0, 12345, 54321, 40000, 0, 65535, 0, 7, 0];
const MESHOPT_BYTES = hex(`
  a0011fc000002da273011fc00000085a610107c000006461013fc00000fffe5558012fc00000582871012bc00000c9c8
  000000000000000000000000000000000000000000000000000000000000ffff0000
`);

test('meshopt: libmeshoptimizer bytes decode to the dequantized q16 values', () => {
  assert.equal(MESHOPT_BYTES.length, 82);
  const min = [-2, 0, 1], max = [2, 3, 1.5];
  const len = new Uint8Array(4);
  new DataView(len.buffer).setUint32(0, MESHOPT_BYTES.length, true);
  const data = frameOf(header({ encoding: 2, n: 5, nRocks: 1, min, max }), frameOf(len, MESHOPT_BYTES),
    rockBytes([{ id: 1, position: [1, 2, 3], radius: 0.5, orientation: [0, 0, 0, 1] }]));
  assert.equal(data.length, 72 + 88 + 36); // 4 + 82 = 86 bytes, padded to 88
  const f = decodeFrame(data, { meshopt: MeshoptDecoder });
  assert.equal(f.encoding, 'meshopt');
  assert.equal(f.nVertices, 5);
  const expected = [];
  for (let v = 0; v < 5; v++)
    for (let c = 0; c < 3; c++) expected.push(min[c] + MESHOPT_Q[4 * v + c] * (max[c] - min[c]) / 65535);
  assertNear(f.positions, expected);
  assert.deepEqual(f.rocks, [{ id: 1, position: [1, 2, 3], radius: 0.5, orientation: [0, 0, 0, 1] }]);
  assert.throws(() => decodeFrame(data), /meshopt/);
});

test('scalar section: padded to 4 bytes, rocks after it', () => {
  const rock = { id: 42, position: [0.5, 1, -1], radius: 2, orientation: [0, 1, 0, 0] };
  const min = [0, 0, 0], max = [1, 1, 1];
  // f32: positions 72..108, scalar 108..111, 1 pad byte, rock at 112.
  // q16: positions 72..90, 2 pad bytes, scalar 92..95, 1 pad byte, rock at 96.
  for (const [encoding, positions, rockAt] of [[0, f32s([0, 0, 0, 1, 1, 1, 0.5, 0.25, 0]), 112],
    [1, u16s([0, 0, 0, 65535, 65535, 65535, 0, 0, 0]), 96]]) {
    const data = frameOf(header({ encoding, scalar: true, n: 3, nRocks: 1, min, max }), positions,
      Uint8Array.from([0, 128, 255]), rockBytes([rock]));
    assert.equal(data.length, rockAt + 36);
    assert.equal(new DataView(data.buffer).getUint32(rockAt, true), 42);
    const f = decodeFrame(data);
    assert.deepEqual(f.scalar, Uint8Array.from([0, 128, 255]));
    assert.deepEqual(f.rocks, [rock]);
    assert.equal(f.positions[3], 1);
  }
});

test('caller arrays: used in place when large enough, left alone when too small', () => {
  const data = frameOf(header({ encoding: 0, scalar: true, n: 2, min: [0, 0, 0], max: [1, 1, 1] }),
    f32s([1, 2, 3, 4, 5, 6]), Uint8Array.from([7, 9]));
  const positions = new Float32Array(10).fill(-1), scalar = new Uint8Array(4).fill(99);
  const f = decodeFrame(data, { positions, scalar });
  assert.equal(f.positions.buffer, positions.buffer);
  assert.equal(f.scalar.buffer, scalar.buffer);
  assert.deepEqual(f.positions, Float32Array.from([1, 2, 3, 4, 5, 6]));
  assert.deepEqual(f.scalar, Uint8Array.from([7, 9]));
  assert.deepEqual(positions, Float32Array.from([1, 2, 3, 4, 5, 6, -1, -1, -1, -1]));
  assert.deepEqual(scalar, Uint8Array.from([7, 9, 99, 99]));
  const exact = new Float32Array(6), exactScalar = new Uint8Array(2); // exactly large enough
  const e = decodeFrame(data, { positions: exact, scalar: exactScalar });
  assert.equal(e.positions.buffer, exact.buffer);
  assert.equal(e.scalar.buffer, exactScalar.buffer);
  assert.deepEqual(exact, Float32Array.from([1, 2, 3, 4, 5, 6]));

  const small = new Float32Array(5).fill(-1), smallScalar = new Uint8Array(1).fill(99);
  const g = decodeFrame(data, { positions: small, scalar: smallScalar });
  assert.notEqual(g.positions.buffer, small.buffer);
  assert.notEqual(g.scalar.buffer, smallScalar.buffer);
  assert.deepEqual(g.positions, Float32Array.from([1, 2, 3, 4, 5, 6]));
  assert.deepEqual(small, new Float32Array(5).fill(-1));
  assert.deepEqual(smallScalar, Uint8Array.from([99]));
});

test('bad input throws a clear Error', () => {
  assert.throws(() => decodeFrame(F32_FRAME.subarray(0, 71)), { name: 'Error', message: /71 bytes.*header/ });
  assert.throws(() => decodeFrame(new Uint8Array(0)), { name: 'Error', message: /header/ });
  const magic = F32_FRAME.slice();
  magic[3] = 0x32; // "CLF2"
  assert.throws(() => decodeFrame(magic), { name: 'Error', message: /magic/ });
  const enc3 = F32_FRAME.slice();
  enc3[6] = 3;
  assert.throws(() => decodeFrame(enc3), { name: 'Error', message: /createDecoder/ });
  // a reserved flag bit (bit 3: a fifth encoding's, later; bit 15): refused, not misread as f32
  for (const bit of [3, 15]) {
    const reserved = F32_FRAME.slice();
    reserved[6 + (bit >> 3)] |= 1 << (bit & 7);
    assert.throws(() => decodeFrame(reserved), { name: 'Error', message: /flags 0x[0-9a-f]+ set bits/ });
  }
  const trailing = new Uint8Array(136);
  trailing.set(F32_FRAME);
  assert.throws(() => decodeFrame(trailing), { name: 'Error', message: /136 bytes/ });
});

// A short payload is refused by the length checks before any read past the end (which would be a
// bare RangeError), and a frame claiming more vertices than any cloth has allocates nothing.
test('truncated payload throws a clear Error', () => {
  for (const cut of [1, 36, 60])
    assert.throws(() => decodeFrame(F32_FRAME.subarray(0, 132 - cut)), { name: 'Error', message: /truncated/ });
  const huge = F32_FRAME.slice();
  new DataView(huge.buffer).setUint32(40, 0xffffffff, true);
  assert.throws(() => decodeFrame(huge), { name: 'Error', message: /more than/ });
});

// The delta section's head (clothd_frame.h), then the zstd frame of the byte planes.
function deltaSection({ kind, keyId, keyFrame, quantum, origin, row, zstdBytes }) {
  const dv = new DataView(new ArrayBuffer(44));
  dv.setUint32(0, kind, true);
  dv.setUint32(4, keyId, true);
  dv.setBigUint64(8, BigInt(keyFrame), true);
  dv.setFloat64(16, quantum, true);
  origin.forEach((o, c) => dv.setInt32(24 + 4 * c, o, true));
  dv.setUint32(36, row, true);
  dv.setUint32(40, zstdBytes.length, true);
  return frameOf(new Uint8Array(dv.buffer), zstdBytes);
}
// A 2 x 2 cloth on a 0.5 m grid, worked out by hand from the layout (as in
// tests/server/unit/test_delta.c): keyframe g = (2,4,0) (4,4,0) (2,6,1) (5,6,-2), origin (2,4,-2),
// zigzagged residuals x (0,4,0,2), y (0,0,4,0), z (4,0,2,5); the delta moves v0 +1 on x and v3 -2
// on z: residuals x (2,1,1,2), z (0,0,0,3). The 48 bytes of planes of each were compressed once
// with the zstd command line (zstd -1 --no-check) and pasted here.
const KEY_ZSTD = hex('28b52ffd2030ad00006000040002000400040002050003100086e6f0a105');
const DELTA_ZSTD = hex('28b52ffd20307d000038020101020003000200c0c022d002');
const deltaFrame = (section, frame) => frameOf(header({ encoding: 3, frame, n: 4, min: [0, 0, 0], max: [1, 1, 1] }), section);
const KEY_FRAME = deltaFrame(deltaSection({ kind: 0, keyId: 1, keyFrame: 77, quantum: 0.5, origin: [2, 4, -2], row: 2, zstdBytes: KEY_ZSTD }), 77);
const DELTA_FRAME = deltaFrame(deltaSection({ kind: 1, keyId: 1, keyFrame: 77, quantum: 0.5, origin: [2, 4, -2], row: 2, zstdBytes: DELTA_ZSTD }), 78);

test('delta: a keyframe and a delta worked out by hand', () => {
  const d = createDecoder({ zstd });
  assert.equal(d.keyframe(), null);
  assert.throws(() => d.decode(DELTA_FRAME), { name: 'Error', message: /holds no keyframe/ });
  const k = d.decode(KEY_FRAME);
  assert.equal(k.encoding, 'delta');
  assert.deepEqual(k.delta, { keyframe: true, keyId: 1, keyFrame: 77, quantum: 0.5 });
  assert.deepEqual(k.positions, Float32Array.from([1, 2, 0, 2, 2, 0, 1, 3, 0.5, 2.5, 3, -1]));
  assert.equal(k.bytes, 72 + 44 + 32); // 30 zstd bytes padded to 32
  const f = d.decode(DELTA_FRAME);
  assert.deepEqual(f.delta, { keyframe: false, keyId: 1, keyFrame: 77, quantum: 0.5 });
  assert.equal(f.frame, 78);
  assert.deepEqual(f.positions, Float32Array.from([1.5, 2, 0, 2, 2, 0, 1, 3, 0.5, 2.5, 3, -2]));
  // Any number of deltas decode with the keyframe alone (the same delta again, as after skips).
  assert.deepEqual(d.decode(DELTA_FRAME).positions, f.positions);
  assert.deepEqual(d.keyframe(), { id: 1, frame: 77, quantum: 0.5, nVertices: 4 });
  // The stateless decoder and a decoder without zstd refuse clearly.
  assert.throws(() => decodeFrame(KEY_FRAME), { name: 'Error', message: /createDecoder/ });
  assert.throws(() => createDecoder().decode(KEY_FRAME), { name: 'Error', message: /zstd/ });
  // createDecoder decodes the other encodings too.
  assert.deepEqual(d.decode(F32_FRAME).positions, Float32Array.from([-1, 0, 0.75, 0.25, 2, 0.5]));
});

test('delta: a delta of another keyframe, or broken, throws and leaves the keyframe', () => {
  const d = createDecoder({ zstd });
  d.decode(KEY_FRAME);
  const other = deltaFrame(deltaSection({ kind: 1, keyId: 2, keyFrame: 90, quantum: 0.5, origin: [2, 4, -2], row: 2, zstdBytes: DELTA_ZSTD }), 91);
  assert.throws(() => d.decode(other), { name: 'Error', message: /keyframe 2 \(frame 90\).*holds keyframe 1/ });
  const quantum = deltaFrame(deltaSection({ kind: 1, keyId: 1, keyFrame: 77, quantum: 0.25, origin: [2, 4, -2], row: 2, zstdBytes: DELTA_ZSTD }), 78);
  assert.throws(() => d.decode(quantum), { name: 'Error', message: /holds keyframe 1/ });
  // A keyframe whose frame is broken after its positions (trailing bytes) does not replace the one held.
  const broken = new Uint8Array(KEY_FRAME.length + 4);
  broken.set(deltaFrame(deltaSection({ kind: 0, keyId: 5, keyFrame: 99, quantum: 0.5, origin: [0, 0, 0], row: 2, zstdBytes: KEY_ZSTD }), 99));
  assert.throws(() => d.decode(broken), { name: 'Error', message: /bytes/ });
  assert.equal(d.keyframe().id, 1);
  assert.throws(() => d.decode(KEY_FRAME.subarray(0, 72 + 40)), { name: 'Error', message: /truncated/ });
  assert.throws(() => d.decode(KEY_FRAME.subarray(0, KEY_FRAME.length - 8)), { name: 'Error', message: /truncated/ });
  const kind = KEY_FRAME.slice();
  kind[72] = 4;
  assert.throws(() => d.decode(kind), { name: 'Error', message: /kind 4/ });
  const nan = KEY_FRAME.slice();
  new DataView(nan.buffer).setFloat64(72 + 16, NaN, true);
  assert.throws(() => d.decode(nan), { name: 'Error', message: /quantum/ });
  const row0 = KEY_FRAME.slice();
  new DataView(row0.buffer).setUint32(72 + 36, 0, true);
  assert.throws(() => d.decode(row0), { name: 'Error', message: /row/ });
  // A zstd frame of the wrong size (the delta of 4 vertices in a frame that claims 3).
  const short = frameOf(header({ encoding: 3, n: 3, min: [0, 0, 0], max: [1, 1, 1] }),
    deltaSection({ kind: 0, keyId: 1, keyFrame: 1, quantum: 0.5, origin: [0, 0, 0], row: 2, zstdBytes: KEY_ZSTD }));
  assert.throws(() => d.decode(short), { name: 'Error', message: /delta values/ });
  assert.equal(d.keyframe().id, 1);
});

// The same cloth in the layout of kinds 2 and 3 (clothd_frame.h): an axis block per axis (basis
// u8, 3 zero, escapes u32, byte count u32, one zstd frame of n int8 residuals then the int32
// escapes), padded to 4. Keyframe residuals x (0,2,0,1), y (0,0,2,0), z (2,0,1,-3). The delta: x
// on the keyframe (basis 1), residuals (1,-1,-1,1), v0 +1; y on the origin (basis 0), a = g - 4 =
// (0,0,2,2), residuals (0,0,2,0); z on the keyframe, v3 -200 (g -202): residual -200, an escape
// (byte -128 then the int32). zstd frames made once with the zstd command line (zstd -1 --no-check).
function axisBlock(basis, escapes, zframe) {
  const head = new DataView(new ArrayBuffer(12));
  head.setUint8(0, basis);
  head.setUint32(4, escapes, true);
  head.setUint32(8, zframe.length, true);
  return frameOf(new Uint8Array(head.buffer), zframe);
}
const KEY2 = deltaFrame(deltaSection({ kind: 2, keyId: 1, keyFrame: 77, quantum: 0.5, origin: [2, 4, -2], row: 2, zstdBytes: frameOf(
  axisBlock(0, 0, hex('28b52ffd200421000000020001')), axisBlock(0, 0, hex('28b52ffd200421000000000200')),
  axisBlock(0, 0, hex('28b52ffd2004210000020001fd'))) }), 77);
const DELTA2 = deltaFrame(deltaSection({ kind: 3, keyId: 1, keyFrame: 77, quantum: 0.5, origin: [2, 4, -2], row: 2, zstdBytes: frameOf(
  axisBlock(1, 0, hex('28b52ffd200421000001ffff01')), axisBlock(0, 0, hex('28b52ffd200421000000000200')),
  axisBlock(1, 1, hex('28b52ffd20084100000000008038ffffff'))) }), 78);

// Kinds 2 and 3 are decoded by WebAssembly (delta_inverse.c) and, with { wasm: false }, by
// frame.mjs's JavaScript: every test of them runs on both.
const PATHS = [['WebAssembly', true], ['JavaScript', false]];

for (const [path, wasm] of PATHS) {
test(`delta (${path}): axis blocks (kinds 2 and 3) worked out by hand, escapes and mixed bases`, () => {
  const d = createDecoder({ zstd, wasm });
  const k = d.decode(KEY2);
  assert.equal(d.wasm(), wasm);
  assert.deepEqual(k.delta, { keyframe: true, keyId: 1, keyFrame: 77, quantum: 0.5 });
  assert.deepEqual(k.positions, Float32Array.from([1, 2, 0, 2, 2, 0, 1, 3, 0.5, 2.5, 3, -1]));
  assert.equal(k.bytes, 72 + 44 + 3 * 28); // each block: 12 + 13 zstd bytes, padded to 28
  for (let i = 0; i < 2; i++) {
    const f = d.decode(DELTA2);
    assert.deepEqual(f.delta, { keyframe: false, keyId: 1, keyFrame: 77, quantum: 0.5 });
    assert.deepEqual(f.positions, Float32Array.from([1.5, 2, 0, 2, 2, 0, 1, 3, 0.5, 2.5, 3, -101]));
  }
  // A keyframe of the first, byte-plane layout is held alike.
  d.decode(KEY_FRAME);
  assert.equal(d.decode(DELTA2).positions[11], -101);
});

test(`delta (${path}): broken axis blocks throw and change neither the keyframe nor the positions`, () => {
  const positions = new Float32Array(12);
  const d = createDecoder({ zstd, positions, wasm });
  d.decode(KEY2);
  const held = positions.slice();
  const at = 72 + 44;
  const cases = [
    [(b) => { b[at] = 1; }, /basis 1 in a keyframe/, KEY2],
    [(b) => { b[at] = 2; }, /basis 2/, DELTA2],
    [(b) => new DataView(b.buffer).setUint32(at + 4, 5, true), /5 escapes for 4 vertices/, DELTA2],
    [(b) => new DataView(b.buffer).setUint32(at + 56 + 4, 0, true), /values|zstd|escape/i, DELTA2],
    [(b) => new DataView(b.buffer).setUint32(at + 8, 200, true), /runs past/, DELTA2],
    [(b) => new DataView(b.buffer).setUint32(72 + 40, 3 * 28 - 8, true), /runs past|end at/, DELTA2],
  ];
  for (const [spoil, message, frame] of cases) {
    const b = frame.slice();
    spoil(b);
    assert.throws(() => d.decode(b), { name: 'Error', message });
    assert.deepEqual(positions, held);
    assert.equal(d.keyframe().id, 1);
  }
  assert.equal(d.decode(DELTA2).positions[11], -101);
});
}

// A zstd frame of raw blocks (RFC 8878: magic, a frame header of a single segment and a 4-byte
// content size, then blocks of at most 128 KiB, each a 3-byte header - last flag, type 0 raw,
// size - and its bytes as they are): any residuals, compressed by no encoder under test.
function zstdRaw(data) {
  const MAX = 1 << 17, parts = Math.max(1, Math.ceil(data.length / MAX));
  const out = new Uint8Array(9 + 3 * parts + data.length);
  out.set([0x28, 0xb5, 0x2f, 0xfd, 0xa0]);
  new DataView(out.buffer).setUint32(5, data.length, true);
  let at = 9;
  for (let i = 0; i < parts; i++) {
    const chunk = data.subarray(i * MAX, Math.min(data.length, (i + 1) * MAX));
    const h = (i === parts - 1 ? 1 : 0) | (chunk.length << 3);
    out.set([h & 255, (h >> 8) & 255, (h >> 16) & 255], at);
    out.set(chunk, at + 3);
    at += 3 + chunk.length;
  }
  return out;
}

// A deterministic generator (xorshift32), so that a failure is the same on every run.
function random(seed) {
  let x = seed >>> 0 || 1;
  return () => {
    x ^= x << 13; x >>>= 0;
    x ^= x >>> 17;
    x ^= x << 5; x >>>= 0;
    return x / 2 ** 32;
  };
}

// One delta frame of n vertices in rows of `row` from each axis's residuals (int32, any) and
// bases, with the grid values it decodes to by the spec, worked here in plain arithmetic: a =
// r + left + below - below-left (0 past the first row and column), g = a + origin (basis 0) or
// a + the keyframe's g (basis 1), mod 2^32.
function synthetic({ n, row, kind, keyId, keyFrame = 10 * keyId, quantum, origin, bases, r, keyG, frame = 1, trailing = 0 }) {
  const blocks = [], g = new Int32Array(3 * n);
  for (let c = 0; c < 3; c++) {
    const bytes = [], escapes = [];
    for (let v = 0; v < n; v++) {
      const x = r[c][v];
      if (x > -128 && x <= 127) bytes.push(x & 255);
      else bytes.push(0x80), escapes.push(x);
    }
    const raw = new Uint8Array(n + 4 * escapes.length);
    raw.set(bytes);
    escapes.forEach((e, i) => new DataView(raw.buffer).setInt32(n + 4 * i, e, true));
    blocks.push(axisBlock(bases[c], escapes.length, zstdRaw(raw)));
    const a = new Int32Array(n);
    for (let v = 0; v < n; v++) {
      const i = v % row, left = i > 0 ? a[v - 1] : 0, below = v >= row ? a[v - row] : 0;
      const diag = i > 0 && v >= row ? a[v - row - 1] : 0;
      a[v] = (r[c][v] + left + below - diag) | 0;
      g[3 * v + c] = (a[v] + (bases[c] ? keyG[3 * v + c] : origin[c])) | 0;
    }
  }
  const body = frameOf(header({ encoding: 3, frame, n, min: [0, 0, 0], max: [1, 1, 1] }),
    deltaSection({ kind, keyId, keyFrame, quantum, origin, row, zstdBytes: frameOf(...blocks) }));
  const bytes = new Uint8Array(body.length + trailing);
  bytes.set(body);
  return { bytes, g, positions: Float32Array.from(g, (v) => v * quantum) };
}

// Residuals for one axis: mostly small, some past int8 (escapes: a run of them, some anywhere,
// some at int32's ends so that the sums wrap).
function residuals(rnd, n) {
  const r = new Int32Array(n);
  for (let v = 0; v < n; v++) {
    const u = rnd();
    r[v] = u < 0.9 ? Math.round((rnd() - 0.5) * 40) : u < 0.96 ? Math.round((rnd() - 0.5) * 254)
      : u < 0.98 ? Math.round((rnd() - 0.5) * 2e5) : rnd() < 0.5 ? -128 : (rnd() < 0.5 ? 2 ** 31 - 1 : -(2 ** 31));
  }
  for (let v = Math.floor(n / 3); v < Math.min(n, Math.floor(n / 3) + 20); v++) r[v] = 1000 + v;
  return r;
}

for (const [path, wasm] of PATHS) {
  test(`delta (${path}): random residuals and escapes on cloths of many shapes decode to the spec's grid values`, () => {
    const rnd = random(7);
    // Rows of 1 to 257 vertices, a last row short or whole, widths on and off SIMD's 4 and 16.
    const shapes = [[1, 1], [4, 2], [7, 7], [12, 3], [50, 7], [33 * 33, 33], [64 * 64, 64], [100 * 37 + 5, 37], [257 * 3, 257]];
    for (const [n, row] of shapes) {
      const positions = new Float32Array(3 * n);
      const d = createDecoder({ zstd, wasm, positions });
      const origin = [Math.round((rnd() - 0.5) * 4e4), -17, 2 ** 31 - 5];
      const quantum = rnd() < 0.5 ? 1e-4 : 0.5;
      const key = synthetic({ n, row, kind: 2, keyId: 1, quantum, origin, bases: [0, 0, 0], r: [0, 1, 2].map(() => residuals(rnd, n)) });
      assert.deepEqual(d.decode(key.bytes).positions, key.positions, `keyframe ${n} / ${row}`);
      assert.equal(d.wasm(), wasm);
      let held = key;
      for (let f = 0; f < 6; f++) {
        const r = [0, 1, 2].map(() => residuals(rnd, n));
        if (f === 3) { // a new keyframe while one is held (the other slot), then deltas of it
          held = synthetic({ n, row, kind: 2, keyId: 2, quantum, origin, bases: [0, 0, 0], r });
          assert.deepEqual(d.decode(held.bytes).positions, held.positions);
          continue;
        }
        const bases = [0, 1, 2].map(() => (rnd() < 0.5 ? 1 : 0));
        const delta = synthetic({ n, row, kind: 3, keyId: held === key ? 1 : 2, quantum, origin, bases, r, keyG: held.g, frame: 2 + f });
        assert.deepEqual(d.decode(delta.bytes).positions, delta.positions, `delta ${f} of ${n} / ${row}, bases ${bases}`);
        assert.deepEqual(d.decode(delta.bytes).positions, delta.positions); // the same again: the keyframe alone
      }
    }
  });

  test(`delta (${path}): a keyframe broken after its positions, or of a larger cloth, leaves the one held`, () => {
    const rnd = random(11), n = 40, row = 8, quantum = 0.25, origin = [3, -4, 5];
    const d = createDecoder({ zstd, wasm });
    const key = synthetic({ n, row, kind: 2, keyId: 1, quantum, origin, bases: [0, 0, 0], r: [0, 1, 2].map(() => residuals(rnd, n)) });
    d.decode(key.bytes);
    const r = [0, 1, 2].map(() => residuals(rnd, n));
    const delta = synthetic({ n, row, kind: 3, keyId: 1, quantum, origin, bases: [1, 0, 1], r, keyG: key.g, frame: 9 });
    // A keyframe with 4 bytes after its sections: it decodes into the other slot, then fails.
    const broken = synthetic({ n, row, kind: 2, keyId: 5, quantum, origin, bases: [0, 0, 0], r: [0, 1, 2].map(() => residuals(rnd, n)), trailing: 4 });
    assert.throws(() => d.decode(broken.bytes), { name: 'Error', message: /bytes/ });
    assert.equal(d.keyframe().id, 1);
    assert.deepEqual(d.decode(delta.bytes).positions, delta.positions);
    // A keyframe of 5,000 vertices (a memory grown, the held keyframe moved), broken alike.
    const big = synthetic({ n: 5000, row: 50, kind: 2, keyId: 6, quantum, origin, bases: [0, 0, 0], r: [0, 1, 2].map(() => residuals(rnd, 5000)), trailing: 4 });
    assert.throws(() => d.decode(big.bytes), { name: 'Error', message: /bytes/ });
    assert.deepEqual(d.keyframe(), { id: 1, frame: 10, quantum, nVertices: n });
    assert.deepEqual(d.decode(delta.bytes).positions, delta.positions);
    // Then that cloth whole: its deltas decode, and the small one's no longer do.
    big.bytes = big.bytes.subarray(0, big.bytes.length - 4);
    assert.deepEqual(d.decode(big.bytes).positions, big.positions);
    const bigDelta = synthetic({ n: 5000, row: 50, kind: 3, keyId: 6, quantum, origin, bases: [1, 1, 0], r: [0, 1, 2].map(() => residuals(rnd, 5000)), keyG: big.g, frame: 70 });
    assert.deepEqual(d.decode(bigDelta.bytes).positions, bigDelta.positions);
    assert.throws(() => d.decode(delta.bytes), { name: 'Error', message: /holds keyframe 6/ });
  });
}

test('delta: WebAssembly and JavaScript take the first layout\'s keyframe alike', () => {
  // A kinds-0 keyframe is held in JavaScript; a kind-3 delta of it copies it into WebAssembly.
  for (const [, wasm] of PATHS) {
    const d = createDecoder({ zstd, wasm });
    d.decode(KEY_FRAME);
    for (let i = 0; i < 2; i++) assert.deepEqual(d.decode(DELTA2).positions, Float32Array.from([1.5, 2, 0, 2, 2, 0, 1, 3, 0.5, 2.5, 3, -101]));
    assert.deepEqual(d.decode(DELTA_FRAME).positions, Float32Array.from([1.5, 2, 0, 2, 2, 0, 1, 3, 0.5, 2.5, 3, -2]));
  }
});

for (const [path, wasm] of PATHS) {
  test(`delta (${path}): random corruption of a delta throws an Error or decodes, and never changes the keyframe`, () => {
    const rnd = random(23), n = 33 * 20, row = 33, quantum = 1e-3, origin = [100, -200, 300];
    const key = synthetic({ n, row, kind: 2, keyId: 1, quantum, origin, bases: [0, 0, 0], r: [0, 1, 2].map(() => residuals(rnd, n)) });
    const good = synthetic({ n, row, kind: 3, keyId: 1, quantum, origin, bases: [1, 0, 1], r: [0, 1, 2].map(() => residuals(rnd, n)), keyG: key.g, frame: 5 });
    const d = createDecoder({ zstd, wasm });
    d.decode(key.bytes);
    let threw = 0, decoded = 0;
    for (let t = 0; t < 400; t++) {
      const bad = good.bytes.slice();
      // 1-4 bytes anywhere in the positions section (heads, zstd frames, residuals), or a cut.
      if (t % 10 === 9) {
        const cut = bad.subarray(0, 72 + Math.floor(rnd() * (bad.length - 72)));
        assert.throws(() => d.decode(cut), Error);
        threw++;
      } else {
        for (let k = 1 + Math.floor(rnd() * 4); k > 0; k--) bad[72 + Math.floor(rnd() * (bad.length - 72))] = Math.floor(rnd() * 256);
        try {
          d.decode(bad);
          decoded++;
        } catch (e) {
          assert.ok(e instanceof Error, `threw ${e}`);
          threw++;
        }
      }
      if (t % 20 === 0) assert.deepEqual(d.decode(good.bytes).positions, good.positions, `after corruption ${t}`);
    }
    assert.ok(threw > 40 && decoded > 40, `threw ${threw}, decoded ${decoded}`);
    assert.equal(d.keyframe().id, 1);
    assert.deepEqual(d.decode(good.bytes).positions, good.positions);
  });
}
