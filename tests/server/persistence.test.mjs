// persistence.test.mjs - what survives and what repeats: the state file across SIGTERM and a
// restart, `clothd replay` of a journal bundle against the live hash, determinism through the
// API, and paused commands visible in the very next read.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { existsSync, writeFileSync, readdirSync } from 'node:fs';
import { join } from 'node:path';
import { start, stop, call, ok, pause, hash, until, tempDir, execChecked, CLOTHD } from './harness.mjs';

const run = execChecked; // execFile, and a sanitizer report fails the test

test('SIGTERM saves the state file and a restart resumes at the same hash', async () => {
  const dir = tempDir();
  const state = join(dir, 'state.bin');
  const a = await start(['--nx', '16', '--ny', '16', '--state-file', state]);
  await until('a rock dropped', async () => (await ok(a, 'GET', '/v1/sim')).n_rocks > 0);
  await ok(a, 'PATCH', '/v1/params', { k_bend: 33 });
  await pause(a);
  const before = await ok(a, 'GET', '/v1/sim');
  assert.equal((await stop(a, 'SIGTERM')).code, 0);
  assert.ok(existsSync(state));
  assert.deepEqual(readdirSync(dir), ['state.bin']); // no temp file left behind
  assert.match(a.log, /state saved to/);

  const b = await start(['--state-file', state, '--paused']);
  const after = await ok(b, 'GET', '/v1/sim');
  assert.equal(after.state_hash, before.state_hash);
  assert.equal(after.step, before.step);
  assert.equal(after.n_rocks, before.n_rocks);
  assert.equal((await ok(b, 'GET', '/v1/params')).k_bend, 33);
  assert.match(b.log, new RegExp(`resumed from .* state hash ${before.state_hash}`));
  // SIGINT saves too, and a running daemon is stopped at a frame boundary.
  await ok(b, 'POST', '/v1/sim/resume');
  assert.equal((await stop(b, 'SIGINT')).code, 0);
  const c = await start(['--state-file', state, '--paused']);
  assert.ok((await ok(c, 'GET', '/v1/sim')).step >= before.step);
  await stop(c);
});

test('a corrupt state file stops the start with a reason', async () => {
  const dir = tempDir();
  const state = join(dir, 'state.bin');
  writeFileSync(state, 'garbage');
  await assert.rejects(start(['--state-file', state]), /cannot resume from the state file/);
});

test('clothd replay reruns the journal bundle to the live hash', async () => {
  const d = await start(['--nx', '20', '--ny', '20', '--time-scale', '4', '--auto-drop-interval', '0.5', '--seed', '7']);
  // Automatic drops, and commands of every kind, while running.
  await until('three automatic drops', async () => (await ok(d, 'GET', '/v1/sim')).n_rocks >= 3);
  const id = (await ok(d, 'POST', '/v1/rocks', { position: [0.2, 0.1, 1.6], radius: 0.08, angular_velocity: [0, 3, 0] })).id;
  await ok(d, 'PATCH', '/v1/params', { k_shear: 70, friction_model: 'resultant', plastic_yield: 0.05 });
  await ok(d, 'PUT', '/v1/grab', { vertex: 210, target: [0, 0, 1.4] });
  await ok(d, 'PATCH', `/v1/rocks/${id}`, { velocity: [0, 0, 1] });
  await ok(d, 'PUT', '/v1/pins', { vertices: [100, 101], pinned: true });
  await until('more drops', async () => (await ok(d, 'GET', '/v1/sim')).n_rocks >= 6);
  await ok(d, 'DELETE', '/v1/grab');
  await pause(d);
  await ok(d, 'POST', '/v1/sim/step', { substeps: 13 });
  const live = await hash(d);
  const bundle = await call(d, 'GET', '/v1/journal', undefined, { Accept: 'application/octet-stream' });
  assert.equal(bundle.status, 200);
  const journal = await ok(d, 'GET', '/v1/journal');
  assert.ok(journal.entries.some((e) => e.command.by === 'auto'));
  assert.ok(journal.entries.length >= 10, `${journal.entries.length} entries`);
  const file = join(tempDir(), 'run.replay');
  writeFileSync(file, bundle.buf);
  const { stdout } = await run(CLOTHD, ['replay', file, '--backend', 'cpu'], { env: { OMP_WAIT_POLICY: 'passive' } });
  assert.equal(stdout.trim(), live);
  await stop(d);
});

