// js_stream.test.mjs - the JavaScript client's stream (clients/js/src/stream.js) against the real
// clothd: frames of every encoding hold the positions GET /v1/cloth/state gives (exactly for f32,
// within half a quantization step for q16 and meshopt); events carry the X-Request-Id of the
// request that caused them; grab and release go through the stream into the journal; after the
// daemon goes away the client reconnects with waits of 0.25 s doubling to 8 s and starts again
// from 0.25 s once back; frames() and pull mode; a scene the server lacks, a token, bad input;
// stop() and start() again while connecting open one connection.
import { before, test } from 'node:test';
import assert from 'node:assert/strict';
import { writeFileSync } from 'node:fs';
import { join } from 'node:path';
import { start, stop, until, tempDir, metric } from '../server/harness.mjs';
import { pausedDaemon } from './support.mjs';
import { Client } from '../../clients/js/src/index.js';

const started = pausedDaemon();
let client;
before(async () => { client = await started; });

// The largest distance, per axis, between a frame's positions and the cloth state's.
function worst(positions, expected) {
  assert.equal(positions.length, expected.length);
  const out = [0, 0, 0];
  for (let k = 0; k < expected.length; k++) out[k % 3] = Math.max(out[k % 3], Math.abs(positions[k] - expected[k]));
  return out;
}

test('frames of f32, q16 and meshopt hold the positions of GET /v1/cloth/state', async () => {
  // A rock on the cloth and a few frames: a surface that is not flat on any axis.
  await client.addRock({ position: [0.2, 0.1, 1.3], radius: 0.2, density: 2000 });
  await client.step({ frames: 20 });
  const { positions } = await client.clothStateBinary();
  const stream = client.stream().start();
  try {
    await stream.waitFor('hello');
    for (const encoding of ['f32', 'q16', 'meshopt']) {
      const scalar = encoding === 'q16' ? 'speed' : 'none';
      // (A frame the sim made without the scalar may come first, then that frame with it.)
      const seen = stream.waitFor('frame', (f) => f.encoding === encoding && (scalar === 'none') === (f.scalar === null));
      stream.subscribe({ encoding, scalar });
      const f = await seen;
      assert.equal(f.nVertices, 64 * 64);
      assert.equal(f.nRocks, 1);
      const err = worst(f.positions, positions);
      if (encoding === 'f32') assert.deepEqual(err, [0, 0, 0]);
      else {
        // Half a step of 65535 over the bbox, and float32's rounding of the result (half an ulp
        // of the largest coordinate).
        const ulp = Math.max(...positions.map(Math.abs)) * 2 ** -24;
        const half = [0, 1, 2].map((c) => (f.bboxMax[c] - f.bboxMin[c]) / 65535 / 2 + ulp);
        for (let c = 0; c < 3; c++) assert.ok(err[c] <= half[c], `${encoding} axis ${c}: ${err[c]} > ${half[c]}`);
        assert.ok(err.some((e) => e > 0), `${encoding} is quantized, not exact`);
      }
      if (encoding === 'q16') assert.equal(f.scalar.length, 64 * 64);
    }
  } finally {
    stream.stop();
  }
  await client.clearRocks();
});

test('events carry the request id; grab and release go through the stream', async () => {
  let hellos = 0;
  const stream = client.stream({ onHello: () => hellos++ }).start().start(); // a second start() opens nothing more
  try {
    await stream.waitFor('hello');
    stream.start();
    const tagged = client.withOptions({ requestId: 'js-stream-test.1' });
    const event = stream.waitFor('event', (e) => e.event === 'rock_add');
    const added = await tagged.addRock({ position: [0, 0, 2], radius: 0.1 });
    const ev = await event;
    assert.equal(ev.request_id, 'js-stream-test.1');
    assert.equal(ev.result.id, added.id);
    // The client's own ids are recognised as its own.
    const own = stream.waitFor('event', (e) => e.event === 'rock_remove');
    await client.removeRock(added.id);
    assert.ok(client.isOwnRequest((await own).request_id));
    assert.ok(!client.isOwnRequest('viewer-abc-1'));

    stream.grab(1234, [0.1, 0.2, 1.4]);
    const grab = await until('the grab in the journal', async () =>
      (await client.journal()).entries.find((e) => e.command.op === 'grab' && e.command.vertex === 1234));
    assert.deepEqual(grab.command.target, [0.1, 0.2, 1.4]);
    assert.equal(stream.release(), true);
    await until('the release in the journal', async () => (await client.journal()).entries.at(-1).command.op === 'release');
    assert.equal(hellos, 1); // one connection
  } finally {
    stream.stop();
  }
});

