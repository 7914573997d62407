// export.mjs - how fast a recording exports, and how large the files are. A benchmark,
// not a test: it prints figures. The default scene (64 x 64, rocks dropping) is recorded for
// `seconds` of sim time in real time (delta), then exported to temporary files one after another:
// USD by the JavaScript client (clients/js/src/recording-export.js, the node script's path), USD by
// the Python client (Recording.to_usd and to_mcap, where python3 imports clothd), and MCAP. For each: frames a
// second of wall time and MB per minute of recording.
//   node bench/export.mjs [seconds, default 10]   (clothd: build/server/clothd or $CLOTHD_BIN)
import { performance } from 'node:perf_hooks';
import { createWriteStream, mkdtempSync, rmSync, statSync, writeFileSync } from 'node:fs';
import { open } from 'node:fs/promises';
import { once } from 'node:events';
import { execFileSync } from 'node:child_process';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { daemon } from './daemon.mjs';
import { exportUsd, exportMcap } from '../clients/js/src/recording-export.js';
import { readRecording } from '../proto/recording.mjs';
import { triangleIndices } from '../web/src/topology.js';

const seconds = Number(process.argv[2] ?? 10);
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
const dir = mkdtempSync(join(tmpdir(), 'clothd-export-bench-'));

const d = await daemon([]);
let bytes;
try {
  const call = async (method, path, body) => {
    const r = await fetch(d.url + path, { method, body: body && JSON.stringify(body), headers: body ? { 'content-type': 'application/json' } : {} });
    if (!r.ok) throw new Error(`${method} ${path}: ${r.status} ${await r.text()}`);
    return r;
  };
  await call('POST', '/v1/recordings', { seconds, id: 'bench-export' });
  for (;;) {
    const { recordings } = await (await call('GET', '/v1/recordings')).json();
    if (recordings.every((r) => r.state !== 'recording')) break;
    await sleep(250);
  }
  bytes = new Uint8Array(await (await call('GET', '/v1/recordings/bench-export')).arrayBuffer());
} finally {
  const exited = once(d.proc, 'exit');
  d.proc.kill('SIGTERM');
  await exited;
}
const rec = readRecording(bytes);
const clr = join(dir, 'bench.clr');
writeFileSync(clr, bytes);
const n = rec.hello.scene.nx * rec.hello.scene.ny, rocks = rec.text(0).rocks?.length ?? 0;
const minutes = rec.duration / 60;
console.log(`recording: ${rec.frames.length} frames, ${rec.duration.toFixed(2)} s of sim time, ${rec.hello.scene.nx} x ${rec.hello.scene.ny} (${n} vertices), ` +
  `${rocks} rocks at the start, ${(bytes.length / 1e6).toFixed(2)} MB (${rec.info.encoding})`);

async function measure(what, fn, path) {
  const t = performance.now();
  const written = await fn();
  const s = (performance.now() - t) / 1000;
  const mb = statSync(path).size / 1e6;
  console.log(`${what.padEnd(22)} ${written} frames in ${s.toFixed(2)} s: ${(written / s).toFixed(0)} frames/s; ` +
    `${mb.toFixed(1)} MB, ${(mb / minutes).toFixed(0)} MB per minute of recording`);
}

await measure('USD (JavaScript)', async () => {
  const stream = createWriteStream(join(dir, 'js.usda'));
  const r = await exportUsd(bytes, { write: (s) => (stream.write(s) ? undefined : once(stream, 'drain')) }, { triangles: triangleIndices });
  stream.end();
  await once(stream, 'finish');
  return r.written;
}, join(dir, 'js.usda'));

const PY = ['/usr/bin/python3'].find((p) => { try { return statSync(p).isFile(); } catch { return false; } }) ?? 'python3'; // Debian's, with numpy, as the tests use
let python = true;
try { execFileSync(PY, ['-c', `import sys; sys.path.insert(0, 'clients/python'); import clothd`], { cwd: new URL('..', import.meta.url).pathname }); } catch { python = false; }
/** The Python client's Recording.<method>(path) of the recording: the frames it wrote. */
const pythonExport = (method, path) => Number(execFileSync(PY, ['-c',
  `import sys; sys.path.insert(0, 'clients/python'); import clothd\nprint(clothd.read_recording(open(sys.argv[1], 'rb').read()).${method}(sys.argv[2])['written'])`,
  clr, path], { cwd: new URL('..', import.meta.url).pathname }).toString());
if (python) {
  await measure('USD (Python)', async () => pythonExport('to_usd', join(dir, 'py.usda')), join(dir, 'py.usda'));
  await measure('MCAP (Python)', async () => pythonExport('to_mcap', join(dir, 'py.mcap')), join(dir, 'py.mcap'));
} else console.log('USD, MCAP (Python)     skipped: python3 does not import clients/python clothd');

await measure('MCAP (JSON)', async () => {
  const file = await open(join(dir, 'bench.mcap'), 'w');
  let position = 0n;
  try {
    const r = await exportMcap(bytes, { position: () => position, write: async (b) => { await file.write(b); position += BigInt(b.byteLength); } }, { triangles: triangleIndices });
    return r.written;
  } finally {
    await file.close();
  }
}, join(dir, 'bench.mcap'));
rmSync(dir, { recursive: true, force: true });
