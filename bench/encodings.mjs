// encodings.mjs - what each stream encoding costs on a moving cloth: bytes per vertex of
// the positions (and of the whole frame), the server's encode time per frame (from
// clothd_stream_encode_seconds_total), and the decode time per frame in node with proto/frame.mjs
// (V8, as in a browser), for f32, q16, meshopt and delta, on the default scene (64 x 64, rocks
// dropping every 3 s) and at 128 x 128, all four encodings subscribed at once; then the decode
// time of 256 x 256 delta frames, beside the sim and then alone. A benchmark, not a test: it prints figures.
//   node bench/encodings.mjs [seconds per size, default 8]
import WebSocket from 'ws';
import { daemon } from './daemon.mjs';
import { MeshoptDecoder } from 'meshoptimizer';
import { ZSTDDecoder } from 'zstddec';
import { ENCODINGS, createDecoder, isDeltaKeyKind } from '../proto/frame.mjs';

const secs = Number(process.argv[2] ?? 8);
await MeshoptDecoder.ready;
const zstd = new ZSTDDecoder();
await zstd.init();

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
const metrics = async (d) => (await fetch(`${d.url}/metrics`)).text();
const series = (text, name, encoding) => Number(new RegExp(`^${name}\\{encoding="${encoding}"\\} ([\\d.e+-]+)$`, 'm').exec(text)?.[1] ?? 0);
const median = (xs) => [...xs].sort((a, b) => a - b)[xs.length >> 1];

// A client of one encoding that decodes every frame it gets and times it.
function client(d, encoding) {
  return new Promise((resolve) => {
    const ws = new WebSocket(d.ws, 'clothd.v1');
    const decoder = createDecoder({ meshopt: MeshoptDecoder, zstd });
    const c = { ws, encoding, frames: 0, bytes: 0, positionBytes: 0, vertices: 0, ms: [], keyframes: 0, errors: 0, on: false };
    ws.on('open', () => {
      ws.send(JSON.stringify({ type: 'subscribe', encoding, max_fps: 60 }));
      resolve(c);
    });
    ws.on('message', (data, binary) => {
      if (!binary) return;
      const t0 = performance.now();
      let f;
      try {
        f = decoder.decode(data);
      } catch {
        c.errors++;
        return;
      }
      const ms = performance.now() - t0;
      if (!c.on || f.encoding !== encoding) return;
      if (c.keep) c.kept.push(new Uint8Array(data));
      c.frames++;
      c.bytes += f.bytes;
      c.positionBytes += f.bytes - 72 - 36 * f.nRocks - (f.scalar ? f.nVertices : 0);
      c.vertices = f.nVertices;
      c.ms.push(ms);
      if (f.delta?.keyframe) c.keyframes++;
    });
  });
}

async function size(label, flags) {
  const d = await daemon(flags);
  const clients = await Promise.all(ENCODINGS.map((e) => client(d, e)));
  await sleep(1000);
  const m0 = await metrics(d);
  for (const c of clients) c.on = true;
  await sleep(secs * 1000);
  for (const c of clients) c.on = false;
  const m1 = await metrics(d);
  const sim = await (await fetch(`${d.url}/v1/sim`)).json();
  for (const c of clients) {
    const encoded = series(m1, 'clothd_stream_frames_encoded_total', c.encoding) - series(m0, 'clothd_stream_frames_encoded_total', c.encoding);
    const encodeS = series(m1, 'clothd_stream_encode_seconds_total', c.encoding) - series(m0, 'clothd_stream_encode_seconds_total', c.encoding);
    console.log(JSON.stringify({
      cloth: label, encoding: c.encoding, frames: c.frames, keyframes: c.encoding === 'delta' ? c.keyframes : undefined,
      bytes_per_vertex: (c.positionBytes / c.frames / c.vertices).toFixed(3),
      bytes_per_frame: Math.round(c.bytes / c.frames),
      encode_ms: (encodeS / encoded * 1e3).toFixed(3), decode_ms_median: median(c.ms).toFixed(3),
      errors: c.errors,
    }));
    c.ws.close();
  }
  console.log(JSON.stringify({ cloth: label, rocks: sim.n_rocks, realtime_factor: sim.realtime_factor }));
  d.proc.kill('SIGTERM');
  await sleep(300);
}

await size('64x64 (default scene)', []);
await size('128x128', ['--nx', '128', '--ny', '128']);

// 256 x 256: the decode time of delta frames (the sim runs slower than real time there).
const d = await daemon(['--nx', '256', '--ny', '256']);
const c = await client(d, 'delta');
c.keep = true;
c.kept = [];
c.on = true;
const t0 = Date.now();
while (c.frames < 30 && Date.now() - t0 < 60000) await sleep(200);
console.log(JSON.stringify({ cloth: '256x256', encoding: 'delta', frames: c.frames, keyframes: c.keyframes,
  bytes_per_vertex: (c.positionBytes / c.frames / c.vertices).toFixed(3), decode_ms_median: median(c.ms).toFixed(3),
  decode_ms_max: Math.max(...c.ms).toFixed(3), errors: c.errors }));
c.ws.close();
d.proc.kill('SIGTERM');
// The same frames decoded again with the daemon gone (no sim beside the decoder), from their
// first keyframe on, 20 times over, into one array as the viewer does.
await sleep(300);
const first = c.kept.findIndex((b) => isDeltaKeyKind(new DataView(b.buffer).getUint32(72, true)));
const again = [], positions = new Float32Array(3 * 256 * 256);
for (let rep = 0; rep < 20; rep++) {
  const dec = createDecoder({ zstd, positions });
  for (const b of c.kept.slice(first)) {
    const t0 = performance.now();
    const f = dec.decode(b);
    if (!f.delta.keyframe) again.push(performance.now() - t0);
  }
}
console.log(JSON.stringify({ cloth: '256x256', encoding: 'delta', alone: true, deltas: again.length,
  decode_ms_median: median(again).toFixed(3), decode_ms_min: Math.min(...again).toFixed(3) }));
