// streamscenes.test.mjs - the stream of a daemon with several scenes: each scene streams its own
// frames (told apart by their vertex counts), a subscribe naming another scene switches, ids that
// are invalid or unknown are refused (at the upgrade and in a subscribe), and deleting a scene
// closes its clients with 1001 and a reason while the others stream on.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import WebSocket from 'ws';
import { stop, ok, call, until, metric } from './harness.mjs';
import { connect, next, daemon } from './wsclient.mjs';

// The HTTP answer to an upgrade that is refused: status and problem+json body.
function refusal(d, query) {
  return new Promise((resolve, reject) => {
    const ws = new WebSocket(`ws://127.0.0.1:${d.streamPort}/stream${query}`, 'clothd.v1');
    ws.on('open', () => reject(new Error(`the stream${query} opened`)));
    ws.on('unexpected-response', (req, res) => {
      let body = '';
      res.on('data', (b) => { body += b; });
      res.on('end', () => resolve({ status: res.statusCode, type: res.headers['content-type'], json: JSON.parse(body) }));
    });
    ws.on('error', () => {});
  });
}

// The close of a client, once it comes.
const closed = (c) => new Promise((resolve) => c.ws.on('close', (code, reason) => resolve({ code, reason: reason.toString() })));

test('two scenes stream their own frames; subscribe switches; unknown and invalid ids are refused', async (t) => {
  const d = await daemon(['--paused', '--nx', '12', '--ny', '10']);
  t.after(() => stop(d));
  const made = await call(d, 'POST', '/v1/scenes', { id: 'lab', scene: { nx: 9, ny: 7 } });
  assert.equal(made.status, 201);
  await ok(d, 'POST', '/v1/scenes/lab/sim/pause'); // a new scene runs
  // Default: 12 x 10; lab: 9 x 7 - sizes picked here, each scene's own.
  const a = await connect(d);
  const b = await connect(d, { path: '/stream?scene=lab' });
  const helloA = await next(a, 'text', (m) => m.type === 'hello');
  const helloB = await next(b, 'text', (m) => m.type === 'hello');
  assert.deepEqual([helloA.scene_id, helloA.subscription.scene, helloA.scene.nx], ['default', 'default', 12]);
  assert.deepEqual([helloB.scene_id, helloB.subscription.scene, helloB.scene.nx], ['lab', 'lab', 9]);
  assert.equal((await next(a, 'frame')).nVertices, 120);
  assert.equal((await next(b, 'frame')).nVertices, 63);
  // Events name their scene, and go to that scene's clients only.
  await ok(d, 'POST', '/v1/scenes/lab/rocks', { position: [0, 0, 1.5], radius: 0.1 });
  const ev = await next(b, 'text', (m) => m.type === 'event' && m.event === 'rock_add');
  assert.equal(ev.scene_id, 'lab');
  await ok(d, 'POST', '/v1/rocks', { position: [0.2, 0, 1.5], radius: 0.1 });
  const evA = await next(a, 'text', (m) => m.type === 'event' && m.event === 'rock_add');
  assert.equal(evA.scene_id, 'default');
  assert.equal(a.texts.filter((m) => m.type === 'event' && m.scene_id !== 'default').length, 0);
  assert.equal(b.texts.filter((m) => m.type === 'event' && m.scene_id !== 'lab').length, 0);

  // a switches to lab, keeping its encoding: a hello of lab, the ack, then lab's frames.
  const from = a.texts.length, framesBefore = a.frames.length;
  a.ws.send(JSON.stringify({ type: 'subscribe', scene: 'lab', encoding: 'q16' }));
  const ack = await next(a, 'text', (m) => m.type === 'subscribed', 15000, from);
  assert.deepEqual([ack.scene, ack.encoding], ['lab', 'q16']);
  const hello2 = await next(a, 'text', (m) => m.type === 'hello', 15000, from);
  assert.deepEqual([hello2.scene_id, hello2.scene.nx, hello2.rocks.length], ['lab', 9, 1]);
  const f = await next(a, 'frame', (g) => g.nVertices === 63, 15000, framesBefore);
  assert.equal(f.encoding, 'q16');
  // A grab now goes to lab: its event comes on lab's channel.
  a.ws.send(JSON.stringify({ type: 'grab', vertex: 62, target: [0, 0, 1] }));
  assert.equal((await next(b, 'text', (m) => m.type === 'event' && m.event === 'grab')).scene_id, 'lab');

  // Unknown and invalid ids in a subscribe: an error, the subscription stays (still lab, q16).
  const before = a.texts.length;
  a.ws.send(JSON.stringify({ type: 'subscribe', scene: 'nope', encoding: 'f32' }));
  const unknown = await next(a, 'text', (m) => m.type === 'error', 15000, before);
  assert.deepEqual([unknown.status, unknown.param, unknown.about], [404, 'scene', 'subscribe']);
  a.ws.send(JSON.stringify({ type: 'subscribe', scene: 'Not An Id' }));
  const invalid = await next(a, 'text', (m) => m.type === 'error' && m.status !== 404, 15000, before);
  assert.deepEqual([invalid.status, invalid.param], [400, 'scene']);
  await ok(d, 'POST', '/v1/scenes/lab/sim/step', { frames: 1 });
  const after = await next(a, 'frame', (g) => g.frame > f.frame);
  assert.deepEqual([after.nVertices, after.encoding], [63, 'q16']);
  // From lab's first frame on, a got lab's frames only.
  assert.deepEqual([...new Set(a.frames.slice(a.frames.indexOf(f)).map((g) => g.nVertices))], [63]);

  // At the upgrade: an invalid id 400, an unknown one 404, both problem+json.
  for (const [query, status, slug] of [['?scene=Bad%20Id', 400, 'bad-scene-id'], ['?scene=', 400, 'bad-scene-id'],
    [`?scene=${'a'.repeat(64)}`, 400, 'bad-scene-id'], ['?scene=nope', 404, 'not-found']]) {
    const r = await refusal(d, query);
    assert.deepEqual([r.status, r.type, r.json.type], [status, 'application/problem+json', `urn:clothd:problem:${slug}`], query);
  }
  const m = (await call(d, 'GET', '/metrics')).text;
  assert.equal(metric(m, 'clothd_stream_refused_total', 'reason="scene"'), 4);
  assert.equal(metric(m, 'clothd_stream_scene_clients', 'scene="lab"'), 2);
  assert.equal(metric(m, 'clothd_stream_scene_clients', 'scene="default"'), 0);
  a.ws.close();
  b.ws.close();
});

