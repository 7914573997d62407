// js_recordings.test.mjs - the JavaScript client's recordings calls (clients/js: record(),
// recordings(), recording(), deleteRecording()) against the real clothd: a recording of a set
// length in sim time is listed, ends `done`, downloads as a CLR1 file that proto/recording.mjs
// reads whole (its hello's `recording`, the frames of the encoding asked, spanning the seconds
// asked at the scene's frame rate), another scene's goes by `scene`, a bad id is a TypeError
// before any request, and a deleted one is NotFound. The routes come with the server's side of
// recordings: where GET /v1/recordings answers 404 the server tests skip, saying so.
import { before, test } from 'node:test';
import assert from 'node:assert/strict';
import { join } from 'node:path';
import { until } from '../server/harness.mjs';
import { pausedDaemon } from './support.mjs';
import * as clothd from '../../clients/js/src/index.js';

const { readRecording } = await import(join(process.env.CLOTHD_SOURCE, 'proto', 'recording.mjs'));
const started = pausedDaemon();
let client, noRoutes = null;
before(async () => {
  client = await started;
  try {
    await client.recordings();
  } catch (e) {
    if (!(e instanceof clothd.NotFound)) throw e;
    noRoutes = `this clothd has no recordings (GET /v1/recordings answers 404): the server's side is not in this build`;
  }
});

test('ids that cannot be recordings are TypeErrors before any request', () => {
  const asked = [];
  const c = new clothd.Client({ base: 'http://127.0.0.1:9', fetch: (...a) => { asked.push(a); throw new Error('no'); } });
  for (const bad of ['', 'Upper', '-lead', 'a/b', 'x'.repeat(64), 7])
    for (const call of [() => c.recording(bad), () => c.deleteRecording(bad), () => c.record({ seconds: 1, id: bad })])
      assert.throws(call, TypeError);
  assert.throws(() => c.record({ seconds: 1, scene: 'No' }), TypeError);
  assert.equal(asked.length, 0);
});

test('record, list, download, delete', async (t) => {
  if (noRoutes) return t.skip(noRoutes);
  const { frame_rate: rate } = await client.params();
  const made = await client.record({ seconds: 0.5, encoding: 'q16', id: 'js-rec' });
  assert.equal(made.id, 'js-rec');
  assert.equal(made.scene, 'default');
  assert.equal(made.state, 'recording');
  assert.equal(made.encoding, 'q16');
  await client.resume();
  const done = await until('the recording done', async () => (await client.recordings()).recordings.find((r) => r.id === 'js-rec' && r.state === 'done'));
  await client.pause();
  const bytes = await client.recording('js-rec');
  assert.ok(bytes instanceof ArrayBuffer);
  assert.equal(bytes.byteLength, done.bytes);
  const r = readRecording(bytes);
  assert.equal(r.complete, true);
  assert.equal(r.hello.recording.id, 'js-rec');
  assert.equal(r.hello.recording.encoding, 'q16');
  assert.equal(r.frames.length, done.frames);
  // 0.5 s of sim time: the frame that reaches it ends the recording, 0.5 * rate + 1 frames in all.
  assert.equal(r.frames.length, Math.round(0.5 * rate) + 1);
  for (let k = 0; k < r.frames.length; k++) assert.equal(r.frame(k)[6] & 3, 1, `frame ${k} is q16`);
  assert.deepEqual(await client.deleteRecording('js-rec'), { id: 'js-rec', deleted: true });
  assert.ok((await client.recording('js-rec').catch((e) => e)) instanceof clothd.NotFound);
  assert.ok(!(await client.recordings()).recordings.some((x) => x.id === 'js-rec'));
});

test("another scene's recording, by handle or by `scene`, and refusals as their classes", async (t) => {
  if (noRoutes) return t.skip(noRoutes);
  await client.createScene({ id: 'rec-other', scene: { nx: 6, ny: 5 } });
  const a = await client.scene('rec-other').record({ seconds: 0.25, id: 'by-handle' });
  const b = await client.record({ seconds: 0.25, id: 'by-scene', scene: 'rec-other' });
  assert.deepEqual([a.scene, b.scene], ['rec-other', 'rec-other']);
  assert.equal(a.encoding, 'delta'); // the server's default
  // An id taken is Conflict; a scene the daemon lacks NotFound; a bad length a ClientError naming it.
  assert.ok((await client.record({ seconds: 1, id: 'by-handle', scene: 'rec-other' }).catch((e) => e)) instanceof clothd.Conflict);
  assert.ok((await client.record({ seconds: 1, scene: 'nowhere' }).catch((e) => e)) instanceof clothd.NotFound);
  const bad = await client.record({ seconds: -1 }).catch((e) => e);
  assert.ok(bad instanceof clothd.ClientError, String(bad));
  assert.equal(bad.param, 'seconds');
  // A running one stops when deleted.
  for (const id of ['by-handle', 'by-scene']) assert.equal((await client.deleteRecording(id)).deleted, true);
  await client.deleteScene('rec-other');
});
