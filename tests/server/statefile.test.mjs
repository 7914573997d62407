// statefile.test.mjs - the state file keeps the run state: a scene saved paused comes back
// paused after a restart, one saved running comes back running (--paused pauses it all the
// same); and the daemon-loop settings, which the engine's snapshot does not hold. The format
// keeps older files loadable - format 2 (the run state, no settings), format 1 (the bare snapshot
// clothd wrote before, which resumes as it did then: running), and a file clothd 0.1.0 wrote,
// whose snapshot still held the daemon-loop settings among the engine's parameters - and refuses
// the others clearly: a newer format, a damaged trailer, a journal bundle.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { copyFileSync, readFileSync, writeFileSync } from 'node:fs';
import { join } from 'node:path';
import { start, stop, call, ok, pause, until, tempDir, refusedStart } from './harness.mjs';

const small = ['--nx', '8', '--ny', '8', '--auto-drop-interval', '0'];

// The snapshot a state file starts with (its header says how long it is), and what follows.
function split(file) {
  const len = 32 + Number(file.readBigUInt64LE(16));
  return { snapshot: file.subarray(0, len), trailer: file.subarray(len).toString() };
}

test('a state saved paused comes back paused, one saved running comes back running', async () => {
  const dir = tempDir();
  const state = join(dir, 'state.bin');
  // Saved paused.
  const a = await start([...small, '--state-file', state]);
  await until('a few frames', async () => (await ok(a, 'GET', '/v1/sim')).step > 0);
  const p = await pause(a);
  assert.equal((await stop(a)).code, 0);
  assert.match(a.log, /state saved to .* \(paused\)/);
  const loop = { time_scale: 1, max_speed: false, auto_drop_interval: 0, auto_drop_max: 8, seed: 1, checkpoint_interval: 60 };
  assert.deepEqual(JSON.parse(split(readFileSync(state)).trailer), { clothd_state: 3, run: 'paused', params: loop });
  const b = await start([...small, '--state-file', state]);
  const back = await ok(b, 'GET', '/v1/sim');
  assert.equal(back.state, 'paused');
  assert.equal(back.step, p.step);
  assert.equal(back.state_hash, p.state_hash);
  assert.match(b.log, /resumed from .* paused as it was saved/);
  // Still paused a while later: nothing runs it.
  assert.equal((await ok(b, 'POST', '/v1/sim/step', { frames: 1 })).step, p.step + p.substeps);
  // Saved running.
  await ok(b, 'POST', '/v1/sim/resume');
  assert.equal((await stop(b)).code, 0);
  assert.match(b.log, /state saved to .* \(running\)/);
  assert.equal(JSON.parse(split(readFileSync(state)).trailer).run, 'running');
  const c = await start([...small, '--state-file', state]);
  assert.equal((await ok(c, 'GET', '/v1/sim')).state, 'running');
  const s0 = (await ok(c, 'GET', '/v1/sim')).step;
  await until('it runs', async () => (await ok(c, 'GET', '/v1/sim')).step > s0);
  assert.equal((await stop(c)).code, 0);
  // --paused pauses a state saved running.
  const e = await start([...small, '--state-file', state, '--paused']);
  assert.equal((await ok(e, 'GET', '/v1/sim')).state, 'paused');
  await stop(e);
});