test('frames() yields frames as they come; pull holds the newest for takeFrame()', async () => {
  await client.resume();
  const stream = client.stream({}, { subscription: { encoding: 'q16' } }).start();
  try {
    // (The frame a client joins on comes first in f32, then again in q16 once subscribed.)
    const frames = [];
    for await (const f of stream.frames()) {
      if (f.encoding === 'q16') frames.push(f);
      if (frames.length === 3) break;
    }
    assert.ok(frames[0].step < frames[1].step && frames[1].step < frames[2].step, frames.map((f) => f.step).join(' '));
  } finally {
    stream.stop();
  }
  const decoded = [];
  const pull = client.stream({ onFrame: (f) => decoded.push(f) }, { pull: true }).start();
  try {
    await until('frames waiting', () => pull.stats.frames >= 4);
    assert.equal(decoded.length, 0);
    assert.ok(pull.stats.skipped >= pull.stats.frames - 2, JSON.stringify(pull.stats));
    assert.equal(pull.takeFrame(), true);
    assert.equal(decoded.length, 1);
    assert.equal(pull.takeFrame(), false); // nothing new since
  } finally {
    pull.stop();
    await client.pause();
  }
});

test('after the daemon goes away the stream reconnects: 0.25 s doubling to 8 s, then from 0.25 s again', async () => {
  let d = await start(['--auto-drop-interval', '0', '--paused']);
  const c = new Client({ base: d.url });
  const streamPort = (await c.health()).stream.port;
  const port = new URL(d.url).port;
  const waits = [];
  const stream = c.stream({ onStatus: (s) => { if (s === 'closed') waits.push(stream.retryMs); } }).start();
  try {
    await stream.waitFor('hello');
    await stop(d);
    d = null;
    await until('four attempts', () => waits.length >= 4, { timeout: 15000 });
    waits.slice(0, 4).forEach((w, k) => {
      const base = 250 * 2 ** k;
      assert.ok(w >= 0.75 * base && w <= 1.25 * base, `wait ${k}: ${w} ms, not ${base} +-25%`);
    });
    const hellos = stream.waitFor('hello', () => true, { timeout: 30000 });
    d = await start(['--auto-drop-interval', '0', '--paused', '--port', port, '--stream-port', String(streamPort), '--nx', '40']);
    assert.equal((await hellos).scene.nx, 40); // the new daemon's hello
    const after = waits.length;
    await stop(d);
    d = null;
    await until('an attempt', () => waits.length > after);
    assert.ok(waits[after] >= 187 && waits[after] <= 313, `first wait after the reconnection: ${waits[after]} ms`);
    assert.ok(stream.stats.reconnects >= 5);
  } finally {
    stream.stop();
    if (d) await stop(d);
  }
  // The cap: the wait doubles to 8 s and stays there (the timer is the stream's own: asked, not waited for).
  const capped = c.stream();
  capped.backoff = 4000;
  capped.closedByUs = false;
  const seen = [];
  for (let k = 0; k < 3; k++) {
    capped.retry('test');
    seen.push(capped.backoff);
    clearTimeout(capped.retryTimer);
  }
  capped.stop();
  assert.deepEqual(seen, [8000, 8000, 8000]);
});

