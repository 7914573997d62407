// js_package.test.mjs - clients/js as the package npm makes of it. `npm pack` (whose prepack
// writes the TypeScript declarations from the JSDoc) gives a tarball that holds the frame and
// recording decoders and the declarations, and nothing of it imports from outside itself; it
// installs offline into an empty directory with none of its optional peers, and there, imported
// as `clothd-client`, talks to a real clothd and decodes a recorded frame into the cloth that
// GET /v1/cloth/state gives. A TypeScript consumer compiles against the installed declarations
// with --strict, and its @ts-expect-error lines (which tsc refuses where nothing is wrong) show
// that the declarations say more than `any`.
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { execFile } from 'node:child_process';
import { cpSync, mkdirSync, readdirSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { join } from 'node:path';
import { promisify } from 'node:util';
import { start, stop, tempDir } from '../server/harness.mjs';

const run = promisify(execFile);
const SOURCE = process.env.CLOTHD_SOURCE;
const PKG = JSON.parse(readFileSync(join(SOURCE, 'clients/js/package.json'), 'utf8'));

let dir, app, env, daemon;
before(async () => {
  dir = tempDir();
  // npm's cache of this test's own: nothing comes from the registry or a cache filled before.
  env = {
    ...process.env, PATH: `${join(SOURCE, 'node_modules/.bin')}:${process.env.PATH}`,
    npm_config_cache: join(dir, 'npm-cache'), npm_config_update_notifier: 'false',
  };
  // Packed from a copy, so that the declarations prepack writes stay out of the source tree; tsc
  // is the root package.json's (the PATH above).
  const pkg = join(dir, 'pkg');
  for (const f of ['package.json', 'tsconfig.json', 'README.md', 'src'])
    cpSync(join(SOURCE, 'clients/js', f), join(pkg, f), { recursive: true });
  await run('npm', ['pack', '--pack-destination', dir], { cwd: pkg, env });
  app = join(dir, 'app');
  mkdirSync(app);
  writeFileSync(join(app, 'package.json'), JSON.stringify({ name: 'app', private: true, type: 'module' }));
  await run('npm', ['install', '--offline', '--no-audit', '--no-fund', join(dir, `${PKG.name}-${PKG.version}.tgz`)], { cwd: app, env });
  daemon = await start(['--auto-drop-interval', '0', '--paused']);
});
after(async () => {
  if (daemon) await stop(daemon);
  if (dir) rmSync(dir, { recursive: true, force: true });
});

test('the tarball holds the decoders and the declarations, and nothing imports from outside it', async () => {
  const { stdout } = await run('tar', ['-tzf', join(dir, `${PKG.name}-${PKG.version}.tgz`)]);
  const files = stdout.split('\n').filter(Boolean);
  for (const f of ['package.json', 'README.md', 'src/index.js', 'src/frame.mjs', 'src/delta-wasm.mjs', 'src/recording.mjs',
    'types/index.d.ts', 'types/frame.d.mts', 'types/recording.d.mts', 'types/client.d.ts'])
    assert.ok(files.includes(`package/${f}`), `${f} is not in the tarball: ${files.join(' ')}`);
  const installed = join(app, 'node_modules', PKG.name);
  const meta = JSON.parse(readFileSync(join(installed, 'package.json'), 'utf8'));
  assert.equal(meta.private, undefined);
  assert.equal(meta.types, './types/index.d.ts');
  for (const f of readdirSync(join(installed, 'src'))) {
    const text = readFileSync(join(installed, 'src', f), 'utf8');
    assert.doesNotMatch(text, /(from|import\()\s*['"]\.\.\//, `${f} imports from outside the package`);
  }
  // None of the optional peers came along.
  assert.deepEqual(readdirSync(join(app, 'node_modules')).filter((n) => !n.startsWith('.')), [PKG.name]);
});

test('installed, it talks to a real clothd and decodes a recorded frame into the cloth state', async () => {
  writeFileSync(join(app, 'use.mjs'), `
import { Client, NotFound, createDecoder, readRecording } from 'clothd-client';
import { decodeFrame } from 'clothd-client/frame';
const c = new Client({ base: process.argv[2] });
const out = { resolved: import.meta.resolve('clothd-client'), health: (await c.health()).status };
await c.setScene({ nx: 8, ny: 6 });
await c.step({ frames: 3 });
out.sim = await c.sim();
const { id } = await c.record({ seconds: 1, encoding: 'f32', id: 'pkg' });
// A paused scene's recording holds its frame of now and waits.
for (const t0 = Date.now(); !(await c.recordings()).recordings.some((r) => r.id === id && r.frames >= 1);) {
  if (Date.now() - t0 > 10000) throw new Error('no frame recorded in 10 s');
  await new Promise((r) => setTimeout(r, 20));
}
const rec = readRecording(new Uint8Array(await c.recording(id)));
const f = createDecoder().decode(rec.frame(0));
out.frame = { encoding: f.encoding, step: f.step, n: f.nVertices, positions: Array.from(f.positions.subarray(0, 3 * f.nVertices)) };
out.same = Array.from(decodeFrame(rec.frame(0)).positions.subarray(0, 3 * f.nVertices));
out.state = Array.from((await c.clothStateBinary()).positions);
await c.deleteRecording(id);
out.notFound = await c.recording(id).then(() => false, (e) => e instanceof NotFound && e.status === 404);
console.log(JSON.stringify(out));
`);
  const { stdout } = await run(process.execPath, ['use.mjs', daemon.url], { cwd: app, env, timeout: 20000 });
  const out = JSON.parse(stdout);
  assert.equal(out.resolved, `file://${join(app, 'node_modules', PKG.name, 'src', 'index.js')}`);
  assert.equal(out.health, 'ok');
  assert.equal(out.sim.n_vertices, 48);
  assert.deepEqual([out.frame.encoding, out.frame.n, out.frame.step], ['f32', 48, out.sim.step]);
  assert.ok(out.sim.step > 0);
  assert.equal(out.state.length, 3 * 48);
  assert.deepEqual(out.frame.positions, out.state); // f32 frames carry the float32 positions as they are
  assert.deepEqual(out.same, out.state);
  assert.equal(out.notFound, true);
});

test('a TypeScript consumer compiles against the installed declarations with --strict', async () => {
  writeFileSync(join(app, 'consumer.ts'), `
import { Client, NotFound, createDecoder, readRecording } from 'clothd-client';
import { decodeFrame, type Frame } from 'clothd-client/frame';

export async function lowest(base: string, rid: string): Promise<number> {
  const c = new Client({ base, timeout: 5000 });
  await c.step({ substeps: 5 });
  const { positions } = await c.clothStateBinary();
  const rec = readRecording(new Uint8Array(await c.recording(rid)));
  const f: Frame = createDecoder().decode(rec.frame(rec.seek(0.5)));
  let z = positions[2];
  for (let i = 2; i < 3 * f.nVertices; i += 3) z = Math.min(z, f.positions[i]);
  return z;
}
export function isMissing(e: unknown): boolean { return e instanceof NotFound && e.status === 404; }
export function bytes(data: Uint8Array): number { return decodeFrame(data).bytes; }

// @ts-expect-error a step is frames or substeps
export const badStep = (c: Client) => c.step({ seconds: 1 });
// @ts-expect-error a recording's file is an ArrayBuffer, not a string
export const badFile = async (c: Client): Promise<string> => c.recording('r');
// @ts-expect-error a frame's positions are a Float32Array
export const badPositions = (data: Uint8Array): string => decodeFrame(data).positions;
`);
  writeFileSync(join(app, 'tsconfig.json'), JSON.stringify({
    compilerOptions: { strict: true, noEmit: true, module: 'nodenext', target: 'es2022', lib: ['es2022', 'dom'], types: [], skipLibCheck: false },
    files: ['consumer.ts'],
  }));
  const r = await run('tsc', ['-p', 'tsconfig.json'], { cwd: app, env }).catch((e) => e);
  assert.equal(r.code ?? 0, 0, `tsc: ${r.stdout}${r.stderr}`);
  // And it does refuse what is wrong: the same consumer without the expectations fails.
  writeFileSync(join(app, 'consumer.ts'), readFileSync(join(app, 'consumer.ts'), 'utf8').replaceAll('// @ts-expect-error', '//'));
  const bad = await run('tsc', ['-p', 'tsconfig.json'], { cwd: app, env }).catch((e) => e);
  assert.notEqual(bad.code ?? 0, 0);
  assert.equal((bad.stdout.match(/error TS/g) ?? []).length, 3, bad.stdout);
});
