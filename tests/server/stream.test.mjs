// stream.test.mjs - the WebSocket stream of the real clothd, read with the npm `ws` client and
// decoded with proto/frame.mjs: hello for late joiners, the frame header, all three encodings
// against GET /v1/cloth/state, events, a stalled client, grabs, and bad messages.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { join } from 'node:path';
import { MeshoptDecoder } from 'meshoptimizer';
import { start, stop, call, ok, pause, hash, until, rssKiB, metric } from './harness.mjs';
import { connect, next, daemon } from './wsclient.mjs';

const { decodeFrame, HEADER_SIZE } = await import(join(process.env.CLOTHD_SOURCE, 'proto', 'frame.mjs'));
await MeshoptDecoder.ready;

// The suite also runs against clothd built with ASan/UBSan (scripts/test.sh), several times slower.
const SANITIZED = process.env.CLOTHD_SANITIZED === '1';

test('a late joiner gets hello, then frames that match the scene', async () => {
  const d = await daemon(['--nx', '20', '--ny', '14', '--auto-drop-interval', '0.2']);
  await until('rocks', async () => (await ok(d, 'GET', '/v1/sim')).n_rocks >= 2);
  await ok(d, 'PATCH', '/v1/params', { tear_strain: 0.05 }); // tears quickly under the rocks
  await until('torn springs', async () => (await ok(d, 'GET', '/v1/sim')).n_torn > 0);
  const health = await ok(d, 'GET', '/v1/health');
  assert.deepEqual(health.stream, { port: d.streamPort, path: '/stream', protocol: 'clothd.v1' });
  const c = await connect(d);
  const hello = await next(c, 'text');
  assert.equal(hello.type, 'hello');
  assert.equal(hello.protocol, 'clothd.v1');
  assert.equal(hello.scene.nx, 20);
  assert.equal(hello.params.tear_strain, 0.05);
  assert.ok(hello.rocks.length >= 2);
  assert.ok(hello.torn.length > 0 && hello.torn.every(Number.isInteger));
  assert.deepEqual(hello.subscription, { encoding: 'f32', max_fps: 60, scalar: 'none' });
  const f = await next(c, 'frame');
  assert.equal(c.texts[0].type, 'hello'); // hello came first
  assert.equal(f.encoding, 'f32');
  assert.equal(f.nVertices, 280);
  assert.equal(f.positions.length, 840);
  assert.ok(f.nRocks >= 2);
  assert.ok(f.rocks.every((r) => r.radius > 0 && Math.abs(Math.hypot(...r.orientation) - 1) < 1e-5));
  assert.ok(f.bboxMin.every((v, k) => v <= f.bboxMax[k]));
  // Frames carry increasing frame and step numbers, and sim time.
  const later = await next(c, 'frame', (g) => g.frame >= f.frame + 5);
  assert.ok(later.step > f.step && later.simTime > f.simTime);
  for (let k = 1; k < c.frames.length; k++) {
    assert.ok(c.frames[k].frame > c.frames[k - 1].frame);
    assert.ok(c.frames[k].step > c.frames[k - 1].step);
  }
  c.ws.close();
  await stop(d);
});

test('all three encodings decode to the cloth state, within the quantization bound', async () => {
  const d = await daemon(['--nx', '33', '--ny', '21', '--auto-drop-interval', '0']);
  await ok(d, 'POST', '/v1/rocks', { position: [0.1, 0.2, 1.5], radius: 0.15, velocity: [0, 0, -3] });
  await until('a deformed cloth', async () => (await ok(d, 'GET', '/v1/sim')).step > 3000);
  await pause(d);
  const state = await ok(d, 'GET', '/v1/cloth/state');
  const want = state.positions.flat();
  const c = await connect(d);
  await next(c, 'text', (m) => m.type === 'hello');
  const sizes = {};
  for (const encoding of ['f32', 'q16', 'meshopt']) {
    c.ws.send(JSON.stringify({ type: 'subscribe', encoding }));
    const ack = await next(c, 'text', (m) => m.type === 'subscribed' && m.encoding === encoding);
    assert.equal(ack.max_fps, 60);
    const f = await next(c, 'frame', (g) => g.encoding === encoding);
    assert.equal(f.step, state.step);
    const bound = f.bboxMax.map((hi, k) => (hi - f.bboxMin[k]) / 65535); // one quantization step
    for (let i = 0; i < want.length; i++) {
      const err = Math.abs(f.positions[i] - want[i]);
      if (encoding === 'f32') assert.equal(f.positions[i], Math.fround(want[i]));
      else assert.ok(err <= bound[i % 3] * 0.5 + 1e-6, `${encoding} ${i}: ${err} > ${bound[i % 3] / 2}`);
    }
    sizes[encoding] = f.bytes;
  }
  const n = 33 * 21, rocks = 36;
  assert.equal(sizes.f32, HEADER_SIZE + 12 * n + rocks);
  assert.equal(sizes.q16, HEADER_SIZE + Math.ceil((6 * n) / 4) * 4 + rocks);
  assert.ok(sizes.meshopt < sizes.q16, JSON.stringify(sizes));
  // Scalars: speed and strain as one byte per vertex.
  c.ws.send(JSON.stringify({ type: 'subscribe', encoding: 'q16', scalar: 'strain' }));
  const sf = await next(c, 'frame', (g) => g.scalar !== null);
  assert.equal(sf.scalar.length, n);
  assert.ok(sf.scalar.some((v) => v > 0), 'the rock strains the cloth');
  c.ws.send(JSON.stringify({ type: 'subscribe', scalar: 'speed' }));
  await next(c, 'text', (m) => m.type === 'subscribed' && m.scalar === 'speed');
  c.ws.close();
  await stop(d);
});