test('clothd replay takes a journal whose commands leave out their optional members', async () => {
  // A bundle is a file anyone can write: rock_set without `rock` and scene without `scene` are
  // patches of nothing, the same as the API's {} (each leaked its empty patch: the sanitized run
  // of this test fails on LeakSanitizer's report).
  const d = await start(['--nx', '8', '--ny', '8', '--paused', '--auto-drop-interval', '0']);
  const { id } = await ok(d, 'POST', '/v1/rocks', { position: [0, 0, 2], radius: 0.1 });
  await ok(d, 'PATCH', `/v1/rocks/${id}`, {});
  const bundle = (await call(d, 'GET', '/v1/journal', undefined, { Accept: 'application/octet-stream' })).buf;
  await ok(d, 'PUT', '/v1/scene', {});
  const live = await hash(d);
  await stop(d);
  const snapshotLength = 32 + Number(bundle.readBigUInt64LE(16));
  const journal = JSON.parse(bundle.subarray(snapshotLength).toString());
  assert.deepEqual(journal.entries.map((e) => e.command.op), ['rock_add', 'rock_set']);
  journal.entries[1].command = { op: 'rock_set', id };
  journal.entries.push({ step: journal.step, command: { op: 'scene' } });
  const file = join(tempDir(), 'short.replay');
  writeFileSync(file, Buffer.concat([bundle.subarray(0, snapshotLength), Buffer.from(JSON.stringify(journal))]));
  const { stdout } = await run(CLOTHD, ['replay', file, '--backend', 'cpu'], { env: { OMP_WAIT_POLICY: 'passive' } });
  assert.equal(stdout.trim(), live);
});

test('clothd replay refuses a file that is not a bundle', async () => {
  const file = join(tempDir(), 'bad.replay');
  writeFileSync(file, 'hello');
  await assert.rejects(run(CLOTHD, ['replay', file]), /not a journal bundle/);
});

// The same commands at the same steps from a reset give the same state. (A reset keeps the
// parameters, so the script sets every one it changes later.)
async function script(d) {
  await ok(d, 'POST', '/v1/sim/reset');
  await ok(d, 'PATCH', '/v1/params', { tear_strain: 0.4, seed: 3, auto_drop_interval: 0.2, integrator: 'velocity_verlet' });
  await ok(d, 'POST', '/v1/rocks', { position: [0, 0, 1.5], radius: 0.12, density: 400, velocity: [0, 0, -3] });
  await ok(d, 'POST', '/v1/sim/step', { frames: 20 });
  await ok(d, 'PUT', '/v1/grab', { vertex: 50, target: [0.3, 0.3, 1.5] });
  await ok(d, 'POST', '/v1/sim/step', { frames: 15 });
  await ok(d, 'PATCH', '/v1/params', { integrator: 'symplectic_euler' });
  await ok(d, 'POST', '/v1/sim/step', { substeps: 101 });
  return hash(d);
}

test('the same commands twice from reset give the same hash', async () => {
  const d = await start(['--nx', '24', '--ny', '24', '--paused']);
  const first = await script(d);
  const second = await script(d);
  assert.equal(second, first);
  // And a different script does not.
  await ok(d, 'POST', '/v1/sim/reset');
  await ok(d, 'POST', '/v1/sim/step', { frames: 1 });
  assert.notEqual(await hash(d), first);
  await stop(d);
});

test('while paused, a command is visible in the next read', async () => {
  const d = await start(['--nx', '8', '--ny', '8', '--paused', '--auto-drop-interval', '0']);
  const h0 = await hash(d);
  await ok(d, 'PATCH', '/v1/params', { gravity: [0, 0, -5] });
  assert.deepEqual((await ok(d, 'GET', '/v1/params')).gravity, [0, 0, -5]);
  const h1 = await hash(d);
  assert.notEqual(h1, h0); // the accelerations were recomputed for the new gravity
  const { id } = await ok(d, 'POST', '/v1/rocks', { position: [0, 0, 3], radius: 0.1 });
  assert.equal((await ok(d, 'GET', '/v1/sim')).n_rocks, 1);
  assert.equal((await ok(d, 'GET', `/v1/rocks/${id}`)).id, id);
  await ok(d, 'PUT', '/v1/pins', { preset: 'none' });
  await ok(d, 'PATCH', `/v1/rocks/${id}`, { position: [1, 1, 3] });
  assert.deepEqual((await ok(d, 'GET', `/v1/rocks/${id}`)).position, [1, 1, 3]);
  await ok(d, 'DELETE', `/v1/rocks/${id}`);
  assert.deepEqual((await ok(d, 'GET', '/v1/rocks')).rocks, []);
  const st = await ok(d, 'GET', '/v1/sim');
  assert.equal(st.step, 0); // paused: no time passed
  await stop(d);
});
