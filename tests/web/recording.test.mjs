// recording.test.mjs - unit tests of proto/recording.mjs against recordings written out byte by
// byte from PROTOCOL.md's "Recordings" tables (never by the writer under test): a finished file
// read through its index, the same file cut at every length (scanned up to its last complete
// record), buildRecording's bytes equal to the literal, seek, and corrupt files refused with a
// message naming where.
// Run: node --test tests/web/recording.test.mjs
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { ZSTDDecoder } from 'zstddec';
import { readRecording, buildRecording, RecordingError } from '../../proto/recording.mjs';
import { createDecoder, decodeFrame } from '../../proto/frame.mjs';

const zstd = new ZSTDDecoder();
await zstd.init();

const enc = new TextEncoder();
const u32 = (v) => { const b = new Uint8Array(4); new DataView(b.buffer).setUint32(0, v, true); return b; };
const u64 = (v) => { const b = new Uint8Array(8); new DataView(b.buffer).setBigUint64(0, BigInt(v), true); return b; };
const f64 = (v) => { const b = new Uint8Array(8); new DataView(b.buffer).setFloat64(0, v, true); return b; };
const cat = (...parts) => {
  const out = new Uint8Array(parts.reduce((s, p) => s + p.length, 0));
  let at = 0;
  for (const p of parts) out.set(p, at), (at += p.length);
  return out;
};
const pad4 = (b) => cat(b, new Uint8Array(((b.length + 3) & ~3) - b.length));

// An f32 frame of a 2 x 1 cloth, no rocks: the 72-byte header of PROTOCOL.md, then 6 f32.
function f32Frame(frame, simTime, xyz) {
  const h = new DataView(new ArrayBuffer(72));
  [...'CLF1'].forEach((c, k) => h.setUint8(k, c.charCodeAt(0)));
  h.setUint16(4, 72, true);
  h.setUint16(6, 0, true);
  h.setBigUint64(8, BigInt(frame), true);
  h.setBigUint64(16, BigInt(10 * frame), true);
  h.setFloat64(24, simTime, true);
  h.setUint32(40, 2, true);
  return cat(new Uint8Array(h.buffer), new Uint8Array(Float32Array.from(xyz).buffer));
}

const HELLO = { type: 'hello', scene_id: 'default', scene: { nx: 2, ny: 1 }, torn: [],
  recording: { id: 'r', scene: 'default', encoding: 'f32', seconds: 1, started_ns: 0, frame_rate: 60 } };
const helloText = enc.encode(JSON.stringify(HELLO));
const eventText = enc.encode('{"type":"event","event":"torn","springs":[0]}');
const FRAMES = [f32Frame(7, 0.5, [0, 0, 1, 1, 0, 1]), f32Frame(8, 0.5 + 1 / 60, [0, 0, 0.9, 1, 0, 0.8])];

// The file by hand: header 16; hello at 16; frame 0; the event; frame 1; the index; the tail.
const rec = (type, payload) => cat(u32(type), u32(payload.length), pad4(payload));
const at = { hello: 16 };
at.f0 = at.hello + 8 + ((helloText.length + 3) & ~3);
at.ev = at.f0 + 8 + 96;
at.f1 = at.ev + 8 + ((eventText.length + 3) & ~3);
at.index = at.f1 + 8 + 96;
const INDEX = cat(u32(2), u32(2),
  u64(at.f0), f64(0.5), u32(0), u32(1),
  u64(at.f1), f64(0.5 + 1 / 60), u32(1), u32(2),
  u64(at.hello), u64(at.ev));
const FILE = cat(enc.encode('CLR1'), u32(1), u32(0), u32(0),
  rec(1, helloText), rec(2, FRAMES[0]), rec(1, eventText), rec(2, FRAMES[1]), rec(3, INDEX),
  enc.encode('CLRX'), u32(0), u64(at.index));

test('a finished recording is read through its index', () => {
  const r = readRecording(FILE);
  assert.equal(r.complete, true);
  assert.deepEqual(r.hello, HELLO);
  assert.equal(r.info.frame_rate, 60);
  assert.deepEqual(r.frames.map((f) => [f.offset, f.length, f.key, f.textsBefore]), [[at.f0, 96, 0, 1], [at.f1, 96, 1, 2]]);
  assert.deepEqual(r.texts.map((t) => t.offset), [at.hello, at.ev]);
  assert.deepEqual(r.text(1), { type: 'event', event: 'torn', springs: [0] });
  assert.deepEqual([...decodeFrame(r.frame(1)).positions], [...Float32Array.from([0, 0, 0.9, 1, 0, 0.8])]);
  assert.equal(decodeFrame(r.frame(0)).frame, 7);
  assert.ok(Math.abs(r.duration - 1 / 60) < 1e-12);
  assert.equal(r.seek(0), 0);
  assert.equal(r.seek(0.01), 0);
  assert.equal(r.seek(1 / 60), 1);
  assert.equal(r.seek(99), 1);
});

test('buildRecording writes that same file byte for byte, and without an index the records alone', () => {
  const messages = [JSON.stringify({ ...HELLO, recording: undefined }), FRAMES[0], new TextDecoder().decode(eventText), FRAMES[1]];
  assert.deepEqual(buildRecording(messages, { recording: HELLO.recording }), FILE);
  assert.deepEqual(buildRecording(messages, { recording: HELLO.recording, index: false }), FILE.subarray(0, at.index));
});

