// recordings.test.mjs - recordings in the daemon (PROTOCOL.md, "Recordings"), against the real
// clothd: the files read with proto/recording.mjs (the lead's reader, not the daemon's) and their
// frames decoded with proto/frame.mjs. A running scene's recording of N seconds has frame_rate x N
// + 1 frames one frame period apart (hand-computed); a paused scene's first frame is its cloth
// state (f32 exact, q16 and meshopt within half a step, delta within quantum / 2) and it waits for
// the next; the hello matches GET /v1/scene and /v1/params; the index's offsets point at records of
// their type (read by hand); a rock dropped while recording is an event and in the later frames;
// delta keyframes at least once a second; each bad input refused with nothing started; the cap;
// recordings_dir (the file, a restart lists it, SIGKILL leaves a file that scans to its last
// complete frame, listed "cut"); a deleted scene stops its recording, still downloadable.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { existsSync, readFileSync, readdirSync, writeFileSync } from 'node:fs';
import { join } from 'node:path';
import { MeshoptDecoder } from 'meshoptimizer';
import { ZSTDDecoder } from 'zstddec';
import { start, stop, call, ok, until, tempDir, TESTHOOKS } from './harness.mjs';

const { readRecording, buildRecording } = await import(join(process.env.CLOTHD_SOURCE, 'proto', 'recording.mjs'));
const { createDecoder } = await import(join(process.env.CLOTHD_SOURCE, 'proto', 'frame.mjs'));
await MeshoptDecoder.ready;
const zstd = new ZSTDDecoder();
await zstd.init();

const small = ['--nx', '8', '--ny', '8', '--auto-drop-interval', '0'];
const slow = { timeout: 60000 }; // the sanitized build on a loaded machine

const listed = async (d, id) => (await ok(d, 'GET', '/v1/recordings')).recordings.find((r) => r.id === id);
const finished = (d, id) => until(`${id} finished`, async () => {
  const r = await listed(d, id);
  return r && r.state !== 'recording' ? r : null;
}, slow);
const download = async (d, id) => {
  const r = await call(d, 'GET', `/v1/recordings/${id}`);
  assert.equal(r.status, 200, r.text);
  assert.equal(r.type, 'application/vnd.clothd.recording');
  assert.equal(r.headers.get('content-disposition'), `attachment; filename="${id}.clr"`);
  return r.buf;
};
// Every frame decoded in order (one decoder: delta frames need their keyframe).
const decodeAll = (rec) => {
  const dec = createDecoder({ meshopt: MeshoptDecoder, zstd });
  return rec.frames.map((_, k) => dec.decode(rec.frame(k)));
};
const u32 = (b, at) => b.readUInt32LE(at);

