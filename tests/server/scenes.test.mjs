// scenes.test.mjs - many scenes in one daemon (PROTOCOL.md, "Scenes"): creating, listing and
// deleting them, and the refusals that leave the table as it was (a bad id 400, an unknown one 404,
// an existing one 409, max_scenes and the shared max_state_mb 422); every route of a scene under
// /v1/scenes/{scene}/ answering as the same route without the prefix answers for "default" (the
// route table walked); parallel creates and deletes from many clients leaving the table
// consistent; a scene's state hash the same alone and beside others created and deleted while it
// runs; one scene's instability rolling back that scene only; the state file keeping every scene.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { writeFileSync } from 'node:fs';
import { join } from 'node:path';
import { start, stop, call, ok, until, tempDir, execChecked, refusedStart, CLOTHD, TESTHOOKS, PROBLEM } from './harness.mjs';

const small = ['--nx', '8', '--ny', '8', '--auto-drop-interval', '0'];
const ids = async (d) => (await ok(d, 'GET', '/v1/scenes')).scenes.map((s) => s.id);

test('scenes are created, listed and deleted; bad ids, unknown, existing, max_scenes and the memory cap are refused and change nothing', async () => {
  // max_state_mb 10: a scene of 70 x 70 (9.7 MB with implicit_euler's workspace, its checkpoints
  // and the stream's buffers) fits alone, not beside the default 8 x 8 scene and another (about
  // 0.7 MB each).
  const d = await start([...small, '--paused', '--max-scenes', '3', '--max-state-mb', '10']);
  const made = await call(d, 'POST', '/v1/scenes', { id: 'b', scene: { nx: 6, ny: 5 }, params: { time_scale: 0.5 } });
  assert.equal(made.status, 201);
  assert.equal(made.headers.get('location'), '/v1/scenes/b');
  assert.equal(made.json.id, 'b');
  assert.equal(made.json.n_vertices, 30);
  assert.equal(made.json.state, 'running');
  assert.equal((await ok(d, 'GET', '/v1/scenes/b/params')).time_scale, 0.5);
  assert.equal((await ok(d, 'GET', '/v1/params')).time_scale, 1); // default's own
  const listed = await ok(d, 'GET', '/v1/scenes');
  assert.deepEqual(listed.scenes.map((s) => [s.id, s.n_vertices]), [['default', 64], ['b', 30]]);
  assert.equal(listed.max_scenes, 3);
  assert.ok(listed.state_mb > 0.5 && listed.state_mb <= 2, JSON.stringify(listed));
  const before = await ids(d);
  const refusals = [
    ['POST', '/v1/scenes', { id: 'Bad' }, 400, 'bad-scene-id'],
    ['POST', '/v1/scenes', { id: 'a'.repeat(64) }, 400, 'bad-scene-id'],
    ['POST', '/v1/scenes', { id: '-a' }, 400, 'bad-scene-id'],
    ['POST', '/v1/scenes', { id: 7 }, 400, 'wrong-type'],
    ['POST', '/v1/scenes', { id: 'c', colour: 'red' }, 400, 'unknown-field'],
    ['POST', '/v1/scenes', { id: 'c', scene: { k_bend: 1 } }, 400, 'unknown-field'],
    ['POST', '/v1/scenes', { id: 'c', scene: { nx: 1 } }, 422, null],
    ['POST', '/v1/scenes', { id: 'b' }, 409, 'exists'],
    ['POST', '/v1/scenes', { id: 'big', scene: { nx: 70, ny: 70 } }, 422, 'limit'],
    ['GET', '/v1/scenes/Bad/sim', undefined, 400, 'bad-scene-id'],
    ['GET', '/v1/scenes/nope/sim', undefined, 404, 'not-found'],
    ['DELETE', '/v1/scenes/nope', undefined, 404, 'not-found'],
    ['DELETE', '/v1/scenes/B', undefined, 400, 'bad-scene-id'],
  ];
  for (const [method, path, body, status, slug] of refusals) {
    const r = await call(d, method, path, body);
    assert.equal(r.status, status, `${method} ${path} ${JSON.stringify(body)}: ${r.text}`);
    assert.equal(r.type, PROBLEM);
    if (slug) assert.equal(r.json.type, `urn:clothd:problem:${slug}`, r.text);
    assert.deepEqual(await ids(d), before, `${method} ${path} changed the table`);
  }
  assert.equal((await call(d, 'POST', '/v1/scenes', { id: 'big', scene: { nx: 70, ny: 70 } })).json.param, 'max_state_mb');
  // A made-up id; then the table is full.
  const gen = await ok(d, 'POST', '/v1/scenes', {});
  assert.match(gen.id, /^scene-\d+$/);
  const full = await call(d, 'POST', '/v1/scenes', { id: 'd' });
  assert.equal(full.status, 422);
  assert.equal(full.json.param, 'max_scenes');
  assert.deepEqual(await ids(d), ['default', 'b', gen.id]);
  // Growing a scene past what the others leave is refused the same way (PUT scene), and changes nothing.
  const grow = await call(d, 'PUT', '/v1/scenes/b/scene', { nx: 70, ny: 70 });
  assert.equal(grow.status, 422, grow.text);
  assert.equal((await ok(d, 'GET', '/v1/scenes/b/sim')).n_vertices, 30);
  // Deleted: its routes are gone, the others stay; default may go too.
  assert.deepEqual(await ok(d, 'DELETE', '/v1/scenes/b'), { id: 'b', deleted: true });
  assert.equal((await call(d, 'GET', '/v1/scenes/b/sim')).status, 404);
  assert.equal((await call(d, 'DELETE', '/v1/scenes/b')).status, 404);
  await ok(d, 'DELETE', '/v1/scenes/default');
  const gone = await call(d, 'GET', '/v1/sim');
  assert.equal(gone.status, 404);
  assert.equal(gone.json.param, 'scene');
  assert.deepEqual(await ids(d), [gen.id]);
  // The room they held is free again: the 70 x 70 scene fits now that the others are gone.
  await ok(d, 'DELETE', `/v1/scenes/${gen.id}`);
  assert.equal((await call(d, 'POST', '/v1/scenes', { id: 'big', scene: { nx: 70, ny: 70 } })).status, 201);
  await stop(d);
});