test('a file cut anywhere reads up to its last complete record', () => {
  for (let len = 16; len < FILE.length; len++) {
    const cut = FILE.subarray(0, len);
    if (len < at.hello + 8 + helloText.length) { // no whole hello (its padding may be cut)
      assert.throws(() => readRecording(cut), RecordingError, `cut at ${len}`);
      continue;
    }
    const r = readRecording(cut);
    assert.equal(r.complete, false, `cut at ${len}`);
    const frames = len >= at.index ? 2 : len >= at.f1 + 104 ? 2 : len >= at.f0 + 104 ? 1 : 0;
    assert.equal(r.frames.length, frames, `cut at ${len}`);
    assert.equal(r.texts.length, len >= at.ev + 8 + eventText.length ? 2 : 1, `cut at ${len}`); // its padding may be cut
    if (frames === 2) assert.deepEqual(r.frames[1].textsBefore, 2);
  }
});

test('corrupt files are refused with the place named', () => {
  const broken = (edit) => { const b = FILE.slice(); edit(new DataView(b.buffer), b); return b; };
  const refuses = (b, re) => assert.throws(() => readRecording(b), (e) => e instanceof RecordingError && re.test(e.message), re.source);
  refuses(broken((dv) => dv.setUint8(0, 0x58)), /not a clothd recording/);
  refuses(broken((dv) => dv.setUint32(4, 2, true)), /version 2/);
  refuses(broken((dv) => dv.setUint32(8, 1, true)), /flags/);
  refuses(FILE.subarray(0, 10), /at least 16 bytes/);
  // The index: its offset outside, a frame entry at a text record, a wrong text count.
  refuses(broken((dv) => dv.setBigUint64(FILE.length - 8, BigInt(FILE.length), true)), /index.*offset/);
  refuses(broken((dv) => dv.setBigUint64(at.index + 16, BigInt(at.hello), true)), /frame 0 does not point at a frame record/);
  refuses(broken((dv) => dv.setUint32(at.index + 16 + 24 + 20, 1, true)), /frame 1 says 1 texts/);
  // A frame of the wrong vertex count; one that is not CLF1; a first record that is no hello.
  refuses(broken((dv) => dv.setUint32(at.f0 + 8 + 40, 3, true)), /frame 0: 3 vertices, the cloth has 2/);
  refuses(broken((dv) => dv.setUint8(at.f1 + 8, 0x41)), /frame 1: not a clothd frame/);
  refuses(broken((dv) => dv.setUint32(at.hello, 2, true)), /text 0 does not point at a text record/);
  refuses(broken((dv) => { dv.setUint32(at.hello, 2, true); dv.setUint32(FILE.length - 16, 0, true); }), /first record/);
  // An unknown record type in a file read by scanning.
  refuses(broken((dv) => { dv.setUint32(at.ev, 9, true); dv.setUint32(FILE.length - 16, 0, true); }), /unknown type 9/);
  // Text that is not JSON.
  refuses(broken((dv, b) => b.set(enc.encode('{{'), at.ev + 8)), /text record 1 is not JSON/);
});

test('a delta recording: seeking needs the keyframe the index names, and a delta without its keyframe is refused', () => {
  // Two keyframes and a delta, built from the spec's delta section (44-byte head, zstd values):
  // zstd's raw-block frame of the 12 n value bytes, written by hand (RFC 8878 3.1.1).
  const zstdRaw = (bytes) => cat(u32(0xfd2fb528), Uint8Array.of(0x20, bytes.length),
    Uint8Array.of(((bytes.length << 3) | 1) & 0xff, (bytes.length << 3) >> 8 & 0xff, (bytes.length << 3) >> 16 & 0xff), bytes);
  const deltaFrame = (frame, kind, keyId, values) => {
    const head = cat(u32(kind), u32(keyId), u64(frame), f64(0.001), u32(0), u32(0), u32(0), u32(2));
    const z = zstdRaw(values);
    const f = f32Frame(frame, frame / 60, []).slice(0, 72);
    const dv = new DataView(f.buffer);
    dv.setUint16(6, 3, true);
    return cat(f, head, u32(z.length), pad4(z));
  };
  const zeros = new Uint8Array(24);
  const msgs = [JSON.stringify({ ...HELLO, recording: { ...HELLO.recording, encoding: 'delta' } }),
    deltaFrame(1, 0, 1, zeros), deltaFrame(2, 1, 1, zeros), deltaFrame(3, 0, 2, zeros), deltaFrame(4, 1, 2, zeros)];
  const r = readRecording(buildRecording(msgs));
  assert.deepEqual(r.frames.map((f) => f.key), [0, 0, 2, 2]);
  const d = createDecoder({ zstd });
  d.decode(r.frame(r.frames[3].key));
  assert.deepEqual([...d.decode(r.frame(3)).positions], [0, 0, 0, 0, 0, 0]);
  // The scan finds the same keyframes.
  assert.deepEqual(readRecording(buildRecording(msgs, { index: false })).frames.map((f) => f.key), [0, 0, 2, 2]);
  // A delta of keyframe 1 after keyframe 2 is refused.
  const wrong = [...msgs.slice(0, 4), deltaFrame(4, 1, 1, zeros)];
  assert.throws(() => readRecording(buildRecording(wrong)), /frame 3: a delta of keyframe 1/);
});