test('a running scene: frame_rate x seconds + 1 frames one period apart, the hello, the index by hand, a rock event, delta keyframes', async () => {
  const d = await start(small);
  const fields = await ok(d, 'GET', '/v1/scene'), params = await ok(d, 'GET', '/v1/params');
  assert.equal(params.frame_rate, 60);
  const made = await call(d, 'POST', '/v1/recordings', { seconds: 1, encoding: 'q16', id: 'one' });
  assert.equal(made.status, 201, made.text);
  assert.equal(made.headers.get('location'), '/v1/recordings/one');
  assert.deepEqual([made.json.id, made.json.scene, made.json.state, made.json.encoding, made.json.frames, made.json.seconds_asked],
    ['one', 'default', 'recording', 'q16', 0, 1]);
  const delta = await ok(d, 'POST', '/v1/recordings', { seconds: 2.5 }); // delta by default, rec-N
  assert.equal(delta.id, 'rec-1');
  assert.equal(delta.encoding, 'delta');
  const one = await finished(d, 'one');
  // (A rock dropped now, while rec-1 runs on: the command's publication is one more pose of rec-1.)
  const rock = (await ok(d, 'POST', '/v1/rocks', { position: [0.1, 0, 2.5], radius: 0.1 })).rock;
  assert.equal(one.state, 'done');
  assert.equal(one.reason, null);
  assert.equal(one.frames_dropped, 0);
  const bytes = await download(d, 'one');
  assert.equal(bytes.length, one.bytes);
  const rec = readRecording(bytes);
  assert.equal(rec.complete, true);
  // 1 s at 60 frames a second: frames at t0, t0 + 1/60, ..., t0 + 60/60.
  assert.equal(rec.frames.length, 61);
  assert.equal(one.frames, 61);
  for (let k = 1; k < 61; k++) assert.ok(Math.abs(rec.frames[k].simTime - rec.frames[k - 1].simTime - 1 / 60) < 1e-9, `frame ${k}`);
  assert.ok(Math.abs(rec.duration - 1) < 1e-9, String(rec.duration));
  assert.ok(Math.abs(one.seconds - 1) < 1e-9);
  // The hello: the stream's, with the recording's own member.
  assert.equal(rec.hello.type, 'hello');
  assert.equal(rec.hello.scene_id, 'default');
  assert.deepEqual(rec.hello.scene, fields);
  assert.deepEqual(rec.hello.params, params);
  assert.equal(rec.hello.state, 'running');
  assert.deepEqual({ ...rec.hello.recording, started_ns: 0 },
    { id: 'one', scene: 'default', encoding: 'q16', seconds: 1, started_ns: 0, frame_rate: 60 });
  assert.ok(Math.abs(rec.hello.recording.started_ns / 1e6 - Date.now()) < 60000);
  // The index and tail read by hand: each offset at a record of its type, the tail at the index.
  const tailAt = bytes.length - 16;
  assert.equal(bytes.toString('latin1', tailAt, tailAt + 4), 'CLRX');
  const indexAt = Number(bytes.readBigUInt64LE(tailAt + 8));
  assert.equal(u32(bytes, indexAt), 3);
  assert.equal(u32(bytes, indexAt + 8), 61); // n_frames
  for (let k = 0; k < 61; k++) {
    const at = Number(bytes.readBigUInt64LE(indexAt + 16 + 24 * k));
    assert.equal(at, rec.frames[k].offset);
    assert.equal(u32(bytes, at), 2, `frame ${k}'s record`);
    assert.equal(bytes.toString('latin1', at + 8, at + 12), 'CLF1');
    assert.equal(bytes.readDoubleLE(indexAt + 16 + 24 * k + 8), bytes.readDoubleLE(at + 8 + 24)); // its own sim_time
  }
  assert.equal(u32(bytes, 16), 1); // the hello first
  const frames = decodeAll(rec);
  assert.ok(frames.every((f) => f.encoding === 'q16' && f.nVertices === 64));

  // The delta recording: the rock's event, the rock in the frames after it; keyframes.
  const dr = await finished(d, 'rec-1');
  assert.equal(dr.state, 'done');
  assert.equal(dr.frames_dropped, 0);
  const drec = readRecording(await download(d, 'rec-1'));
  // 2.5 s x 60 + 1, and the pose the rock's command published between two frames (at the step
  // of the frame before it).
  assert.equal(drec.frames.length, 152);
  assert.equal(drec.frames.filter((f, k) => k > 0 && f.simTime === drec.frames[k - 1].simTime).length, 1);
  const texts = drec.texts.map((_, k) => drec.text(k));
  const at = texts.findIndex((t) => t.type === 'event' && t.event === 'rock_add');
  assert.ok(at > 0, JSON.stringify(texts.map((t) => t.event)));
  assert.equal(texts[at].result.rock.id, rock.id);
  assert.equal(texts[at].scene_id, 'default');
  const dframes = decodeAll(drec);
  for (let k = 0; k < dframes.length; k++) {
    const has = dframes[k].rocks.some((r) => r.id === rock.id);
    assert.equal(has, drec.frames[k].textsBefore > at, `frame ${k}: rock ${has}, ${drec.frames[k].textsBefore} texts before`);
    const key = drec.frames[k].key;
    assert.equal(dframes[key].delta.keyframe, true);
    assert.ok(k - key < 60 && drec.frames[k].simTime - drec.frames[key].simTime < 1 - 1e-9, `frame ${k} needs keyframe ${key}`);
  }
  assert.equal(dframes[0].delta.keyframe, true);
  assert.ok(drec.frames.filter((f, k) => f.key === k).length >= 3); // 0, 60, 120 at least
  await stop(d);
});

