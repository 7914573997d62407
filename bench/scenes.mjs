#!/usr/bin/env node
// scenes.mjs - many scenes in one daemon against the same scenes in as many clothd
// processes, in the same run (figures, not a test):
//
//   1. aggregate vertex-substeps per second for 1, 4, 16 and 64 scenes of 32 x 32 and of 64 x 64,
//      every scene at max_speed, counted from GET /v1/scenes' steps (or each process's GET /v1/sim)
//      over a fixed wall time: one daemon (its CPU threads shared by the scenes' batched frames)
//      against N daemons of one scene each, one thread each;
//   2. how many default scenes of 32 x 32 (the default material and parameters, real time) one
//      daemon runs with every scene's real-time factor at 0.95 or more.
//
// usage: node bench/scenes.mjs [--bin build/server/clothd] [--seconds 3] [--counts 1,4,16,64]
//        [--sizes 32,64] [--threads 0] [--realtime false]
// Figures taken on a machine others share are provisional.
import { spawn } from 'node:child_process';
import { mkdtempSync, rmSync } from 'node:fs';
import { tmpdir, cpus } from 'node:os';
import { join, dirname } from 'node:path';
import { fileURLToPath } from 'node:url';

const root = join(dirname(fileURLToPath(import.meta.url)), '..');
const arg = (name, def) => {
  const k = process.argv.indexOf(`--${name}`);
  return k > 0 ? process.argv[k + 1] : def;
};
const BIN = arg('bin', join(root, 'build/server/clothd'));
const SECONDS = Number(arg('seconds', '3'));
const COUNTS = arg('counts', '1,4,16,64').split(',').map(Number);
const SIZES = arg('sizes', '32,64').split(',').map(Number);
const THREADS = arg('threads', '0');
const REALTIME = arg('realtime', 'true') !== 'false';
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

// A clothd on free ports, resolved once it listens.
function daemon(flags) {
  const dir = mkdtempSync(join(tmpdir(), 'bench-scenes-'));
  const proc = spawn(BIN, ['--port', '0', '--stream-port', '0', '--backend', 'cpu', '--web-root', dir, ...flags], {
    stdio: ['ignore', 'ignore', 'pipe'], env: { ...process.env, OMP_WAIT_POLICY: 'passive' },
  });
  let log = '';
  return new Promise((resolve, reject) => {
    proc.stderr.setEncoding('utf8');
    proc.stderr.on('data', (c) => {
      log += c;
      const m = /listening on http:\/\/([0-9.]+):(\d+)/.exec(log);
      if (m) resolve({ proc, dir, url: `http://${m[1]}:${m[2]}` });
    });
    proc.on('exit', (code) => reject(new Error(`clothd exited (${code}):\n${log}`)));
  });
}
async function stopAll(ds) {
  await Promise.all(ds.map((d) => new Promise((r) => {
    d.proc.removeAllListeners('exit');
    d.proc.on('exit', r);
    d.proc.kill('SIGTERM');
  })));
  for (const d of ds) rmSync(d.dir, { recursive: true, force: true });
}
async function api(d, method, path, body) {
  const r = await fetch(d.url + path, { method, body: body === undefined ? undefined : JSON.stringify(body) });
  const j = await r.json();
  if (r.status >= 300) throw new Error(`${method} ${path}: ${r.status} ${JSON.stringify(j)}`);
  return j;
}

// Vertex-substeps per second of every scene of these daemons over SECONDS of wall time.
async function throughput(ds) {
  const read = async () => {
    let sum = 0;
    for (const d of ds) for (const s of (await api(d, 'GET', '/v1/scenes')).scenes) sum += s.step * s.n_vertices;
    return { sum, t: performance.now() };
  };
  await sleep(500); // past the first frames' cost measurements
  const a = await read();
  await sleep(SECONDS * 1000);
  const b = await read();
  return (b.sum - a.sum) / ((b.t - a.t) / 1000);
}

const scene = (n) => ['--nx', String(n), '--ny', String(n), '--auto-drop-interval', '0'];

async function oneDaemon(n, size) {
  const d = await daemon([...scene(size), '--max-speed', 'true', '--max-scenes', String(n), '--threads', THREADS]);
  for (let k = 1; k < n; k++) await api(d, 'POST', '/v1/scenes', { id: `s${k}` });
  try {
    return await throughput([d]);
  } finally {
    await stopAll([d]);
  }
}

async function manyDaemons(n, size) {
  const ds = await Promise.all(Array.from({ length: n }, () => daemon([...scene(size), '--max-speed', 'true', '--threads', '1'])));
  try {
    return await throughput(ds);
  } finally {
    await stopAll(ds);
  }
}

// The least real-time factor of k default 32 x 32 scenes in one daemon, after they settle.
async function leastRtf(k) {
  const d = await daemon([...scene(32), '--max-scenes', String(k), '--threads', THREADS]);
  try {
    for (let j = 1; j < k; j++) await api(d, 'POST', '/v1/scenes', { id: `s${j}` });
    await sleep(2500);
    let least = Infinity;
    for (let look = 0; look < 3; look++) {
      for (const s of (await api(d, 'GET', '/v1/scenes')).scenes) least = Math.min(least, s.realtime_factor);
      await sleep(500);
    }
    return least;
  } finally {
    await stopAll([d]);
  }
}

const fmt = (v) => (v / 1e6).toFixed(1).padStart(8);
console.log(`bench-scenes: ${cpus().length} CPUs, ${SECONDS} s per figure, one daemon with --threads ${THREADS} ` +
  'against N daemons of --threads 1 (provisional on a shared machine)');
console.log('scenes  size   one daemon   N daemons   ratio   (M vertex-substeps/s)');
for (const size of SIZES) {
  for (const n of COUNTS) {
    const one = await oneDaemon(n, size);
    const many = await manyDaemons(n, size);
    console.log(`${String(n).padStart(6)}  ${String(size).padStart(2)}^2 ${fmt(one)}    ${fmt(many)}    ${(one / many).toFixed(2).padStart(5)}`);
  }
}
let best = 0;
for (const k of REALTIME ? [1, 2, 4, 6, 8, 10, 12, 14, 16, 20, 24, 32] : []) {
  const least = await leastRtf(k);
  console.log(`real time: ${String(k).padStart(2)} default 32^2 scenes, least real-time factor ${least.toFixed(3)}`);
  if (least < 0.95) break;
  best = k;
}
if (REALTIME) console.log(`real time: ${best} default 32^2 scenes run with every real-time factor >= 0.95 in one daemon`);
