// recording.mjs - what a recording costs and how fast one seeks. A benchmark, not a test:
// it prints figures (docs/performance.md "Recordings").
//   1. Bytes per second of simulated time of the default scene (64 x 64, rocks dropping), one
//      recording per encoding of the same seconds, recorded at once.
//   2. Seek time in a 10-minute recording: the delta recording of part 1 repeated to 10 minutes
//      (its frames renumbered in time, keyframes where they were), then in node (V8, as a
//      browser): the time to open it (readRecording: the index read and every frame's header
//      checked), and per seek to a random time, the frame found and decoded with its keyframe.
//   node bench/recording.mjs [seconds, default 10]
import { performance } from 'node:perf_hooks';
import { ZSTDDecoder } from 'zstddec';
import { MeshoptDecoder } from 'meshoptimizer';
import { daemon } from './daemon.mjs';
import { readRecording, buildRecording } from '../proto/recording.mjs';
import { ENCODINGS, createDecoder } from '../proto/frame.mjs';

const seconds = Number(process.argv[2] ?? 10);
const zstd = new ZSTDDecoder();
await zstd.init();
await MeshoptDecoder.ready;
const median = (xs) => [...xs].sort((a, b) => a - b)[xs.length >> 1];
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

const d = await daemon([]);
const call = async (method, path, body) => {
  const r = await fetch(d.url + path, { method, body: body && JSON.stringify(body), headers: body ? { 'content-type': 'application/json' } : {} });
  if (!r.ok) throw new Error(`${method} ${path}: ${r.status} ${await r.text()}`);
  return r;
};
for (const encoding of ENCODINGS) await call('POST', '/v1/recordings', { seconds, encoding, id: `bench-${encoding}` });
for (;;) {
  const { recordings } = await (await call('GET', '/v1/recordings')).json();
  if (recordings.every((r) => r.state !== 'recording')) break;
  await sleep(250);
}
const files = {};
const { recordings } = await (await call('GET', '/v1/recordings')).json();
for (const encoding of ENCODINGS) {
  const bytes = new Uint8Array(await (await call('GET', `/v1/recordings/bench-${encoding}`)).arrayBuffer());
  const r = readRecording(bytes);
  files[encoding] = bytes;
  const listed = recordings.find((x) => x.id === `bench-${encoding}`);
  console.log(JSON.stringify({ part: 'size', cloth: '64x64 (default scene)', encoding, state: listed.state, frames: r.frames.length,
    seconds: +r.duration.toFixed(3), bytes: bytes.length, bytes_per_second: Math.round(bytes.length / r.duration),
    frames_dropped: listed.frames_dropped ?? 0 }));
}
d.proc.kill();

// Part 2: the delta recording repeated to 10 minutes.
const r = readRecording(files.delta);
const period = r.duration + 1 / (r.info.frame_rate || 60);
const copies = Math.ceil(600 / period);
const messages = [r.text(0)];
for (let c = 0; c < copies; c++) {
  for (let k = 0, t = 1; k < r.frames.length; k++) {
    for (; t < r.frames[k].textsBefore; t++) messages.push(r.text(t));
    const f = r.frame(k).slice();
    const dv = new DataView(f.buffer);
    dv.setFloat64(24, dv.getFloat64(24, true) + c * period, true);
    dv.setBigUint64(8, dv.getBigUint64(8, true) + BigInt(c * r.frames.length), true);
    if ((dv.getUint16(6, true) & 3) === 3) dv.setUint32(76, dv.getUint32(76, true) + c * 1000, true); // keyframe ids stay distinct
    messages.push(f);
  }
}
const long = buildRecording(messages);
const t0 = performance.now();
const big = readRecording(long);
const openMs = performance.now() - t0;
const seekMs = [];
let x = 12345;
for (let k = 0; k < 200; k++) {
  x = (x * 1103515245 + 12345) % 2147483648;
  const t = (x / 2147483648) * big.duration;
  const s0 = performance.now();
  const i = big.seek(t);
  const dec = createDecoder({ zstd, meshopt: MeshoptDecoder });
  if (big.frames[i].key !== i) dec.decode(big.frame(big.frames[i].key));
  dec.decode(big.frame(i));
  seekMs.push(performance.now() - s0);
}
console.log(JSON.stringify({ part: 'seek', cloth: '64x64', encoding: 'delta', minutes: +(big.duration / 60).toFixed(2), frames: big.frames.length,
  bytes: long.length, open_ms: +openMs.toFixed(1), seek_ms_median: +median(seekMs).toFixed(3), seek_ms_max: +Math.max(...seekMs).toFixed(3) }));