test('a paused scene: the first frame at once, equal to GET /v1/cloth/state in each encoding, then it waits', async () => {
  const d = await start([...small, '--paused', '--stream-delta-quantum', '0.001']);
  const encodings = ['f32', 'q16', 'meshopt', 'delta'];
  for (const e of encodings) assert.equal((await call(d, 'POST', '/v1/recordings', { seconds: 0.5, encoding: e, id: e })).status, 201);
  for (const e of encodings) await until(`${e}'s first frame`, async () => (await listed(d, e)).frames === 1, slow);
  const check = async (k) => {
    const state = await ok(d, 'GET', '/v1/cloth/state');
    for (const e of encodings) {
      const rec = readRecording(await download(d, e));
      assert.equal(rec.complete, false); // still recording: scanned
      assert.equal(rec.frames.length, k + 1);
      const f = decodeAll(rec)[k];
      assert.equal(f.step, state.step);
      for (let v = 0; v < 64; v++) {
        for (let c = 0; c < 3; c++) {
          const want = state.positions[v][c], got = f.positions[3 * v + c];
          // (GET /v1/cloth/state prints each float to 9 digits: Math.fround gives it back exactly.)
          const tol = e === 'f32' ? 0 : e === 'delta' ? 0.001 / 2 * 1.0001
            : (f.bboxMax[c] - f.bboxMin[c]) / 65535 / 2 * 1.0001 + 1e-7;
          assert.ok(Math.abs(got - Math.fround(want)) <= tol, `${e} frame ${k} vertex ${v}.${c}: ${got} vs ${want}`);
        }
      }
    }
  };
  await check(0);
  // Paused, it waits: nothing new however long (a read changes nothing).
  await new Promise((r) => setTimeout(r, 300));
  await ok(d, 'GET', '/v1/sim');
  for (const e of encodings) assert.deepEqual([(await listed(d, e)).frames, (await listed(d, e)).state], [1, 'recording']);
  await ok(d, 'POST', '/v1/sim/step', { frames: 1 });
  for (const e of encodings) await until(`${e}'s second frame`, async () => (await listed(d, e)).frames === 2, slow);
  await check(1);
  await stop(d);
});

