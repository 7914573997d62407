// statefile.test.mjs - the state file keeps the run state: a scene saved paused comes back
// paused after a restart, one saved running comes back running (--paused pauses it all the
// same). The format keeps older files loadable - format 1, the bare snapshot clothd wrote
// before, resumes as it did then (running) - and refuses the others clearly: a newer format, a
// damaged trailer, a journal bundle.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync, writeFileSync } from 'node:fs';
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
  assert.deepEqual(JSON.parse(split(readFileSync(state)).trailer), { clothd_state: 2, run: 'paused' });
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

test('a state file of format 1 (the bare snapshot) still resumes; a newer format, a bad trailer, a bundle are refused', async () => {
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
  const cases = [
    ['a newer format', '{"clothd_state":3,"run":"paused"}', /it was written by a newer clothd \(state file format 3; this build reads formats 1 to 2\)/],
    ['an unknown run state', '{"clothd_state":2,"run":"sleeping"}', /it is damaged \(has a trailer that is not/],
    ['a trailer cut short', '{"clothd_state":2,"ru', /it is damaged \(has 21 bytes after its snapshot that are not a state file's trailer/],
    ['another member', '{"clothd_state":2,"run":"paused","x":1}', /it is damaged/],
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
