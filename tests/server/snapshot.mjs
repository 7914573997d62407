// snapshot.mjs - reading and editing snapshots (GET /v1/snapshot) in the tests, from the format
// as kernels/src/snapshot.c documents it: a 32-byte header ("CSNP", u32 version, u64 layout id,
// u64 payload bytes, u64 FNV-1a 64 of the payload), then the engine's parameter table's rows (f64
// per component), u64 step, f64 time, i32 grab, 3 f32 target, u32
// rocks, u32 next rock id, ... An edit keeps the checksum right (this file's own FNV-1a), so only
// the daemon's checks of the content can refuse it.
import { call, ok } from './harness.mjs';

const HEADER = 32;

// FNV-1a 64 of bytes, as a BigInt.
export function fnv1a64(bytes) {
  let h = 0xcbf29ce484222325n;
  for (const b of bytes) h = BigInt.asUintN(64, (h ^ BigInt(b)) * 0x100000001b3n);
  return h;
}

// The offsets of the clock and rock counters. The engine's parameter table comes first in the
// payload: its size is what a snapshot of the daemon's current state has beyond the parts whose
// sizes the format gives (clock and counters 40 bytes, 15 f32 arrays of n, n pins padded to 4
// bytes, 92 bytes a rock). The daemon's own live settings are not in it.
export async function layout(d, headers) {
  const { nx, ny } = await ok(d, 'GET', '/v1/scene', undefined, headers);
  const { rocks } = await ok(d, 'GET', '/v1/rocks', undefined, headers);
  const snap = await call(d, 'GET', '/v1/snapshot', undefined, headers);
  const n = nx * ny;
  const table = Number(snap.buf.readBigUInt64LE(16)) - 40 - 60 * n - Math.ceil(n / 4) * 4 - 92 * rocks.length;
  const clock = HEADER + table;
  return { step: clock, time: clock + 8, grab: clock + 16, rocks: clock + 32, nextId: clock + 36 };
}

// A copy of a snapshot with edits ({offset: [kind, value]}, kind u32, u64 or f64) and its
// checksum fixed.
export function edited(snapshot, edits) {
  const b = Buffer.from(snapshot);
  for (const [off, [kind, v]] of Object.entries(edits)) {
    if (kind === 'u32') b.writeUInt32LE(Number(v), Number(off));
    else if (kind === 'u64') b.writeBigUInt64LE(BigInt(v), Number(off));
    else b.writeDoubleLE(v, Number(off));
  }
  b.writeBigUInt64LE(fnv1a64(b.subarray(HEADER)), 24);
  return b;
}

// The step count of GET /v1/sim's text, exactly (JSON.parse rounds integers past 2^53).
export function exactStep(text) {
  return BigInt(/"step":(-?\d+)/.exec(text)[1]);
}