test('bad input is refused and starts nothing; unknown recordings are 404; 64 at most', async () => {
  const d = await start([...small, '--paused']);
  await ok(d, 'POST', '/v1/recordings', { seconds: 1, id: 'taken' });
  const refusals = [
    ['POST', '/v1/scenes/nope/recordings', { seconds: 1 }, 404, 'not-found'],
    ['POST', '/v1/scenes/Bad/recordings', { seconds: 1 }, 400, 'bad-scene-id'],
    ['POST', '/v1/recordings', {}, 400, 'wrong-type'],
    ['POST', '/v1/recordings', { seconds: '1' }, 400, 'wrong-type'],
    ['POST', '/v1/recordings', { seconds: 0 }, 422, 'out-of-range'],
    ['POST', '/v1/recordings', { seconds: -1 }, 422, 'out-of-range'],
    ['POST', '/v1/recordings', { seconds: 3600.5 }, 422, 'out-of-range'],
    ['POST', '/v1/recordings', '{"seconds": 1e999}', 422, 'out-of-range'], // past a double: not finite
    ['POST', '/v1/recordings', { seconds: 1, encoding: 'png' }, 422, 'out-of-range'],
    ['POST', '/v1/recordings', { seconds: 1, encoding: 3 }, 400, 'wrong-type'],
    ['POST', '/v1/recordings', { seconds: 1, id: 'Bad' }, 400, 'bad-recording-id'],
    ['POST', '/v1/recordings', { seconds: 1, id: 'a'.repeat(64) }, 400, 'bad-recording-id'],
    ['POST', '/v1/recordings', { seconds: 1, id: 7 }, 400, 'wrong-type'],
    ['POST', '/v1/recordings', { seconds: 1, id: 'taken' }, 409, 'exists'],
    ['POST', '/v1/recordings', { seconds: 1, colour: 'red' }, 400, 'unknown-field'],
    ['POST', '/v1/recordings', '[1]', 400, null],
    ['GET', '/v1/recordings/nope', undefined, 404, 'not-found'],
    ['GET', '/v1/recordings/Bad', undefined, 404, 'not-found'],
    ['DELETE', '/v1/recordings/nope', undefined, 404, 'not-found'],
  ];
  for (const [method, path, body, status, slug] of refusals) {
    const r = await call(d, method, path, body);
    assert.equal(r.status, status, `${method} ${path} ${JSON.stringify(body)}: ${r.text}`);
    if (slug) assert.equal(r.json.type, `urn:clothd:problem:${slug}`, r.text);
  }
  assert.deepEqual((await ok(d, 'GET', '/v1/recordings')).recordings.map((r) => r.id), ['taken']);
  // 64 held at most: the 65th is refused until one is deleted.
  for (let k = 1; k < 64; k++) await ok(d, 'POST', '/v1/recordings', { seconds: 0.1, encoding: 'f32' });
  const over = await call(d, 'POST', '/v1/recordings', { seconds: 0.1 });
  assert.equal(over.status, 422);
  assert.equal(over.json.param, 'max_recordings');
  assert.equal((await ok(d, 'GET', '/v1/recordings')).recordings.length, 64);
  assert.deepEqual(await ok(d, 'DELETE', '/v1/recordings/taken'), { id: 'taken', deleted: true });
  assert.equal((await call(d, 'GET', '/v1/recordings/taken')).status, 404);
  assert.equal((await call(d, 'POST', '/v1/recordings', { seconds: 0.1 })).status, 201);
  await stop(d);
});

test('max_recordings_mb: a recording whose estimate does not fit is refused; one that outgrows it stops at the cap with its index', async () => {
  // 8 x 8 q16: a frame record is 72 + 384 + 8 bytes and 24 of index, so 30 s (1801 frames) is
  // about 0.90 MiB with the 64 KiB allowed for texts: it fits in 1 MiB; 60 s does not. 100 rocks
  // (36 bytes each in every frame) make each frame 8 times larger: it reaches the cap well before 30 s.
  // They are dropped while the scene is paused (a frame each, 0.18 MB in all), so that every frame
  // after it resumes holds all 100, however slowly the commands come.
  const d = await start([...small, '--max-recordings-mb', '1', '--time-scale', '4', '--paused']);
  const big = await call(d, 'POST', '/v1/recordings', { seconds: 60, encoding: 'q16' });
  assert.equal(big.status, 422, big.text);
  assert.equal(big.json.param, 'max_recordings_mb');
  assert.equal((await ok(d, 'GET', '/v1/recordings')).recordings.length, 0);
  await ok(d, 'POST', '/v1/recordings', { seconds: 30, encoding: 'q16', id: 'capped' });
  // Beside it nothing fits: its estimate is reserved.
  assert.equal((await call(d, 'POST', '/v1/recordings', { seconds: 5, encoding: 'q16' })).status, 422);
  for (let k = 0; k < 100; k++) {
    await ok(d, 'POST', '/v1/rocks', { position: [-0.45 + 0.1 * (k % 10), -0.45 + 0.1 * Math.floor(k / 10), 2.5], radius: 0.02 });
  }
  await ok(d, 'POST', '/v1/sim/resume');
  const r = await finished(d, 'capped');
  assert.deepEqual([r.state, r.reason], ['stopped', 'max_recordings_mb reached']);
  assert.ok(r.bytes <= 1 << 20, String(r.bytes));
  assert.ok(r.seconds < 29, String(r.seconds));
  const rec = readRecording(await download(d, 'capped'));
  assert.equal(rec.complete, true);
  assert.equal(rec.frames.length, r.frames);
  assert.equal(decodeAll(rec).at(-1).nRocks, 100);
  await stop(d);
});