test('a state file of format 2 or 1 (the bare snapshot) still resumes; a newer format, a bad trailer, a bundle are refused', async () => {
  const dir = tempDir();
  const state = join(dir, 'state.bin');
  const a = await start([...small, '--paused', '--state-file', state]);
  await ok(a, 'POST', '/v1/sim/step', { frames: 3 });
  const bundle = (await call(a, 'GET', '/v1/journal', undefined, { Accept: 'application/octet-stream' })).buf;
  const h = (await ok(a, 'GET', '/v1/sim')).state_hash;
  await stop(a);
  const { snapshot } = split(readFileSync(state));
  // Format 1: what clothd wrote before the trailer. It resumes, running, as it did then.
  writeFileSync(state, snapshot);
  const b = await start([...small, '--state-file', state]);
  assert.match(b.log, /resumed from .* running as it was saved \(a state file of format 1, which kept no run state\)/);
  assert.equal((await ok(b, 'GET', '/v1/sim')).state, 'running');
  await stop(b, 'SIGKILL');
  writeFileSync(state, snapshot);
  const b2 = await start([...small, '--state-file', state, '--paused']);
  assert.equal((await ok(b2, 'GET', '/v1/sim')).state_hash, h);
  await stop(b2, 'SIGKILL');
  // Format 2: the run state, no daemon-loop settings (those of the configuration hold).
  writeFileSync(state, Buffer.concat([snapshot, Buffer.from('{"clothd_state":2,"run":"paused"}')]));
  const b3 = await start([...small, '--state-file', state, '--time-scale', '3']);
  assert.match(b3.log, /resumed from .* paused as it was saved/);
  assert.equal((await ok(b3, 'GET', '/v1/sim')).state_hash, h);
  assert.equal((await ok(b3, 'GET', '/v1/params')).time_scale, 3);
  await stop(b3, 'SIGKILL');
  const cases = [
    ['a newer format', '{"clothd_state":5,"run":"paused","params":{}}', /it was written by a newer clothd \(state file format 5; this build reads formats 1 to 4\)/],
    ['an unknown run state', '{"clothd_state":2,"run":"sleeping"}', /it is damaged \(has a trailer that is not/],
    ['a trailer cut short', '{"clothd_state":2,"ru', /it is damaged \(has 21 bytes after its snapshot that are not a state file's trailer/],
    ['another member', '{"clothd_state":2,"run":"paused","x":1}', /it is damaged/],
    ['format 3 without params', '{"clothd_state":3,"run":"paused"}', /it is damaged \(has a trailer that is not/],
    ['an engine parameter in params', '{"clothd_state":3,"run":"paused","params":{"k_bend":3}}',
      /it is damaged \(has a trailer whose params are refused: 'k_bend' is not a daemon-loop setting\)/],
    ['a setting out of range', '{"clothd_state":3,"run":"paused","params":{"time_scale":0}}', /it is damaged \(.*time_scale must be between/],
  ];
  for (const [what, trailer, reason] of cases) {
    const bad = Buffer.concat([snapshot, Buffer.from(trailer)]);
    writeFileSync(state, bad);
    const r = await refusedStart([...small, '--state-file', state]);
    assert.equal(r.code, 1, what);
    assert.match(r.log, reason, what);
    assert.match(r.log, /--state-file-invalid fresh/, what);
    assert.ok(readFileSync(state).equals(bad), `${what}: left as it was`);
  }
  // A journal bundle is a snapshot followed by other JSON: not a state file.
  writeFileSync(state, bundle);
  const r = await refusedStart([...small, '--state-file', state]);
  assert.match(r.log, /it is not a clothd state file \(is not a state file: its snapshot is followed by other JSON \(a journal bundle\?\)\)/);
});

test('the daemon-loop settings survive a restart; a state file clothd 0.1.0 wrote resumes with those its snapshot held', async () => {
  const dir = tempDir();
  const state = join(dir, 'state.bin');
  const a = await start([...small, '--paused', '--state-file', state]);
  await ok(a, 'PATCH', '/v1/params', { time_scale: 0.5, seed: 9, checkpoint_interval: 7 });
  assert.equal((await stop(a)).code, 0);
  const b = await start([...small, '--state-file', state]);
  const p = await ok(b, 'GET', '/v1/params');
  assert.deepEqual([p.time_scale, p.seed, p.checkpoint_interval, p.auto_drop_interval], [0.5, 9, 7, 0]);
  await stop(b);
  // tests/data/clothd-0.1.0.state: written by clothd 0.1.0 (format 2; the daemon-loop settings
  // among its snapshot's parameters) with --nx 6 --ny 5 --time-scale 2.5 --seed 7
  // --auto-drop-interval 0.75 --auto-drop-max 3 --checkpoint-interval 17 --max-speed true
  // --k-bend 33, a rock added and 3 frames stepped, paused: step 90, state hash aaf84cac7b29ecbf.
  copyFileSync(join(process.env.CLOTHD_SOURCE, 'tests', 'data', 'clothd-0.1.0.state'), state);
  const c = await start(['--state-file', state]);
  assert.match(c.log, /resumed from .* paused as it was saved; its daemon-loop settings from its snapshot/);
  const sim = await ok(c, 'GET', '/v1/sim');
  assert.deepEqual([sim.state, sim.step, sim.state_hash, sim.n_rocks], ['paused', 90, 'aaf84cac7b29ecbf', 1]);
  const q = await ok(c, 'GET', '/v1/params');
  assert.deepEqual([q.time_scale, q.seed, q.auto_drop_interval, q.auto_drop_max, q.checkpoint_interval, q.max_speed, q.k_bend],
    [2.5, 7, 0.75, 3, 17, true, 33]);
  // Its snapshot PUT into a running daemon brings the settings it holds too, as it did then.
  const d = await start(small);
  const old = split(readFileSync(state)).snapshot;
  const put = await call(d, 'PUT', '/v1/snapshot', old, { 'Content-Type': 'application/octet-stream' });
  assert.equal(put.status, 200, put.text);
  assert.equal(put.json.state_hash, 'aaf84cac7b29ecbf');
  assert.equal((await ok(d, 'GET', '/v1/params')).time_scale, 2.5);
  await stop(d);
  // Saved again, it is a state file of this format, with the same settings.
  assert.equal((await stop(c)).code, 0);
  const t = JSON.parse(split(readFileSync(state)).trailer);
  assert.equal(t.clothd_state, 3);
  assert.deepEqual(t.params, { time_scale: 2.5, max_speed: true, auto_drop_interval: 0.75, auto_drop_max: 3, seed: 7, checkpoint_interval: 17 });
});