test('a rock spawned over HTTP is an event and is in the next frames', async () => {
  const d = await daemon(['--nx', '16', '--ny', '16', '--auto-drop-interval', '0']);
  const c = await connect(d);
  await next(c, 'frame');
  const r = await call(d, 'POST', '/v1/rocks', { position: [0.3, 0.3, 1.7], radius: 0.1 }, { 'X-Request-Id': 'spawn-1' });
  assert.equal(r.status, 201);
  const ev = await next(c, 'text', (m) => m.type === 'event' && m.event === 'rock_add');
  assert.equal(ev.request_id, 'spawn-1');
  assert.equal(ev.applied_step, r.json.applied_step);
  assert.equal(ev.result.id, r.json.id);
  assert.deepEqual(ev.command.rock.position, [0.3, 0.3, 1.7]);
  const f = await next(c, 'frame', (g) => g.rocks.some((k) => k.id === r.json.id));
  assert.ok(f.step >= r.json.applied_step);
  const rock = f.rocks.find((k) => k.id === r.json.id);
  assert.ok(Math.abs(rock.radius - 0.1) < 1e-7);
  // Other commands are events too.
  await ok(d, 'PATCH', '/v1/params', { k_bend: 21 }, { 'X-Request-Id': 'p-2' });
  const pe = await next(c, 'text', (m) => m.type === 'event' && m.event === 'params');
  assert.equal(pe.result.params.k_bend, 21);
  assert.equal(pe.request_id, 'p-2');
  await pause(d);
  assert.equal((await next(c, 'text', (m) => m.event === 'paused')).type, 'event');
  c.ws.close();
  await stop(d);
});

test('a grab message moves the vertex', async () => {
  const d = await daemon(['--nx', '12', '--ny', '12', '--auto-drop-interval', '0']);
  const c = await connect(d);
  await next(c, 'frame');
  const before = (await ok(d, 'GET', '/v1/cloth/state')).positions[66];
  c.ws.send(JSON.stringify({ type: 'grab', vertex: 66, target: [before[0], before[1], before[2] + 0.5] }));
  const ev = await next(c, 'text', (m) => m.event === 'grab');
  assert.equal(ev.command.vertex, 66);
  await until('the vertex rose', async () => (await ok(d, 'GET', '/v1/cloth/state')).positions[66][2] > before[2] + 0.3);
  c.ws.send(JSON.stringify({ type: 'release' }));
  await next(c, 'text', (m) => m.event === 'release');
  c.ws.close();
  await stop(d);
});