// Example requests for each route of a scene (the path below the prefix), in an order that works
// on a paused scene of 8 x 8 at step 0. The test fails when a route of the table has none.
const examples = [
  ['GET', '/sim'], ['GET', '/params'], ['GET', '/params/schema'], ['GET', '/scene'], ['GET', '/rocks'],
  ['POST', '/recordings', { seconds: 0.1, encoding: 'f32' }], ['POST', '/rocks', { position: [0, 0, 3], radius: 0.1 }], ['GET', '/rocks/1'], ['PATCH', '/rocks/1', { radius: 0.2 }],
  ['DELETE', '/rocks/1'], ['DELETE', '/rocks'], ['PATCH', '/params', { seed: 5 }], ['PUT', '/pins', { preset: 'corners' }],
  ['PUT', '/grab', { vertex: 3, target: [0, 0, 1] }], ['POST', '/sim/step', { frames: 2 }], ['DELETE', '/grab'],
  ['DELETE', '/sim/step'], ['GET', '/cloth/state'], ['GET', '/snapshot'], ['PUT', '/snapshot'], ['GET', '/journal'],
  ['PUT', '/scene', { nx: 6 }], ['POST', '/sim/reset'], ['POST', '/sim/resume'], ['POST', '/sim/pause'],
];

test('every route of a scene answers under /v1/scenes/{scene}/ as it does without the prefix for default', async () => {
  const { stdout } = await execChecked(CLOTHD, ['routes']);
  const prefixed = stdout.trim().split('\n').filter((l) => l.includes('/v1/scenes/{scene}/'))
    .map((l) => l.replace('/v1/scenes/{scene}', '').replace('{id}', '1')).sort();
  assert.deepEqual(examples.map(([m, p]) => `${m} ${p}`).sort(), prefixed, 'an example for every route of a scene');
  const d = await start([...small, '--paused']);
  await ok(d, 'POST', '/v1/scenes', { id: 'twin' });
  await ok(d, 'POST', '/v1/scenes/twin/sim/pause');
  await ok(d, 'POST', '/v1/scenes/twin/sim/reset'); // both at step 0 of the same scene now
  await ok(d, 'POST', '/v1/sim/reset');
  let snapshot;
  for (const [method, path, body] of examples) {
    const send = path === '/snapshot' && method === 'PUT' ? snapshot : body;
    const a = await call(d, method, `/v1${path}`, send);
    const b = await call(d, method, `/v1/scenes/twin${path}`, send);
    const what = `${method} ${path}`;
    assert.equal(b.status, a.status, `${what}: ${b.text} vs ${a.text}`);
    assert.ok(a.status < 300, `${what}: ${a.text}`);
    assert.equal(b.type, a.type, what);
    if (method === 'GET' && path === '/snapshot') snapshot = a.buf;
    if (path === '/sim/resume' || path === '/sim/pause') assert.equal(b.json.state, a.json.state, what);
    else if (path === '/recordings') { // a recording of each scene (ids made up: rec-1, rec-2)
      assert.deepEqual([a.json.scene, b.json.scene], ['default', 'twin']);
      assert.deepEqual({ ...b.json, id: 0, scene: 0 }, { ...a.json, id: 0, scene: 0 }, what);
    }
    else if (a.json) assert.deepEqual(b.json, a.json, what);
    else assert.ok(b.buf.equals(a.buf), `${what}: the same bytes`);
  }
  await stop(d);
});