test('a file written by proto/recording.mjs is listed from recordings_dir; downloads not yet read count against max_recordings_mb', async () => {
  // 20 f32 frames of a 256 x 256 cloth: 15.7 MB, built by the lead's writer, not the daemon's.
  const n = 256 * 256, frames = [];
  for (let k = 0; k < 20; k++) {
    const f = new Uint8Array(72 + 12 * n), dv = new DataView(f.buffer);
    f.set([0x43, 0x4c, 0x46, 0x31]); // CLF1
    dv.setUint16(4, 72, true);
    dv.setFloat64(24, k / 60, true);
    dv.setUint32(40, n, true);
    frames.push(f);
  }
  const file = buildRecording([{ type: 'hello', scene: { nx: 256, ny: 256 } }, ...frames],
    { recording: { id: 'big', scene: 'elsewhere', encoding: 'f32', seconds: 19 / 60, started_ns: 0, frame_rate: 60 } });
  const dir = tempDir();
  writeFileSync(join(dir, 'big.clr'), file);
  const d = await start([...small, '--recordings-dir', dir, '--max-recordings-mb', '24']);
  const big = await listed(d, 'big');
  assert.deepEqual([big.state, big.frames, big.bytes, big.scene, big.encoding], ['done', 20, file.length, 'elsewhere', 'f32']);
  // A client that does not read its download holds its copy (the kernel's socket buffers take
  // part of it): beside it, another copy would take the copies past max_recordings_mb, 503 busy
  // with Retry-After, until that client goes.
  const net = await import('node:net');
  const sock = net.connect(Number(new URL(d.url).port), '127.0.0.1', () => {
    sock.write('GET /v1/recordings/big HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n');
    sock.pause();
  });
  sock.on('error', () => {});
  const busy = await until('a busy download', async () => {
    const b = await call(d, 'GET', '/v1/recordings/big');
    return b.status === 503 ? b : null;
  }, slow);
  assert.equal(busy.json.type, 'urn:clothd:problem:busy');
  assert.equal(busy.headers.get('retry-after'), '1');
  sock.destroy();
  const again = await until('the download again', async () => {
    const b = await call(d, 'GET', '/v1/recordings/big');
    return b.status === 200 ? b : null;
  }, slow);
  assert.ok(again.buf.equals(Buffer.from(file)));
  await stop(d);
});

test('recordings_dir: the file as it is written, listed after a restart; SIGKILL leaves a file that scans to its last complete frame', async () => {
  const dir = tempDir();
  let d = await start([...small, '--recordings-dir', dir]);
  await ok(d, 'POST', '/v1/recordings', { seconds: 0.5, encoding: 'f32', id: 'kept' });
  const done = await finished(d, 'kept');
  assert.equal(done.state, 'done');
  assert.equal(done.frames_dropped, 0);
  const file = readFileSync(join(dir, 'kept.clr'));
  assert.deepEqual(file, await download(d, 'kept'));
  assert.equal(readRecording(file).frames.length, 31);
  await ok(d, 'POST', '/v1/recordings', { seconds: 600, encoding: 'delta', id: 'cut' });
  await until('frames on disk', async () => (await listed(d, 'cut')).frames >= 30, slow);
  await stop(d, 'SIGKILL');
  const cut = readFileSync(join(dir, 'cut.clr'));
  const scanned = readRecording(cut);
  assert.equal(scanned.complete, false);
  assert.ok(scanned.frames.length >= 30);
  assert.equal(decodeAll(scanned).length, scanned.frames.length); // every frame decodes
  // A file cut inside its last frame reads up to the frame before.
  const last = scanned.frames.at(-1);
  const shorter = readRecording(cut.subarray(0, last.offset + 8 + Math.floor(last.length / 2)));
  assert.equal(shorter.frames.length, scanned.frames.length - 1);
  // A restart lists both: the finished one done, the cut one stopped ("cut"); they count. A file
  // that is no recording is left alone, unlisted, and its name is not taken over.
  writeFileSync(join(dir, 'junk.clr'), 'CLR1 but not really a recording');
  d = await start([...small, '--recordings-dir', dir]);
  assert.match(d.log, /junk\.clr is not a recording clothd can read/);
  const clash = await call(d, 'POST', '/v1/recordings', { seconds: 1, id: 'junk' });
  assert.equal(clash.status, 409, clash.text);
  assert.equal(readFileSync(join(dir, 'junk.clr'), 'utf8'), 'CLR1 but not really a recording');
  const all = (await ok(d, 'GET', '/v1/recordings'));
  const byId = Object.fromEntries(all.recordings.map((r) => [r.id, r]));
  assert.deepEqual([byId.kept.state, byId.kept.frames, byId.kept.bytes, byId.kept.encoding], ['done', 31, file.length, 'f32']);
  assert.deepEqual([byId.cut.state, byId.cut.reason, byId.cut.frames, byId.cut.scene], ['stopped', 'cut', scanned.frames.length, 'default']);
  assert.ok(Math.abs(all.recordings_mb - (file.length + cut.length) / 1048576) < 1e-6, JSON.stringify(all));
  assert.deepEqual(await download(d, 'cut'), cut);
  // Deleted: the file goes too; a new one takes the id.
  await ok(d, 'DELETE', '/v1/recordings/kept');
  assert.equal(existsSync(join(dir, 'kept.clr')), false);
  assert.deepEqual(readdirSync(dir).sort(), ['cut.clr', 'junk.clr']);
  await stop(d);
});