test('bad messages get an error and change nothing', async () => {
  const d = await daemon(['--nx', '10', '--ny', '10', '--paused', '--stream-max-message', '256']);
  const c = await connect(d);
  await next(c, 'frame');
  const h0 = await hash(d);
  const bad = [
    ['{', 400], ['[1]', 400], ['"subscribe"', 400], ['{"type": 7}', 400], ['{"type": "dance"}', 400],
    [JSON.stringify({ type: 'subscribe', encoding: 'png' }), 422],
    [JSON.stringify({ type: 'subscribe', max_fps: 0 }), 422],
    [JSON.stringify({ type: 'subscribe', max_fps: 100000 }), 422],
    [JSON.stringify({ type: 'subscribe', scalar: 'colour' }), 422],
    [JSON.stringify({ type: 'subscribe', extra: 1 }), 400],
    [JSON.stringify({ type: 'grab', vertex: 5 }), 400],
    [JSON.stringify({ type: 'grab', vertex: 5, target: [0, 0] }), 400],
    [JSON.stringify({ type: 'subscribe', pad: 'x'.repeat(300) }), 413],
    ['{"type": "release", "type": "grab"}', 400],
  ];
  const answer = async (message) => {
    const from = c.texts.length;
    c.ws.send(message);
    return next(c, 'text', (m) => m.type === 'error', 15000, from);
  };
  for (const [text, status] of bad) {
    const e = await answer(text);
    assert.equal(e.status, status, `${text.slice(0, 40)}: ${JSON.stringify(e)}`);
  }
  // A grab of a vertex out of range is refused by the sim thread; the error comes back too.
  const ge = await answer(JSON.stringify({ type: 'grab', vertex: 100, target: [0, 0, 1] }));
  assert.equal(ge.about, 'grab');
  assert.equal(ge.status, 422);
  assert.equal(ge.param, 'vertex');
  // The detail quotes at most 64 bytes of an unknown type; cut inside a character, it loses that
  // character's bytes (an error that is not UTF-8 could not be sent at all).
  const le = await answer(JSON.stringify({ type: `${'a'.repeat(63)}é` }));
  assert.equal(le.status, 400);
  assert.equal(le.detail, `unknown message type '${'a'.repeat(63)}'`);
  assert.equal(le.about, `${'a'.repeat(63)}é`);
  const be = await answer(Buffer.from([1, 2, 3])); // binary
  assert.equal(be.status, 400);
  assert.match(be.detail, /binary/);
  assert.equal(await hash(d), h0);
  // The client is still served.
  c.ws.send(JSON.stringify({ type: 'subscribe', encoding: 'q16' }));
  await next(c, 'frame', (g) => g.encoding === 'q16');
  c.ws.close();
  await stop(d);
});

test('only /stream upgrades', async () => {
  const d = await daemon(['--paused']);
  await assert.rejects(connect(d, { path: '/other' }));
  const c = await connect(d);
  await next(c, 'text', (m) => m.type === 'hello');
  c.ws.close();
  await stop(d);
});

test('a frame follows each change, and only a change: reads and joining clients send none', async (t) => {
  const d = await daemon(['--paused', '--nx', '12', '--ny', '10']);
  t.after(() => stop(d));
  const a = await connect(d);
  const first = await next(a, 'frame');
  // A second client joins, and the queued reads run on the sim thread: nothing changed, so the
  // first client is sent nothing new.
  const b = await connect(d);
  assert.equal((await next(b, 'frame')).frame, first.frame);
  // A frame, were one sent, would go out within 1/60 s (the client's max_fps): each read is
  // followed by a window of 100 ms for it, else the next frame would take its place unseen.
  const window = () => new Promise((r) => setTimeout(r, 100));
  for (const read of [() => ok(d, 'GET', '/v1/cloth/state'), () => ok(d, 'GET', '/v1/sim?hash=1'),
    () => call(d, 'GET', '/v1/snapshot'), () => ok(d, 'POST', '/v1/sim/pause')]) {
    await read();
    await window();
  }
  await ok(d, 'POST', '/v1/sim/step', { frames: 1 });
  const stepped = await next(a, 'frame', (g) => g.frame > first.frame);
  assert.equal(stepped.frame, first.frame + 1);
  assert.deepEqual(a.frames.map((g) => g.frame), [first.frame, first.frame + 1]);
  // A change without a step (a rock while paused) is a new frame of the same number.
  await ok(d, 'POST', '/v1/rocks', { position: [0, 0, 1], radius: 0.1 });
  const withRock = await next(a, 'frame', (g) => g.nRocks === 1);
  assert.equal(withRock.frame, stepped.frame);
  assert.equal(a.frames.length, 3);
  a.ws.close();
  b.ws.close();
});

test('a client joining a paused daemon after a change nobody watched gets the changed cloth first', async (t) => {
  const d = await daemon(['--paused', '--nx', '12', '--ny', '10']);
  t.after(() => stop(d));
  const a = await connect(d);
  assert.equal((await next(a, 'frame')).nVertices, 120);
  await ok(d, 'POST', '/v1/sim/step', { frames: 3 });
  assert.equal((await next(a, 'frame', (g) => g.frame === 3)).nVertices, 120);
  a.ws.close();
  const clients = async () => metric((await call(d, 'GET', '/metrics')).text, 'clothd_stream_clients');
  await until('no stream client', async () => (await clients()) === 0);
  // With nobody listening the sim thread makes no frames: the new scene (16 x 10, step 0) has
  // none until a client asks. The joiner's first frame must be that one, never the 12 x 10 cloth
  // at frame 3 the stream kept from before.
  await ok(d, 'PUT', '/v1/scene', { nx: 16, ny: 10 });
  const b = await connect(d);
  const hello = await next(b, 'text');
  assert.equal(hello.scene.nx, 16);
  const first = await next(b, 'frame');
  assert.deepEqual([b.frames[0].nVertices, b.frames[0].step, b.frames[0].frame], [160, 0, 0]);
  assert.equal(first, b.frames[0]);
  b.ws.close();
});