test("a scene's metrics carry its id; deleting it ends its step in progress and its series", async () => {
  const d = await start([...small, '--paused']);
  await ok(d, 'POST', '/v1/scenes', { id: 'long', scene: { nx: 48, ny: 48 } });
  await ok(d, 'POST', '/v1/scenes/long/rocks', { position: [0, 0, 3], radius: 0.1 });
  await ok(d, 'POST', '/v1/scenes/long/sim/pause');
  const text = (await call(d, 'GET', '/metrics')).text;
  assert.match(text, /^clothd_vertices\{scene="default"\} 64$/m);
  assert.match(text, /^clothd_vertices\{scene="long"\} 2304$/m);
  assert.match(text, /^clothd_rocks\{scene="long"\} 1$/m);
  const step = call(d, 'POST', '/v1/scenes/long/sim/step', { frames: 100000 });
  const s0 = (await ok(d, 'GET', '/v1/scenes/long/sim')).step;
  await until('the step runs', async () => (await ok(d, 'GET', '/v1/scenes/long/sim')).step > s0);
  await ok(d, 'DELETE', '/v1/scenes/long');
  const ended = await step;
  assert.equal(ended.status, 200, ended.text);
  assert.equal(ended.json.interrupted_by, 'deleted');
  assert.ok(ended.json.frames_run < 100000);
  const after = (await call(d, 'GET', '/metrics')).text;
  assert.doesNotMatch(after, /scene="long"/);
  assert.match(after, /^clothd_paused\{scene="default"\} 1$/m);
  await stop(d);
});

