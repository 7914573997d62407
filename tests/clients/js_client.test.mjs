// js_client.test.mjs - the JavaScript client (clients/js) against the real clothd (127.0.0.1,
// ephemeral ports, CPU backend): every operation of proto/openapi.yaml is reached by one of its
// methods (counted by the daemon's own /metrics), answers carry what the protocol says (checked
// against analytic values and against each other: the binary cloth state against the JSON one, a
// restored snapshot against the hash it was taken at), every refusal is the error class of its
// status with the problem's slug, detail and param and changes nothing, tokens (given, asked for,
// view-only), X-Request-Id, timeouts, an unreachable server, and scenes (list, create, delete, handles).
import { before, test } from 'node:test';
import assert from 'node:assert/strict';
import { writeFileSync } from 'node:fs';
import { join } from 'node:path';
import { start, stop, tempDir, until, SPEC } from '../server/harness.mjs';
import { pausedDaemon } from './support.mjs';
import * as clothd from '../../clients/js/src/index.js';

const { Client } = clothd;
const started = pausedDaemon();
let client;
before(async () => { client = await started; });

// HTTP requests the daemon answered with a 2xx, by "METHOD route" (its route patterns are the
// spec's paths).
async function answered(c) {
  const text = await c.metrics();
  const seen = new Map();
  for (const m of text.matchAll(/^clothd_http_requests_total\{route="([^"]+)",method="([A-Z]+)",status="(\d+)"\} (\d+)$/gm))
    if (m[3].startsWith('2')) seen.set(`${m[2]} ${m[1]}`, (seen.get(`${m[2]} ${m[1]}`) ?? 0) + Number(m[4]));
  return seen;
}

test('every operation of openapi.yaml is a client method, and the answers hold what the protocol says', async () => {
  const health = await client.health();
  assert.equal(health.status, 'ok');
  assert.equal(health.stream.protocol, 'clothd.v1');
  assert.deepEqual(await client.livez(), { status: 'live' });
  const ready = await client.readyz();
  assert.equal(ready.status, 'ready');
  assert.ok(ready.scenes >= 1 && ready.max_scenes >= ready.scenes, JSON.stringify(ready));
  assert.equal((await client.sim()).state, 'paused');
  assert.match((await client.sim({ hash: true })).state_hash, /^[0-9a-f]{16}$/);

  // Steps: the frame advances by the frames asked, the step by substeps per frame each.
  const s0 = await client.pause();
  const stepped = await client.step({ frames: 2 });
  assert.equal(stepped.frame, s0.frame + 2);
  assert.equal(stepped.step, s0.step + 2 * s0.substeps);
  assert.equal((await client.step({ substeps: 5 })).step, stepped.step + 5);
  assert.deepEqual(await client.cancelStep(), { cancelled: false, step: stepped.step + 5, frame: stepped.frame });
  assert.equal((await client.resume()).state, 'running');
  await client.pause();
  assert.equal((await client.reset()).applied_step >= 0, true);
  assert.equal((await client.sim()).step, 0);

  // Parameters and scene.
  assert.equal((await client.setParams({ k_bend: 31.5 })).params.k_bend, 31.5);
  assert.equal((await client.params()).k_bend, 31.5);
  const schema = await client.paramsSchema();
  assert.ok(schema.params.some((p) => p.name === 'k_bend' && p.kind === 'live'));
  assert.equal((await client.setScene({ nx: 24, ny: 20 })).nx, 24);
  assert.deepEqual([(await client.getScene()).ny, (await client.sim()).n_vertices], [20, 24 * 20]);

  // Rocks: mass is density 4/3 pi r^3.
  const added = await client.addRock({ position: [0, 0, 2], radius: 0.1, density: 300 });
  assert.ok(Math.abs(added.rock.mass - 300 * (4 / 3) * Math.PI * 0.001) < 1e-5, `mass ${added.rock.mass}`);
  assert.deepEqual((await client.rocks()).rocks.map((r) => r.id), [added.id]);
  assert.deepEqual((await client.rock(added.id)).position, [0, 0, 2]);
  assert.deepEqual((await client.setRock(added.id, { position: [0.5, 0, 2] })).rock.position, [0.5, 0, 2]);
  assert.equal((await client.removeRock(added.id)).id, added.id);
  await client.addRock({ position: [0, 0, 2], radius: 0.1 });
  await client.addRock({ position: [0.3, 0, 2], radius: 0.1 });
  assert.equal((await client.clearRocks()).removed, 2);

  // Pins and grab.
  assert.equal((await client.setPins({ preset: 'corners' })).pinned, 4);
  assert.equal((await client.grab(100, [0, 0, 1.5])).vertex, 100);
  await client.release();
  const ops = (await client.journal()).entries.map((e) => e.command.op);
  assert.deepEqual(ops.slice(-2), ['grab', 'release']);

  // The cloth state: the binary form holds the JSON form's numbers, as float32.
  const json = await client.clothState();
  const bin = await client.clothStateBinary();
  assert.equal(json.positions.length, 24 * 20);
  assert.equal(bin.positions.length, 3 * 24 * 20);
  assert.deepEqual(Array.from(bin.positions), json.positions.flat().map(Math.fround));
  assert.deepEqual(Array.from(bin.velocities), json.velocities.flat().map(Math.fround));

  // A snapshot restores the state it was taken in (its hash).
  const { state_hash: hash } = await client.sim();
  const snap = await client.snapshot();
  assert.ok(snap instanceof Uint8Array && snap.length > 1000);
  await client.step({ frames: 3 });
  assert.notEqual((await client.sim()).state_hash, hash);
  assert.equal((await client.restoreSnapshot(snap)).state_hash, hash);
  const bundle = await client.journalBundle();
  assert.deepEqual(Array.from(bundle.subarray(0, 8)), Array.from(snap.subarray(0, 8))); // the base snapshot first

  // The daemon's scenes: list, create, delete.
  assert.deepEqual((await client.scenes()).scenes.map((e) => e.id), ['default']);
  assert.equal((await client.createScene({ id: 'made', scene: { nx: 4, ny: 4 } })).n_vertices, 16);
  assert.deepEqual(await client.deleteScene('made'), { id: 'made', deleted: true });

  // Recordings, of the default scene and of another (both paused: each holds its first frame
  // and waits), listed, downloaded, deleted.
  assert.equal((await client.record({ seconds: 1, encoding: 'f32', id: 'ops' })).state, 'recording');
  await client.createScene({ id: 'rec', scene: { nx: 4, ny: 4 } });
  assert.equal((await client.scene('rec').record({ seconds: 1, id: 'ops2' })).scene, 'rec');
  assert.deepEqual((await client.recordings()).recordings.map((r) => r.id).sort(), ['ops', 'ops2']);
  const file = new Uint8Array(await client.recording('ops'));
  assert.equal(String.fromCharCode(...file.subarray(0, 4)), 'CLR1');
  assert.deepEqual(await client.deleteRecording('ops'), { id: 'ops', deleted: true });
  await client.deleteScene('rec');
  // Its scene went: the sim thread stops the recording when it drops the scene, just after the
  // DELETE's answer.
  await until('the deleted scene\'s recording stopped', async () => (await client.recordings()).recordings[0].state === 'stopped');
  assert.equal((await client.recordings()).recordings[0].reason, 'scene deleted');
  await client.deleteRecording('ops2');

  // Every operation of the spec was answered with a success (the metrics count this scrape's
  // own request from the next one on).
  await client.metrics();
  const seen = await answered(client);
  const missing = [], METHODS = ['get', 'put', 'post', 'patch', 'delete'];
  for (const [path, item] of Object.entries(SPEC.paths))
    for (const method of Object.keys(item).filter((k) => METHODS.includes(k)))
      if (!seen.get(`${method.toUpperCase()} ${path}`)) missing.push(`${method.toUpperCase()} ${path}`);
  assert.deepEqual(missing, []);
});

test('a refusal is the error of its status, with slug, detail and param, and changes nothing', async () => {
  await client.pause();
  const { state_hash: hash } = await client.sim();
  const cases = [
    [() => client.setParams({ k_bend: -1 }), clothd.Unprocessable, 422, 'out-of-range', 'k_bend'],
    [() => client.setParams({ no_such: 1 }), clothd.BadRequest, 400, 'unknown-field', 'no_such'],
    [() => client.setParams({ k_bend: 'stiff' }), clothd.Unprocessable, 422, 'wrong-type', 'k_bend'],
    [() => client.addRock({ position: 'here', radius: 0.1 }), clothd.BadRequest, 400, 'wrong-type', 'position'],
    [() => client.rock(999), clothd.NotFound, 404, 'not-found', 'id'],
    [() => client.removeRock(999), clothd.NotFound, 404, 'not-found', 'id'],
    [() => client.step({ frames: 0 }), clothd.Unprocessable, 422, 'out-of-range', 'frames'],
    [() => client.restoreSnapshot(new Uint8Array([1, 2, 3])), clothd.BadRequest, 400, 'bad-snapshot', null],
    [() => client.request('POST', '/v1/health'), clothd.MethodNotAllowed, 405, 'method-not-allowed', null],
    [() => client.request('GET', '/v1/no-such-route'), clothd.NotFound, 404, 'not-found', null],
  ];
  for (const [call, Class, status, slug, param] of cases) {
    const e = await call().then(() => null, (x) => x);
    assert.ok(e instanceof Class, `${call}: ${e}`);
    assert.ok(e instanceof clothd.ClientError && e instanceof clothd.ClothdError);
    assert.deepEqual([e.status, e.slug, e.param, e.type], [status, slug, param, `urn:clothd:problem:${slug}`], String(call));
    assert.ok(e.detail && e.message === e.detail, `${call}: detail ${e.detail}`);
    assert.match(e.requestId, /^js-[a-z0-9]+-\d+$/);
  }
  const e405 = await client.request('POST', '/v1/health').catch((x) => x);
  assert.ok(e405.allow.includes('GET'), String(e405.allow));
  // None of it changed the state: the same hash as before.
  assert.equal((await client.sim()).state_hash, hash);
  // While running, a step is 409.
  await client.resume();
  const conflict = await client.step({ frames: 1 }).catch((x) => x);
  assert.ok(conflict instanceof clothd.Conflict);
  assert.equal(conflict.slug, 'wrong-state');
  await client.pause();
});

test('the refused answers no request can be made to give here: 413, 429, 503 busy, a page that is not a problem', async () => {
  const d = await start(['--auto-drop-interval', '0', '--paused', '--max-body', '1024', '--rate-limit', '1', '--rate-burst', '2']);
  try {
    const c = new Client({ base: d.url });
    const big = await c.setParams({ k_bend: 1, pad: 'x'.repeat(2000) }).catch((x) => x);
    assert.ok(big instanceof clothd.PayloadTooLarge, String(big));
    assert.deepEqual([big.status, big.slug], [413, 'too-large']);
    let limited = null;
    for (let k = 0; k < 10 && !limited; k++) limited = await c.pause().then(() => null, (x) => x);
    assert.ok(limited instanceof clothd.RateLimited, String(limited));
    assert.equal(limited.slug, 'rate-limited');
    assert.ok(Number.isInteger(limited.retryAfter) && limited.retryAfter >= 1, `Retry-After ${limited.retryAfter}`);
  } finally {
    await stop(d);
  }
  // 503 busy needs a full command queue, which no test can hold still: the mapping alone, from
  // PROTOCOL.md's table.
  const busy = clothd.errorFromAnswer(503, 'application/problem+json',
    '{"type":"urn:clothd:problem:busy","title":"Busy","status":503,"detail":"the queue is full"}',
    { method: 'POST', path: '/v1/rocks', requestId: 'r-1', retryAfter: '1', allow: null });
  assert.ok(busy instanceof clothd.Busy && busy instanceof clothd.ServerError);
  assert.deepEqual([busy.status, busy.slug, busy.retryAfter, busy.detail], [503, 'busy', 1, 'the queue is full']);
  const gone = clothd.errorFromAnswer(503, 'application/problem+json',
    '{"type":"urn:clothd:problem:unavailable","title":"Unavailable","status":503,"detail":"backend failed"}',
    { method: 'GET', path: '/v1/snapshot', requestId: null, retryAfter: null, allow: null });
  assert.ok(gone instanceof clothd.Unavailable && !(gone instanceof clothd.Busy));
  // libmicrohttpd's own answers are HTML: still an error of the status, with the page as body.
  const html = clothd.errorFromAnswer(431, 'text/html', '<html><body>Request header too large</body></html>',
    { method: 'GET', path: '/v1/sim', requestId: null, retryAfter: null, allow: null });
  assert.ok(html instanceof clothd.ClientError);
  assert.deepEqual([html.status, html.slug, html.problem], [431, null, null]);
  assert.match(html.message, /header too large/);
});

test('tokens: none is 401, the view token reads and is 403 on changes, askToken is asked once', async () => {
  const dir = tempDir();
  const control = 'control-token-0123456789', viewer = 'view-token-0123456789ab';
  writeFileSync(join(dir, 'token'), control);
  writeFileSync(join(dir, 'view'), viewer);
  const d = await start(['--auto-drop-interval', '0', '--token-file', join(dir, 'token'), '--view-token-file', join(dir, 'view')]);
  try {
    const none = new Client({ base: d.url });
    assert.equal((await none.health()).status, 'ok'); // an open route
    const e401 = await none.sim().catch((x) => x);
    assert.ok(e401 instanceof clothd.Unauthorized);
    assert.equal(e401.slug, 'unauthorized');
    const view = new Client({ base: d.url, token: viewer });
    assert.equal(typeof (await view.params()).k_bend, 'number');
    const e403 = await view.pause().catch((x) => x);
    assert.ok(e403 instanceof clothd.Forbidden);
    assert.equal(e403.slug, 'forbidden');
    const asked = [];
    const asking = new Client({ base: d.url, askToken: async (reason) => { asked.push(reason); return control; } });
    assert.equal((await asking.pause()).state, 'paused');
    assert.equal((await asking.resume()).state, 'running');
    assert.equal(asked.length, 1);
    assert.equal(asking.token, control);
    // A page that has no token to give: the 401 is thrown.
    const refusing = new Client({ base: d.url, askToken: async () => null });
    assert.ok((await refusing.sim().catch((x) => x)) instanceof clothd.Unauthorized);
  } finally {
    await stop(d);
  }
});

test('timeouts, an unreachable server, X-Request-Id checks', async () => {
  await client.pause();
  // A step of 100000 frames takes minutes here; a 100 ms step timeout gives up on it.
  const hurried = client.withOptions({ stepTimeout: 100 });
  const t = await hurried.step({ frames: 100000 }).catch((x) => x);
  assert.ok(t instanceof clothd.TimeoutError, String(t));
  assert.equal(t.status, null);
  // The step goes on in the daemon until it is cancelled.
  const cancelled = await client.cancelStep();
  assert.equal(cancelled.cancelled, true);
  const nowhere = new Client({ base: 'http://127.0.0.1:9', timeout: 2000 });
  const c = await nowhere.health().catch((x) => x);
  assert.ok(c instanceof clothd.ConnectionError, String(c));
  assert.match(c.message, /cannot reach clothd at http:\/\/127\.0\.0\.1:9/);
  assert.throws(() => client.withOptions({ requestId: 'has space' }), TypeError);
  assert.throws(() => new Client({ requestIdPrefix: 'x'.repeat(130) }), TypeError);
  const tagged = client.withOptions({ requestId: 'tagged-request.1' });
  const e = await tagged.rock(12345).catch((x) => x);
  assert.equal(e.requestId, 'tagged-request.1');
});

test('scenes: list, create, delete; a handle reaches its own scene, default the routes without a prefix', async () => {
  const def = client.scene('default');
  assert.equal(def.prefix, '/v1');
  await client.pause();
  assert.equal((await def.sim()).step, (await client.sim()).step);
  assert.throws(() => client.scene('Not A Scene'), TypeError);
  assert.throws(() => client.scene(''), TypeError);
  assert.throws(() => client.createScene({ id: 'Bad Id' }), TypeError);
  // A scene of its own size and parameters, made and listed by the server.
  const made = await client.createScene({ id: 'other', scene: { nx: 7, ny: 5 }, params: { k_bend: 0.02 } });
  assert.deepEqual([made.id, made.n_vertices], ['other', 35]);
  const other = client.scene('other');
  assert.equal(other.prefix, '/v1/scenes/other');
  assert.deepEqual((await client.scenes()).scenes.map((x) => x.id).sort(), ['default', 'other']);
  assert.equal((await other.params()).k_bend, 0.02);
  await other.addRock({ position: [0, 0, 1.5], radius: 0.1 });
  assert.equal((await other.rocks()).rocks.length, 1);
  assert.equal((await client.rocks()).rocks.length, 0); // nothing reached the default scene
  // The server's refusals come through as their classes: an id taken 409, an unknown one 404.
  assert.ok((await client.createScene({ id: 'other' }).catch((x) => x)) instanceof clothd.Conflict);
  await client.deleteScene('other');
  for (const call of [() => other.sim(), () => client.deleteScene('other'), () => other.record({ seconds: 1 })]) {
    const e = await call().catch((x) => x);
    assert.ok(e instanceof clothd.NotFound, `${call}: ${e}`);
  }
  assert.deepEqual((await client.scenes()).scenes.map((x) => x.id), ['default']);
});