// A 128 x 128 f32 frame is 197 kB: 120 frames queued for a client would be 24 MB, over the bound.
const STALL_FRAMES = 120, STALL_BOUND_KIB = 16 * 1024;

test('a client that reads nothing stays within its memory bound, and the others keep their frames',
  async (t) => {
    // Under ASan, freed memory waits in a quarantine (256 MB by default) before it is reused, and
    // the RSS would count every frame freed: a small one keeps the measure about the daemon.
    const env = SANITIZED ? { ASAN_OPTIONS: [process.env.ASAN_OPTIONS, 'quarantine_size_mb=4'].filter(Boolean).join(':') } : {};
    // The stall timeout is out of reach here: this test is about the time before it.
    const d = await daemon(['--nx', '128', '--ny', '128', '--auto-drop-interval', '0', '--stream-stall-timeout', '3600'], { env });
    t.after(() => stop(d));
    const slow = await connect(d), fast = await connect(d);
    await next(slow, 'frame');
    await next(fast, 'frame');
    slow.ws._socket.pause(); // reads nothing from now on
    const framesMade = async () => metric((await call(d, 'GET', '/metrics')).text, 'clothd_frames_total');
    const rss0 = rssKiB(d.proc.pid);
    const framesBefore = fast.frames.length, madeBefore = await framesMade(), t0 = Date.now();
    // At least the ten seconds of the requirement, and until the sim has made enough frames that
    // queueing them would break the bound (a loaded or sanitized machine makes them slowly). The
    // RSS is sampled all along: under ASan this takes longer than the stream's keepalive (a client
    // silent for 30 s is hung up), and the peak is what would show frames held for the client.
    let peak = rss0;
    await until(`${STALL_FRAMES} frames made, 10 s after the client stopped reading`, async () => {
      peak = Math.max(peak, rssKiB(d.proc.pid));
      return Date.now() - t0 >= 10000 && (await framesMade()) - madeBefore >= STALL_FRAMES;
    }, { timeout: 180000, every: 250 });
    const grown = peak - rss0;
    const made = (await framesMade()) - madeBefore, got = fast.frames.length - framesBefore;
    // Under ASan the RSS also counts the sanitizer's own allocator caches and shadow pages (18 MB
    // was seen with a 4 MB quarantine), so the bound is checked in the plain build, as the memory
    // tests do; the skipped-frame counts below hold in both.
    if (!SANITIZED) assert.ok(grown < STALL_BOUND_KIB, `the daemon grew by ${grown} KiB while making ${made} frames`);
    // The other client keeps up with the sim: it is not held back by the one that reads nothing.
    assert.ok(got >= 0.8 * made, `the other client got ${got} of the ${made} frames made`);
    // The stalled client was skipped: sent far fewer frames than the sim made (the fast client's
    // are counted as received, no more than were sent; the socket buffers take the first few).
    const m = (await call(d, 'GET', '/metrics')).text;
    const sent = metric(m, 'clothd_stream_frames_sent_total', 'encoding="f32"');
    const total = await framesMade(), toSlow = sent - fast.frames.length;
    assert.ok(toSlow < 0.75 * total, `the stalled client was sent ${toSlow} of ${total} frames`);
    assert.match(m, /clothd_stream_disconnected_total 0/); // stream_stall_timeout was out of reach
    fast.ws.close();
  });

test('a client that reads nothing for stream_stall_timeout is cut off, the others stay', async (t) => {
  const d = await daemon(['--nx', '64', '--ny', '64', '--auto-drop-interval', '0', '--stream-stall-timeout', '2']);
  t.after(() => stop(d));
  const slow = await connect(d), fast = await connect(d);
  await next(slow, 'frame');
  slow.ws._socket.pause();
  const closed = new Promise((r) => slow.ws.once('close', r));
  await until('the stalled client is disconnected',
    async () => (await call(d, 'GET', '/metrics')).text.includes('clothd_stream_disconnected_total 1'),
    { timeout: 60000, every: 100 });
  slow.ws._socket.resume(); // reads the close now
  await closed;
  assert.match((await call(d, 'GET', '/metrics')).text, /clothd_stream_clients 1/);
  const n = fast.frames.length;
  await until('the other client still gets frames', async () => fast.frames.length > n + 2);
  fast.ws.close();
});