test('parallel creates and deletes from many clients leave the table consistent', async () => {
  const d = await start([...small, '--paused', '--max-scenes', '16', '--http-threads', '8']);
  const names = Array.from({ length: 10 }, (_, k) => `p${k}`);
  const ops = [];
  for (let round = 0; round < 4; round++)
    for (const id of names) ops.push({ id, create: (round + id.charCodeAt(1)) % 2 === 0 || round === 0 });
  const answers = await Promise.all(ops.map(async (o) => {
    const r = o.create ? await call(d, 'POST', '/v1/scenes', { id: o.id, scene: { nx: 24, ny: 24 } })
      : await call(d, 'DELETE', `/v1/scenes/${o.id}`);
    return { ...o, status: r.status };
  }));
  const listed = new Set(await ids(d));
  for (const id of names) {
    const mine = answers.filter((a) => a.id === id);
    for (const a of mine) assert.ok(a.create ? [201, 409].includes(a.status) : [200, 404].includes(a.status), JSON.stringify(a));
    // Successful creates and deletes of one id alternate, starting with a create: the id exists
    // exactly when there was one more successful create than delete.
    const made = mine.filter((a) => a.create && a.status === 201).length;
    const removed = mine.filter((a) => !a.create && a.status === 200).length;
    assert.ok(made - removed === 0 || made - removed === 1, `${id}: ${made} created, ${removed} deleted`);
    assert.equal(listed.has(id), made - removed === 1, id);
    if (listed.has(id)) assert.equal((await ok(d, 'GET', `/v1/scenes/${id}/sim`)).n_vertices, 576);
    else assert.equal((await call(d, 'GET', `/v1/scenes/${id}/sim`)).status, 404);
  }
  assert.equal(listed.size, names.filter((id) => listed.has(id)).length + 1); // and default
  await stop(d);
});

// The same commands at the same steps on a paused scene of 10 x 9 (with automatic drops): its hash.
async function script(d, base) {
  await ok(d, 'POST', `${base}/sim/pause`);
  await ok(d, 'POST', `${base}/sim/reset`);
  await ok(d, 'POST', `${base}/rocks`, { position: [0.1, 0, 3], radius: 0.15 });
  await ok(d, 'POST', `${base}/sim/step`, { frames: 1000 });
  await ok(d, 'PATCH', `${base}/params`, { k_bend: 0.002 });
  await ok(d, 'POST', `${base}/sim/step`, { frames: 9 });
  return (await ok(d, 'GET', `${base}/sim`)).state_hash;
}

test("a scene's state hash is the same alone and beside others created and deleted while it runs", async () => {
  const fields = ['--nx', '10', '--ny', '9', '--auto-drop-interval', '0.1'];
  const lone = await start([...fields, '--paused']);
  const alone = await script(lone, '/v1');
  await stop(lone);
  const d = await start([...fields, '--max-scenes', '12']);
  const others = [
    { scene: { nx: 12, ny: 12 } }, { scene: { nx: 7, ny: 20 } }, { params: { k_bend: 0.01 } }, { params: { time_scale: 2 } },
    { scene: { nx: 16, ny: 16 }, params: { max_speed: true } }, { params: { auto_drop_interval: 0.05 } }, {},
  ];
  for (const [k, o] of others.entries()) await ok(d, 'POST', '/v1/scenes', { id: `o${k}`, ...o });
  await ok(d, 'POST', '/v1/scenes', { id: 'x' });
  // Beside 7 running scenes (their frames stepped together), with one deleted and two created part
  // way, and beside default running the same commands at the same time (the frames of the two
  // steps stepped together too).
  const runs = Promise.all([script(d, '/v1/scenes/x'), script(d, '/v1')]);
  await ok(d, 'DELETE', '/v1/scenes/o2');
  await ok(d, 'POST', '/v1/scenes', { id: 'late', scene: { nx: 9, ny: 9 } });
  await ok(d, 'POST', '/v1/scenes', { id: 'later', params: { max_speed: true } });
  assert.deepEqual(await runs, [alone, alone]);
  // Its journal bundle replays to its own hash.
  const bundle = await call(d, 'GET', '/v1/scenes/x/journal', undefined, { Accept: 'application/octet-stream' });
  const file = join(tempDir(), 'x.replay');
  writeFileSync(file, bundle.buf);
  const { stdout } = await execChecked(CLOTHD, ['replay', file, '--backend', 'cpu'], { env: { OMP_WAIT_POLICY: 'passive' } });
  assert.equal(stdout.trim(), alone);
  for (const s of (await ok(d, 'GET', '/v1/scenes')).scenes)
    if (!['x', 'default'].includes(s.id)) assert.equal(s.state, 'running', s.id);
  await stop(d);
});