test('a deleted scene stops its recording, which stays downloadable; the daemon stopping stops the others with their index', async () => {
  const dir = tempDir();
  const d = await start([...small, '--recordings-dir', dir]);
  await ok(d, 'POST', '/v1/scenes', { id: 'b', scene: { nx: 6, ny: 5 } });
  const made = await call(d, 'POST', '/v1/scenes/b/recordings', { seconds: 600, encoding: 'f32', id: 'of-b' });
  assert.equal(made.status, 201, made.text);
  assert.equal(made.json.scene, 'b');
  await ok(d, 'POST', '/v1/recordings', { seconds: 600, id: 'of-default' });
  await until('frames of b', async () => (await listed(d, 'of-b')).frames >= 5, slow);
  await ok(d, 'DELETE', '/v1/scenes/b');
  const r = await finished(d, 'of-b');
  assert.deepEqual([r.state, r.reason], ['stopped', 'scene deleted']);
  const rec = readRecording(await download(d, 'of-b'));
  assert.equal(rec.complete, true);
  assert.equal(rec.hello.scene_id, 'b');
  assert.ok(decodeAll(rec).every((f) => f.nVertices === 30));
  assert.equal((await listed(d, 'of-default')).state, 'recording');
  await stop(d); // SIGTERM: of-default gets its index and tail
  const other = readRecording(readFileSync(join(dir, 'of-default.clr')));
  assert.equal(other.complete, true);
  assert.ok(other.frames.length >= 1);
});

test('a writer that falls behind drops frames with a count, never waits the scene, and the file still decodes', async () => {
  // The test daemon's writer waits 40 ms before each frame: 25 a second against the scene's 60.
  const d = await start(small, { bin: TESTHOOKS, env: { CLOTHD_TEST_RECORDING_WRITE_MS: '40' } });
  await ok(d, 'POST', '/v1/recordings', { seconds: 2, id: 'slow' }); // delta
  const t0 = (await ok(d, 'GET', '/v1/sim')).sim_time, w0 = Date.now();
  const r = await finished(d, 'slow');
  assert.equal(r.state, 'done');
  assert.ok(r.frames_dropped > 0, JSON.stringify(r));
  // Every pose handed over is written or counted: 2 s x 60 + 1.
  assert.equal(r.frames + r.frames_dropped, 121, JSON.stringify(r));
  const rec = readRecording(await download(d, 'slow'));
  assert.equal(rec.frames.length, r.frames);
  assert.equal(decodeAll(rec).length, r.frames); // each delta has its keyframe before it
  // The scene did not wait for the writer: about as much sim time as wall time passed meanwhile
  // (the writer alone would have taken 121 x 40 ms = 4.8 s for the 2 s).
  const t1 = (await ok(d, 'GET', '/v1/sim')).sim_time, w1 = Date.now();
  assert.ok(t1 - t0 > 0.5 * (w1 - w0) / 1000, `${t1 - t0} s of sim time in ${(w1 - w0) / 1000} s`);
  await stop(d);
});

