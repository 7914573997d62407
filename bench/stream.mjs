// stream.mjs - the stream under load: frames per second delivered to 1, 8 and 32 clients
// per encoding while clothd runs a 128 x 128 cloth on the CPU backend, with the sim's real-time
// factor; bytes per frame per encoding (and on the default 64 x 64 scene); the latency from
// POST /v1/rocks to the first frame that holds the rock. A benchmark, not a test.
//   node bench/stream.mjs [seconds per case, default 5]
//   BENCH_CASES=delta:128,q16:64 node bench/stream.mjs   only these fan-out cases
// (encoding:clients) at 128 x 128; BENCH_PARAMS='{"time_scale":0.25,...}' patches /v1/params
// first (the sim in slow motion, to see what the stream delivers when the sim is not the limit);
// a frame counts once per client (a delta keyframe sent again
// before a delta, to a client that skipped it, is not a frame of its own).
import WebSocket from 'ws';
import { daemon } from './daemon.mjs';
import { MeshoptDecoder } from 'meshoptimizer';
import { decodeFrame } from '../proto/frame.mjs';

const secs = Number(process.argv[2] ?? 5);
await MeshoptDecoder.ready;

const sim = async (d) => (await fetch(`${d.url}/v1/sim`)).json();

function client(d, encoding) {
  return new Promise((resolve) => {
    const ws = new WebSocket(d.ws, 'clothd.v1');
    const c = { ws, frames: 0, bytes: 0, last: null, onFrame: null }; // last: the newest wall clock seen
    ws.on('open', () => {
      ws.send(JSON.stringify({ type: 'subscribe', encoding, max_fps: 240 }));
      resolve(c);
    });
    ws.on('message', (data, binary) => {
      if (!binary) return;
      const wall = data.readBigUInt64LE(32);
      if (c.last !== null && wall <= c.last) return; // a keyframe sent again
      c.last = wall;
      c.frames++;
      c.bytes = data.length;
      if (c.onFrame) c.onFrame(data);
    });
  });
}

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

async function fpsCase(d, encoding, n) {
  const clients = await Promise.all(Array.from({ length: n }, () => client(d, encoding)));
  await sleep(1000);
  for (const c of clients) c.frames = 0;
  const s0 = await sim(d), t0 = Date.now();
  await sleep(secs * 1000);
  const s1 = await sim(d), dt = (Date.now() - t0) / 1000;
  const fps = clients.map((c) => c.frames / dt);
  for (const c of clients) c.ws.close();
  await sleep(300);
  return {
    encoding, clients: n, fps_min: Math.min(...fps).toFixed(1), fps_mean: (fps.reduce((a, b) => a + b) / n).toFixed(1),
    realtime_factor: ((s1.sim_time - s0.sim_time) / dt).toFixed(3), bytes_per_frame: clients[0].bytes,
  };
}

async function latency(d, encoding) {
  const c = await client(d, encoding);
  await sleep(500);
  const results = [];
  for (let k = 0; k < 10; k++) {
    const t0 = performance.now();
    const res = await fetch(`${d.url}/v1/rocks`, { method: 'POST', body: JSON.stringify({ position: [0.5 * Math.cos(k), 0.5 * Math.sin(k), 2], radius: 0.05 }) });
    const { id, applied_step: applied } = await res.json();
    const tAnswer = performance.now();
    const frame = await new Promise((resolve) => {
      c.onFrame = (data) => {
        const f = decodeFrame(data, { meshopt: MeshoptDecoder });
        if (f.rocks.some((r) => r.id === id)) resolve(f);
      };
    });
    const tFrame = performance.now();
    c.onFrame = null;
    results.push({ answer_ms: tAnswer - t0, frame_ms: tFrame - t0, applied, frame_step: frame.step });
    await fetch(`${d.url}/v1/rocks/${id}`, { method: 'DELETE' });
    await sleep(100);
  }
  c.ws.close();
  const ms = results.map((r) => r.frame_ms).sort((a, b) => a - b);
  return {
    encoding, median_ms: ms[5].toFixed(1), max_ms: ms[9].toFixed(1),
    median_answer_ms: results.map((r) => r.answer_ms).sort((a, b) => a - b)[5].toFixed(1),
  };
}

const big = await daemon(['--nx', '128', '--ny', '128', '--auto-drop-interval', '1', '--stream-max-clients', '256']);
if (process.env.BENCH_PARAMS) {
  const r = await fetch(`${big.url}/v1/params`, { method: 'PATCH', headers: { 'content-type': 'application/json' }, body: process.env.BENCH_PARAMS });
  if (!r.ok) {
    big.proc.kill('SIGTERM'); // not left running behind a failed benchmark
    throw new Error(`PATCH /v1/params: ${r.status} ${await r.text()}`);
  }
}
if (process.env.BENCH_CASES) {
  await sleep(2000);
  for (const c of process.env.BENCH_CASES.split(',')) {
    const [encoding, n] = c.split(':');
    console.log(JSON.stringify(await fpsCase(big, encoding, Number(n))));
  }
  big.proc.kill('SIGTERM');
  process.exit(0);
}
await sleep(2000);
console.log(`clothd 128x128 on the CPU backend, ${(await sim(big)).substeps} substeps per frame`);
for (const encoding of ['f32', 'q16', 'meshopt', 'delta'])
  for (const n of [1, 8, 32]) console.log(JSON.stringify(await fpsCase(big, encoding, n)));
for (const encoding of ['f32', 'meshopt']) console.log(JSON.stringify({ latency: await latency(big, encoding) }));
big.proc.kill('SIGTERM');

const def = await daemon([]);
await sleep(4000); // a rock or two in the net
for (const encoding of ['f32', 'q16', 'meshopt', 'delta']) {
  const c = await client(def, encoding);
  await sleep(1500);
  const n = (await sim(def)).n_vertices, rocks = (await sim(def)).n_rocks;
  console.log(JSON.stringify({ default_scene: true, encoding, bytes_per_frame: c.bytes, vertices: n, rocks,
    bytes_per_vertex: ((c.bytes - 72 - 36 * rocks) / n).toFixed(3) }));
  c.ws.close();
}
def.proc.kill('SIGTERM');