test('deleting a scene closes its clients with 1001 and a reason; the others stream on', async (t) => {
  const d = await daemon(['--paused', '--nx', '12', '--ny', '10']);
  t.after(() => stop(d));
  assert.equal((await call(d, 'POST', '/v1/scenes', { id: 'gone', scene: { nx: 8, ny: 8 } })).status, 201);
  const doomed = [await connect(d, { path: '/stream?scene=gone' }), await connect(d, { path: '/stream?scene=gone' })];
  const other = await connect(d);
  for (const c of doomed) assert.equal((await next(c, 'frame')).nVertices, 64);
  await next(other, 'frame');
  const closes = doomed.map(closed);
  assert.equal((await call(d, 'DELETE', '/v1/scenes/gone')).status < 300, true);
  for (const c of await Promise.all(closes)) assert.deepEqual(c, { code: 1001, reason: 'scene deleted' });
  // The default scene's client streams on; a new client of the deleted id is refused (404).
  await ok(d, 'POST', '/v1/sim/step', { frames: 1 });
  assert.equal((await next(other, 'frame', (g) => g.frame > 0)).nVertices, 120);
  assert.equal(other.closed, false);
  assert.equal((await refusal(d, '?scene=gone')).status, 404);
  await until('counted', async () => metric((await call(d, 'GET', '/metrics')).text, 'clothd_stream_scene_closed_total') === 2);
  // A scene made again under the same id streams again, its own new cloth.
  assert.equal((await call(d, 'POST', '/v1/scenes', { id: 'gone', scene: { nx: 5, ny: 4 } })).status, 201);
  const again = await connect(d, { path: '/stream?scene=gone' });
  assert.equal((await next(again, 'frame')).nVertices, 20);
  again.ws.close();
  other.ws.close();
});