test('a step, or a scene at max_speed, waits for a slow writer instead: its recording keeps every frame', async () => {
  // The writer waits 20 ms before each frame; a step of 60 frames of this small cloth alone takes
  // a few ms, so without waiting for the writer most of its frames would be dropped (the 16
  // poses the writer holds are fewer than the 61).
  const d = await start([...small, '--paused'], { bin: TESTHOOKS, env: { CLOTHD_TEST_RECORDING_WRITE_MS: '20' } });
  await ok(d, 'POST', '/v1/recordings', { seconds: 1, id: 'stepped', encoding: 'q16' });
  const w0 = Date.now();
  const stepped = await ok(d, 'POST', '/v1/sim/step', { frames: 60 });
  const took = Date.now() - w0;
  assert.equal(stepped.frames_run, 60);
  const r = await finished(d, 'stepped');
  assert.deepEqual([r.state, r.frames, r.frames_dropped], ['done', 61, 0], JSON.stringify(r));
  // The step went at the writer's pace: 60 frames past the 16 the writer holds, 20 ms each.
  assert.ok(took >= (60 - 16) * 20 * 0.9, `the step took ${took} ms`);
  const rec = readRecording(await download(d, 'stepped'));
  const times = rec.frames.map((f) => f.simTime);
  const rate = (await ok(d, 'GET', '/v1/params')).frame_rate;
  for (let k = 1; k < times.length; k++) assert.ok(Math.abs(times[k] - times[k - 1] - 1 / rate) < 1e-9, `frame ${k}`);
  // At max_speed the same: every frame of the recording, none dropped.
  await ok(d, 'PATCH', '/v1/params', { max_speed: true });
  await ok(d, 'POST', '/v1/recordings', { seconds: 0.5, id: 'fast', encoding: 'q16' });
  await ok(d, 'POST', '/v1/sim/resume');
  const f = await finished(d, 'fast');
  assert.deepEqual([f.state, f.frames, f.frames_dropped], ['done', Math.round(0.5 * rate) + 1, 0], JSON.stringify(f));
  await stop(d);
});

test('clothctl record, recordings, recording RID (the file), recording delete RID', async () => {
  const { execFile } = await import('node:child_process');
  const d = await start([...small, '--paused']);
  const ctl = (...args) => new Promise((resolve) => {
    execFile(join(process.env.CLOTHD_SOURCE, 'scripts', 'clothctl'), args, { env: { PATH: process.env.PATH, CLOTHD_URL: d.url }, encoding: 'buffer' },
      (err, stdout, stderr) => resolve({ code: err ? err.code : 0, stdout, stderr: stderr.toString() }));
  });
  let r = await ctl('record', '0.05', 'f32', 'by-ctl');
  assert.equal(r.code, 0, r.stderr);
  assert.equal(JSON.parse(r.stdout).id, 'by-ctl');
  await ok(d, 'POST', '/v1/sim/step', { frames: 5 });
  await finished(d, 'by-ctl');
  r = await ctl('recordings');
  assert.deepEqual(JSON.parse(r.stdout).recordings.map((x) => [x.id, x.state]), [['by-ctl', 'done']]);
  r = await ctl('recording', 'by-ctl');
  assert.deepEqual(r.stdout, await download(d, 'by-ctl'));
  assert.equal(readRecording(r.stdout).complete, true);
  r = await ctl('record', '0', 'f32');
  assert.equal(r.code, 1); // refused: 422
  r = await ctl('recording', 'delete', 'by-ctl');
  assert.equal(r.code, 0, r.stderr);
  assert.equal((await ok(d, 'GET', '/v1/recordings')).recordings.length, 0);
  await stop(d);
});