test('one scene that stops being finite is rolled back and paused; the others run on', { skip: !TESTHOOKS && 'CLOTHD_TESTHOOKS_BIN is not set' }, async () => {
  // The hook poisons the first scene to reach frame 40: default, which ran before b was made.
  const d = await start([...small, '--checkpoint-interval', '10'], { bin: TESTHOOKS, env: { CLOTHD_TEST_NAN_FRAME: '40' } });
  await ok(d, 'POST', '/v1/scenes', { id: 'b' });
  const hit = await until('the rollback', async () => {
    const s = await ok(d, 'GET', '/v1/sim');
    return s.last_event?.type === 'instability' && s;
  });
  assert.equal(hit.state, 'paused');
  const b0 = await ok(d, 'GET', '/v1/scenes/b/sim');
  assert.equal(b0.state, 'running');
  assert.equal(b0.last_event, null);
  await until('b runs on', async () => (await ok(d, 'GET', '/v1/scenes/b/sim')).step > b0.step);
  assert.equal((await ok(d, 'GET', '/v1/sim')).step, hit.step); // default stays where it was rolled back to
  await stop(d);
});

test('the state file keeps every scene, paused ones paused, and a restart resumes each', async () => {
  const state = join(tempDir(), 'state.bin');
  const a = await start([...small, '--state-file', state]);
  await ok(a, 'POST', '/v1/scenes', { id: 'b', scene: { nx: 10, ny: 10 } });
  await ok(a, 'POST', '/v1/scenes', { id: 'c', params: { time_scale: 0.5, seed: 7 } });
  await until('b runs', async () => (await ok(a, 'GET', '/v1/scenes/b/sim')).step > 0);
  const b = await ok(a, 'POST', '/v1/scenes/b/sim/pause');
  const bHash = (await ok(a, 'GET', '/v1/scenes/b/sim?hash=1')).state_hash;
  const c = await ok(a, 'GET', '/v1/scenes/c/sim');
  assert.equal((await stop(a)).code, 0);
  assert.match(a.log, /state saved to .* \(3 scenes: 1 paused, 2 running\)/);
  const few = await refusedStart([...small, '--state-file', state, '--max-scenes', '2']);
  assert.equal(few.code, 1);
  assert.match(few.log, /it holds 3 scenes, more than max_scenes \(2\): raise max_scenes/);
  const r = await start([...small, '--state-file', state]);
  assert.deepEqual((await ok(r, 'GET', '/v1/scenes')).scenes.map((s) => [s.id, s.state]),
    [['default', 'running'], ['b', 'paused'], ['c', 'running']]);
  const b2 = await ok(r, 'GET', '/v1/scenes/b/sim');
  assert.equal(b2.step, b.step);
  assert.equal(b2.state_hash, bHash);
  assert.equal(b2.n_vertices, 100);
  const p = await ok(r, 'GET', '/v1/scenes/c/params');
  assert.deepEqual([p.time_scale, p.seed], [0.5, 7]);
  assert.ok((await ok(r, 'GET', '/v1/scenes/c/sim')).step >= c.step);
  assert.match(r.log, /resumed the scene 'b' from .* paused as it was saved/);
  // Deleted scenes are not saved; a daemon of one "default" writes the one-scene format again.
  await ok(r, 'DELETE', '/v1/scenes/b');
  await ok(r, 'DELETE', '/v1/scenes/c');
  assert.equal((await stop(r)).code, 0);
  assert.match(r.log, /state saved to .* \(running\)/);
  const s = await start([...small, '--state-file', state]);
  assert.deepEqual(await ids(s), ['default']);
  await stop(s);
});