test('a scene this clothd does not have ends the stream with a problem, no retries', async () => {
  const problems = [];
  const stream = client.scene('elsewhere').stream({ onProblem: (p) => problems.push(p) }).start();
  const status = await stream.waitFor('status', (s) => s === 'closed');
  assert.equal(status, 'closed');
  assert.match(problems[0], /no scene "elsewhere"/);
  assert.equal(stream.stats.reconnects, 0);
  assert.equal(stream.ws, null);
});

test('switchScene moves the stream to another scene; a deleted scene ends it with a problem', async (t) => {
  await client.createScene({ id: 'two', scene: { nx: 6, ny: 4 } });
  const problems = [];
  // waitFor sees only what comes after it is called: each wait is set before what it waits for
  // can come (a paused scene sends one frame).
  const stream = client.stream({ onProblem: (p) => problems.push(p) });
  const first = stream.waitFor('frame');
  stream.start();
  t.after(() => stream.stop()); // a failure leaves no stream reconnecting (the process could not end)
  const own = (await client.sim()).n_vertices;
  assert.equal((await first).nVertices, own);
  const hello = stream.waitFor('hello', (h) => h.scene_id === 'two');
  const twos = stream.waitFor('frame', (f) => f.nVertices !== own);
  assert.equal(stream.switchScene('two'), true);
  assert.equal((await hello).scene.nx, 6);
  assert.equal((await twos).nVertices, 24);
  assert.throws(() => stream.switchScene('Two'), TypeError);
  // A scene the server lacks: a problem, and the stream stays on two.
  stream.switchScene('nowhere');
  await until('refused', () => problems.some((p) => /cannot stream scene "nowhere"/.test(p)));
  assert.equal(stream.scene, 'two');
  // Deleting two closes the stream (1001, "scene deleted"): a problem, no retries.
  const closed = stream.waitFor('status', (s) => s === 'closed');
  await client.deleteScene('two');
  await closed;
  assert.ok(problems.some((p) => p === 'scene "two" was deleted'), problems.join('; '));
  assert.equal(stream.stats.reconnects, 0);
});

test('with a token the stream opens with it; bad input from a server is reported and the stream goes on', async () => {
  const dir = tempDir();
  writeFileSync(join(dir, 'token'), 'stream-token-0123456789');
  const d = await start(['--auto-drop-interval', '0', '--token-file', join(dir, 'token')]);
  const problems = [];
  const stream = new Client({ base: d.url, token: 'stream-token-0123456789' }).stream({ onProblem: (p) => problems.push(p) }).start();
  try {
    await stream.waitFor('hello');
    await stream.waitFor('frame');
    stream.inject(new Uint8Array([0x43, 0x4c, 0x46, 0x31, 72, 0, 0, 0])); // a truncated header
    stream.inject('{"type":"no-such-message"}');
    stream.inject('[1, 2]');
    stream.inject('not json');
    assert.equal(problems.length, 4);
    assert.match(problems[0], /bad frame \(8 bytes\)/);
    assert.match(problems[1], /unknown stream message type "no-such-message"/);
    assert.match(problems[2], /not a JSON object/);
    assert.match(problems[3], /not JSON/);
    const decoded = stream.stats.decoded;
    await until('frames to go on', () => stream.stats.decoded > decoded + 2);
  } finally {
    stream.stop();
    await stop(d);
  }
});

test('stop() then start() while the first attempt is on its way opens one connection, not two', async () => {
  const d = await start(['--auto-drop-interval', '0']);
  const c = new Client({ base: d.url });
  const gauge = async () => metric(await c.metrics(), 'clothd_stream_clients');
  let hellos = 0;
  const stream = c.stream({ onHello: () => hellos++ });
  try {
    stream.start(); // asking GET /v1/health for the port: no socket yet
    stream.stop();
    stream.start();
    await stream.waitFor('frame');
    await until('the daemon to count the connection', async () => (await gauge()) >= 1);
    // A second socket, were there one, would be connected by the time this one's frames flow.
    await stream.waitFor('frame');
    assert.equal(await gauge(), 1);
    assert.equal(hellos, 1);
  } finally {
    stream.stop();
    await stop(d);
  }
});
