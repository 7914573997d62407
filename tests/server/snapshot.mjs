// snapshot.mjs - reading and editing snapshots (GET /v1/snapshot) in the tests, from the format
// as kernels/src/snapshot.c documents it: a 32-byte header ("CSNP", u32 version, u64 layout id,
// u64 payload bytes, u64 FNV-1a 64 of the payload), then the parameter table's rows (f64 per
// component, in GET /v1/params/schema's order), u64 step, f64 time, i32 grab, 3 f32 target, u32
// rocks, u32 next rock id, ... An edit keeps the checksum right (this file's own FNV-1a), so only
// the daemon's checks of the content can refuse it.
import { ok } from './harness.mjs';

const HEADER = 32;

// FNV-1a 64 of bytes, as a BigInt.
export function fnv1a64(bytes) {
  let h = 0xcbf29ce484222325n;
  for (const b of bytes) h = BigInt.asUintN(64, (h ^ BigInt(b)) * 0x100000001b3n);
  return h;
}

// The offsets of the clock and rock counters, from the daemon's parameter table.
export async function layout(d, headers) {
  const { params } = await ok(d, 'GET', '/v1/params/schema', undefined, headers);
  let table = 0;
  for (const p of params) if (p.kind === 'scene' || p.kind === 'live') table += 8 * (p.type === 'vec3' ? 3 : 1);
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
