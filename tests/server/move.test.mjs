// move.test.mjs - a scene moves between two daemons by its snapshot (docs/operating.md "Moving a
// scene"): pause it on A, GET /v1/scenes/{id}/snapshot there, POST /v1/scenes with the same id and
// A's live parameters on B, PUT the snapshot there. The two are then the same scene, bitwise (the
// state hash and the snapshot's bytes), and stay so frame for frame. Two real daemons on 127.0.0.1.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { start, stop, call, ok } from './harness.mjs';

const OCTETS = { 'Content-Type': 'application/octet-stream' };
const ID = 'moved-1';
const at = (path) => `/v1/scenes/${ID}${path}`;

async function snapshot(d) {
  const r = await call(d, 'GET', at('/snapshot'));
  assert.equal(r.status, 200, r.text);
  return r.buf;
}

async function pausedHash(d) {
  const sim = await ok(d, 'GET', at('/sim'));
  assert.equal(sim.state, 'paused');
  return sim.state_hash;
}

// The move itself, as docs/operating.md tells it; returns the snapshot moved.
async function move(a, b) {
  await ok(a, 'POST', at('/sim/pause'));
  const snap = await snapshot(a);
  // The daemon-loop settings (drops, seed, checkpoints, speed) are not in a snapshot: they go
  // with the new scene's parameters.
  const params = await ok(a, 'GET', at('/params'));
  const made = await call(b, 'POST', '/v1/scenes', { id: ID, params });
  assert.equal(made.status, 201, made.text);
  assert.equal(made.headers.get('location'), `/v1/scenes/${ID}`);
  await ok(b, 'POST', at('/sim/pause'));
  const put = await call(b, 'PUT', at('/snapshot'), snap, OCTETS);
  assert.equal(put.status, 200, put.text);
  return { snap, put: put.json };
}

// A scene of A with rocks and some history, paused.
async function makeScene(a, params) {
  const made = await call(a, 'POST', '/v1/scenes', { id: ID, scene: { nx: 16, ny: 16 }, params });
  assert.equal(made.status, 201, made.text);
  await ok(a, 'POST', at('/sim/pause'));
  for (const x of [-0.3, 0.2]) await ok(a, 'POST', at('/rocks'), { position: [x, 0.1, 1.5], radius: 0.08 });
  await ok(a, 'PATCH', at('/params'), { wind: [1.5, 0, 0] });
  await ok(a, 'POST', at('/sim/step'), { frames: 40 });
}

test('a scene moved by its snapshot is bitwise the same on the other daemon, and stays so as both step', async () => {
  const a = await start(['--paused']);
  const b = await start(['--paused']);
  try {
    await makeScene(a, { auto_drop_interval: 0 });
    const { snap, put } = await move(a, b);
    const hA = await pausedHash(a);
    assert.equal(put.state_hash, hA);
    assert.equal(await pausedHash(b), hA);
    assert.ok(Buffer.from(await snapshot(b)).equals(Buffer.from(snap)), 'the snapshot bytes differ');
    const simA = await ok(a, 'GET', at('/sim'));
    const simB = await ok(b, 'GET', at('/sim'));
    for (const k of ['step', 'frame', 'sim_time', 'n_rocks', 'n_vertices']) assert.deepEqual(simB[k], simA[k], k);
    // The same frames on both: still the same, step by step.
    for (let i = 0; i < 3; i++) {
      const sa = await ok(a, 'POST', at('/sim/step'), { frames: 30 });
      const sb = await ok(b, 'POST', at('/sim/step'), { frames: 30 });
      assert.equal(sb.state_hash, sa.state_hash, `after ${30 * (i + 1)} frames`);
      assert.equal(sb.step, sa.step);
    }
    assert.ok(Buffer.from(await snapshot(b)).equals(Buffer.from(await snapshot(a))));
    // B's journal starts at the moved state; A's keeps its history.
    const jb = await ok(b, 'GET', at('/journal'));
    const ja = await ok(a, 'GET', at('/journal'));
    assert.equal(jb.base_step, simA.step);
    assert.equal(jb.entries.length, 0);
    assert.ok(ja.entries.length >= 3, JSON.stringify(ja));
    // The move ends with the scene deleted on A.
    await ok(a, 'DELETE', `/v1/scenes/${ID}`);
    assert.equal((await call(a, 'GET', at('/sim'))).status, 404);
  } finally {
    await stop(a);
    await stop(b);
  }
});

test('with automatic drops on, a moved scene restarts their sequence as any restore does: the same as its source restored', async () => {
  const a = await start(['--paused']);
  const b = await start(['--paused']);
  try {
    await makeScene(a, { auto_drop_interval: 0.5, auto_drop_max: 2, seed: 7 });
    // Drops happened on A before the move (its sequence is mid-way).
    assert.ok((await ok(a, 'GET', at('/journal'))).entries.some((e) => e.command.by === 'auto'));
    const { snap } = await move(a, b);
    // The drops' sequence and schedule are not in the snapshot: B restarts them from the seed. A
    // restored from the same snapshot does the same, and the two step alike through new drops.
    const back = await call(a, 'PUT', at('/snapshot'), snap, OCTETS);
    assert.equal(back.status, 200, back.text);
    assert.equal(await pausedHash(b), await pausedHash(a));
    const sa = await ok(a, 'POST', at('/sim/step'), { frames: 90 });
    const sb = await ok(b, 'POST', at('/sim/step'), { frames: 90 });
    assert.equal(sb.state_hash, sa.state_hash);
    const drops = (await ok(b, 'GET', at('/journal'))).entries.filter((e) => e.command.by === 'auto');
    assert.ok(drops.length >= 1, 'B dropped rocks after the move');
    assert.deepEqual(drops, (await ok(a, 'GET', at('/journal'))).entries.filter((e) => e.command.by === 'auto'));
  } finally {
    await stop(a);
    await stop(b);
  }
});
