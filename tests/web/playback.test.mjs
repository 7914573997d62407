// playback.test.mjs - recordings in the viewer (headless Chromium, a real clothd): files built with
// proto/recording.mjs's buildRecording from what a real daemon's stream sent (its hello, its
// events and its frames, one file per encoding, while rocks drop), chosen in the page's file
// input. The page shows the frame count; scrubbing to frame k draws the positions of
// decodeFrame of frame k (its keyframe, then k, decoded here in node); a spring torn by a
// hand-built `torn` event takes its two triangles out from that frame on and back when
// scrubbed before it; play moves the sim time forward; a cut file plays what it has and says
// so; corrupt ones show the reader's message and the page stays live; Back to live reopens the
// stream. Exports, read back with three's own GLTFLoader (in node) and by their bytes: the frame
// as glb (the cloth's vertex count and positions), as PLY (header counts, the first vertex), a
// range as animated glb (the clip's frame count, a morph target equal to its frame). A recording
// the daemon made is listed, downloaded and played (the frame shown is the file's).
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync, writeFileSync } from 'node:fs';
import { join } from 'node:path';
import WebSocket from 'ws';
import { MeshoptDecoder } from 'meshoptimizer';
import { ZSTDDecoder } from 'zstddec';
import { start, stop, ok, call, until } from '../server/harness.mjs';
import { WEB_ROOT, missing, launch, openViewer, artifact } from './browser.mjs';

const SOURCE = process.env.CLOTHD_SOURCE;
const { buildRecording, readRecording } = await import(join(SOURCE, 'proto', 'recording.mjs'));
const { createDecoder } = await import(join(SOURCE, 'proto', 'frame.mjs'));
// three's loader, from the viewer's own packages (its bare `three` import resolves there).
const { GLTFLoader } = await import(join(SOURCE, 'web', 'node_modules', 'three', 'examples', 'jsm', 'loaders', 'GLTFLoader.js'));
await MeshoptDecoder.ready;
const zstd = new ZSTDDecoder();
await zstd.init();

const why = missing();
const opts = { skip: why ?? false };
const NX = 24, NY = 20, N = NX * NY;
const ENCODINGS = ['q16', 'delta', 'f32', 'meshopt'];
const FRAMES = 75; // 2.5 s of 30 frames a second: a delta file spans at least two keyframes
let daemon, browser, page;
const captured = {}; // encoding -> [hello text, event texts and frames in stream order]

// One stream client per encoding, all at once: the hello, every event after it, and the frames
// after the subscription's ack (a delta file from its first keyframe), as the bytes came.
// `ready` resolves with the ack, `done` with the messages; `progress.frames` counts.
function capture(streamPort, encoding, frames) {
  let acknowledged;
  const ready = new Promise((r) => { acknowledged = r; });
  const progress = { frames: 0 };
  const done = new Promise((resolve, reject) => {
    const ws = new WebSocket(`ws://127.0.0.1:${streamPort}/stream`, 'clothd.v1');
    const messages = [];
    let acked = false, count = 0;
    ws.on('open', () => ws.send(JSON.stringify({ type: 'subscribe', encoding, max_fps: 30 })));
    ws.on('message', (data, binary) => {
      if (!binary) {
        const text = data.toString();
        const m = JSON.parse(text);
        if (m.type === 'hello') messages.push(text);
        else if (m.type === 'subscribed') {
          acked = m.encoding === encoding;
          if (acked) acknowledged();
        }
        else if (m.type === 'event' && messages.length) messages.push(text);
        return;
      }
      const b = new Uint8Array(data); // a copy: ws may pool its buffers
      if (!acked) return;
      const dv = new DataView(b.buffer);
      if (count === 0 && (dv.getUint16(6, true) & 3) === 3 && (dv.getUint32(72, true) & ~2) !== 0) return; // not a keyframe (kind 2; 0 in the first layout)
      messages.push(b);
      progress.frames = ++count;
      if (count === frames) {
        ws.close();
        resolve(messages);
      }
    });
    ws.on('error', reject);
  });
  return { ready, done, progress };
}

/** Frame positions as decodeFrame gives them: each frame of the list decoded in order. */
function decodedFrames(messages) {
  const d = createDecoder({ meshopt: MeshoptDecoder, zstd });
  return messages.filter((m) => typeof m !== 'string').map((b) => d.decode(b));
}

const recordingOf = (encoding, extra = {}) => ({
  id: `rec-${encoding}`, scene: 'default', encoding, seconds: 2.5, started_ns: '0', frame_rate: 60, ...extra,
});

function file(name, bytes) {
  const path = artifact(name);
  writeFileSync(path, bytes);
  return path;
}

const bar = () => page.evaluate(() => {
  const t = document.getElementById('rec-time');
  const m = document.getElementById('rec-message');
  return { frame: Number(t.dataset.frame), frames: Number(t.dataset.frames), simTime: Number(t.dataset.simTime),
    text: t.textContent, message: m.textContent, level: m.className,
    player: !document.getElementById('rec-player').hidden, playing: !!window.__clothd.playback() };
});
const shownPositions = () => page.evaluate(() => Array.from(window.__clothd.view.cloth.position.array));
// How many drawn triangles have the edge a-b.
const trianglesWith = (a, b) => page.evaluate(([a, b]) => {
  const idx = window.__clothd.view.cloth.index;
  let n = 0;
  for (let t = 0; t < idx.length; t += 3) {
    const tri = [idx[t], idx[t + 1], idx[t + 2]];
    if (tri.includes(a) && tri.includes(b)) n++;
  }
  return n;
}, [a, b]);

async function openFile(path) {
  const before = await page.evaluate(() => document.getElementById('rec-message').textContent);
  await page.setInputFiles('#rec-file', path);
  await until('the bar to answer', async () => (await bar()).message !== before && !/downloading/.test((await bar()).message));
}

async function scrub(k) {
  await page.evaluate((k) => {
    const s = document.getElementById('rec-scrub');
    s.value = String(k);
    s.dispatchEvent(new Event('input'));
  }, k);
  await until(`frame ${k} shown`, async () => (await bar()).frame === k);
}

function assertPositions(shown, expected, what) {
  assert.equal(shown.length, 3 * N, what);
  for (let k = 0; k < shown.length; k++)
    if (shown[k] !== expected[k]) assert.fail(`${what}: value ${k} is ${shown[k]}, decodeFrame gives ${expected[k]}`);
}

async function downloadOf(selector) {
  const [dl] = await Promise.all([page.waitForEvent('download'), page.click(selector)]);
  const path = artifact(dl.suggestedFilename());
  await dl.saveAs(path);
  const buf = readFileSync(path);
  return { name: dl.suggestedFilename(), bytes: buf.buffer.slice(buf.byteOffset, buf.byteOffset + buf.byteLength) };
}

const loadGltf = (bytes) => new GLTFLoader().parseAsync(bytes, '');
function clothOf(gltf) {
  let cloth = null;
  gltf.scene.traverse((o) => { if (o.isMesh && o.name === 'cloth') cloth = o; });
  assert.ok(cloth, 'a mesh named cloth');
  return cloth;
}

before(async () => {
  if (why) return;
  daemon = await start(['--nx', String(NX), '--ny', String(NY), '--auto-drop-interval', '0'], { webRoot: WEB_ROOT });
  const { stream } = await ok(daemon, 'GET', '/v1/health');
  const runs = ENCODINGS.map((e) => capture(stream.port, e, FRAMES));
  await Promise.all(runs.map((r) => r.ready));
  // Rocks drop while the four clients record, after their hellos, spread over the frames (a
  // placement the daemon finds taken is 409: skipped).
  for (const [k, p] of [[0.1, 0.05, 1.7], [-0.25, 0.2, 1.9], [0.3, -0.2, 2.1]].entries()) {
    await until(`frame ${10 * k} of the capture`, () => runs[0].progress.frames >= 10 * k, { timeout: 30000 });
    await call(daemon, 'POST', '/v1/rocks', { position: p, radius: 0.12, density: 600 });
  }
  const results = await Promise.all(runs.map((r) => r.done));
  ENCODINGS.forEach((e, k) => { captured[e] = results[k]; });
  browser = await launch();
  page = await openViewer(browser.context, daemon.url + '/');
});

after(async () => {
  await browser?.close();
  if (daemon) await stop(daemon);
});

test('the capture holds what the test needs: a hello, rock events, frames of each encoding', opts, () => {
  for (const e of ENCODINGS) {
    const m = captured[e];
    assert.equal(JSON.parse(m[0]).type, 'hello');
    assert.equal(m.filter((x) => typeof x !== 'string').length, FRAMES, e);
    assert.ok(m.some((x) => typeof x === 'string' && JSON.parse(x).event === 'rock_add'), `${e}: rock_add events`);
  }
  // The delta capture crosses keyframes (one at least every second of its 2.5 s).
  const keys = decodedFrames(captured.delta).filter((f) => f.delta.keyframe).length;
  assert.ok(keys >= 2, `${keys} keyframes`);
});

test('each encoding plays: the frame count shown, scrubbing draws decodeFrame of that frame, back and forth', opts, async () => {
  for (const e of ENCODINGS) {
    const bytes = buildRecording(captured[e], { recording: recordingOf(e) });
    await openFile(file(`playback-${e}.clr`, bytes));
    const b = await bar();
    assert.equal(b.level, '', `${e}: ${b.message}`);
    assert.equal(b.frames, FRAMES, e);
    assert.match(b.text, new RegExp(`frame 1 / ${FRAMES}\\b`));
    assert.match(b.message, new RegExp(`${FRAMES} frames`));
    const expected = decodedFrames(captured[e]);
    assertPositions(await shownPositions(), expected[0].positions, `${e} frame 0`);
    if (e === 'q16') await page.screenshot({ path: artifact('playback.png') });
    // Late, then early, then late again: each a keyframe and the frame, never the frames between.
    for (const k of [FRAMES - 3, 5, 41, 40, FRAMES - 1]) {
      await scrub(k);
      assertPositions(await shownPositions(), expected[k].positions, `${e} frame ${k}`);
      assert.equal((await bar()).simTime, expected[k].simTime);
    }
    // While it plays the live stream is closed: no frame comes in.
    const live = await page.evaluate(() => window.__clothd.stream.stats.frames);
    await scrub(10);
    assert.equal(await page.evaluate(() => window.__clothd.stream.stats.frames), live);
  }
  assert.deepEqual(page.errors, []);
});

test('a torn event in the file takes its spring\'s triangles out from its frame on', opts, async () => {
  // Structural +x spring of vertex v (id 0 * n + v): the edge v - v+1, in two triangles of an
  // intact grid (one of each quad it borders), none once it is torn.
  const v = 10 * NX + 7, at = 30; // torn before frame `at`
  const m = [...captured.q16];
  const frameIdx = m.map((x, k) => (typeof x === 'string' ? -1 : k)).filter((k) => k >= 0);
  m.splice(frameIdx[at], 0, JSON.stringify({ type: 'event', event: 'torn', scene_id: 'default', step: 0, springs: [v] }));
  await openFile(file('playback-torn.clr', buildRecording(m, { recording: recordingOf('q16') })));
  assert.equal((await bar()).level, '');
  assert.equal(await trianglesWith(v, v + 1), 2);
  await scrub(at - 1);
  assert.equal(await trianglesWith(v, v + 1), 2);
  await scrub(at);
  assert.equal(await trianglesWith(v, v + 1), 0);
  await scrub(FRAMES - 1);
  assert.equal(await trianglesWith(v, v + 1), 0);
  await scrub(3); // back before the event: from the hello again, the spring whole
  assert.equal(await trianglesWith(v, v + 1), 2);
  await scrub(at + 5);
  assert.equal(await trianglesWith(v, v + 1), 0);
  // The edge next to it is untouched throughout.
  assert.equal(await trianglesWith(v + 1, v + 2), 2);

  // Exports of this frame (after the tear): PLY and glb with the torn topology.
  const expected = decodedFrames(m)[at + 5].positions;
  const ply = await downloadOf('#export-ply');
  assert.match(ply.name, /\.ply$/);
  const text = new TextDecoder('latin1').decode(new Uint8Array(ply.bytes, 0, 400));
  const headerEnd = text.indexOf('end_header\n') + 'end_header\n'.length;
  assert.ok(headerEnd > 20, text);
  const header = text.slice(0, headerEnd);
  assert.match(header, /^ply\nformat binary_little_endian 1\.0\n/);
  assert.match(header, new RegExp(`element vertex ${N}\\n`));
  // Two triangles per quad, less the two the torn spring took.
  assert.match(header, new RegExp(`element face ${2 * (NX - 1) * (NY - 1) - 2}\\n`));
  const first = new DataView(ply.bytes, headerEnd, 12);
  assert.deepEqual([0, 1, 2].map((c) => first.getFloat32(4 * c, true)), Array.from(expected.slice(0, 3)));

  const glb = await downloadOf('#export-glb');
  assert.match(glb.name, /\.glb$/);
  const cloth = clothOf(await loadGltf(glb.bytes));
  const pos = cloth.geometry.attributes.position;
  assert.equal(pos.count, N);
  assert.equal(cloth.geometry.index.count, 3 * (2 * (NX - 1) * (NY - 1) - 2));
  for (const vertex of [0, v, N - 1])
    assert.deepEqual([pos.getX(vertex), pos.getY(vertex), pos.getZ(vertex)], Array.from(expected.slice(3 * vertex, 3 * vertex + 3)), `vertex ${vertex}`);
  assert.deepEqual(page.errors, []);
});

test('a range as animated glTF: the clip has the frames asked, each a morph target equal to its frame', opts, async () => {
  await openFile(file('playback-delta-range.clr', buildRecording(captured.delta, { recording: recordingOf('delta') })));
  const from = 12, to = 47;
  await page.fill('#rec-from', String(from));
  await page.fill('#rec-to', String(to));
  const anim = await downloadOf('#export-animation');
  assert.match(anim.name, /frames-12-47\.glb$/);
  const gltf = await loadGltf(anim.bytes);
  assert.equal(gltf.animations.length, 1);
  const [track] = gltf.animations[0].tracks;
  assert.equal(track.times.length, to - from + 1);
  const expected = decodedFrames(captured.delta);
  assert.ok(Math.abs(track.times[track.times.length - 1] - (expected[to].simTime - expected[from].simTime)) < 1e-5);
  const cloth = clothOf(gltf);
  const targets = cloth.geometry.morphAttributes.position;
  assert.equal(targets.length, to - from + 1);
  // glTF's targets are relative to the base (the first frame): base + target is the frame.
  const base = cloth.geometry.attributes.position;
  for (const j of [0, 17, to - from]) {
    const want = expected[from + j].positions;
    for (let vtx = 0; vtx < N; vtx += 37) {
      for (let c = 0; c < 3; c++) {
        const got = base.getComponent(vtx, c) + (cloth.geometry.morphTargetsRelative ? targets[j].getComponent(vtx, c) : 0);
        assert.ok(Math.abs(got - want[3 * vtx + c]) < 1e-5, `frame ${from + j} vertex ${vtx}: ${got} vs ${want[3 * vtx + c]}`);
      }
    }
  }
  // The page says the cap.
  assert.match(await page.textContent('#rec-cap'), /at most 600 frames/);
});

// Dropped on the page as a file dragged from the desktop would be: a drop event with a DataTransfer.
async function dropFile(name, bytes) {
  const before = (await bar()).message;
  await page.evaluate(([name, b64]) => {
    const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
    const dt = new DataTransfer();
    dt.items.add(new File([bytes], name));
    const view = document.getElementById('view');
    for (const type of ['dragenter', 'dragover', 'drop'])
      view.dispatchEvent(new DragEvent(type, { dataTransfer: dt, bubbles: true, cancelable: true }));
  }, [name, Buffer.from(bytes).toString('base64')]);
  await until('the bar to answer', async () => (await bar()).message !== before);
}

test('play moves the sim time forward at the speed chosen, and stops at the end', opts, async () => {
  await dropFile('playback-play.clr', buildRecording(captured.q16, { recording: recordingOf('q16') }));
  assert.match((await bar()).message, new RegExp(`^playback-play\\.clr: ${FRAMES} frames`));
  await page.selectOption('#rec-speed', '0.5');
  await page.click('#rec-play');
  const seen = [];
  await until('the time to move', async () => {
    seen.push((await bar()).simTime);
    return seen.length > 5 && seen[seen.length - 1] > seen[0];
  }, { every: 100 });
  for (let k = 1; k < seen.length; k++) assert.ok(seen[k] >= seen[k - 1], `time went back: ${seen.join(', ')}`);
  await page.click('#rec-play'); // pause
  const paused = (await bar()).simTime;
  await new Promise((r) => setTimeout(r, 300)); // paused: nothing is to happen, so nothing to wait for
  assert.equal((await bar()).simTime, paused);
  // 4x from near the end: it plays to the last frame and stops there.
  await page.selectOption('#rec-speed', '4');
  await scrub(FRAMES - 10);
  await page.click('#rec-play');
  await until('the last frame', async () => (await bar()).frame === FRAMES - 1);
  await until('play to stop', async () => (await page.textContent('#rec-play')) === 'Play');
  assert.deepEqual(page.errors, []);
});

test('a cut file plays what it has and says it is cut', opts, async () => {
  const whole = buildRecording(captured.q16, { recording: recordingOf('q16'), index: false });
  const r = readRecording(whole);
  // Cut in the middle of frame 50's record: frames 0..49 remain.
  const cut = whole.slice(0, r.frames[50].offset + 8 + 40);
  await openFile(file('playback-cut.clr', cut));
  const b = await bar();
  assert.match(b.message, /cut/);
  assert.equal(b.level, 'warn');
  assert.equal(b.frames, 50);
  await scrub(49);
  assertPositions(await shownPositions(), decodedFrames(captured.q16)[49].positions, 'cut file, frame 49');
});

test('corrupt files show the reader\'s message, and the page goes on with what it showed', opts, async () => {
  await page.click('#rec-live');
  await until('live again', async () => !(await bar()).playing);
  const good = buildRecording(captured.f32, { recording: recordingOf('f32') });
  const badMagic = good.slice();
  badMagic[0] = 0x58;
  // The hello says 23 x 20: its frames of 24 x 20 vertices are not this cloth's.
  const hello = JSON.parse(captured.f32[0]);
  hello.scene.nx = NX - 1;
  const wrongCount = buildRecording([JSON.stringify(hello), ...captured.f32.slice(1)], { recording: recordingOf('f32') });
  for (const [name, bytes] of [['bad-magic', badMagic], ['wrong-vertex-count', wrongCount], ['empty', new Uint8Array(5)]]) {
    let expected;
    try {
      readRecording(bytes);
    } catch (e) {
      expected = e.message;
    }
    assert.ok(expected, `${name} is refused by the reader`);
    await openFile(file(`playback-${name}.clr`, bytes));
    const b = await bar();
    assert.equal(b.level, 'error', name);
    assert.ok(b.message.includes(expected), `${name}: the page says "${b.message}", the reader "${expected}"`);
    assert.equal(b.player, false, `${name}: no timeline`);
    assert.equal(b.playing, false, `${name}: still live`);
  }
  // Still live: frames keep coming and drawing, the cloth the daemon's.
  const f0 = await page.evaluate(() => window.__clothd.stream.stats.frames);
  await until('live frames', async () => (await page.evaluate(() => window.__clothd.stream.stats.frames)) > f0 + 5);
  assert.equal(await page.evaluate(() => window.__clothd.view.cloth.n), N);
  assert.deepEqual(page.errors, []);
});

test('the live frame exports too; a recording of the server is listed, downloaded and played', opts, async () => {
  await ok(daemon, 'POST', '/v1/sim/pause');
  const { step } = await ok(daemon, 'GET', '/v1/sim');
  await until('the paused frame', () => page.evaluate((s) => window.__clothd.view.lastStep === s, step));
  const shown = await shownPositions();
  const ply = await downloadOf('#export-ply');
  assert.match(ply.name, new RegExp(`clothd-default-step-${step}\\.ply$`));
  const text = new TextDecoder('latin1').decode(new Uint8Array(ply.bytes, 0, 400));
  const headerEnd = text.indexOf('end_header\n') + 'end_header\n'.length;
  assert.match(text.slice(0, headerEnd), new RegExp(`element vertex ${N}\\n[^]*element face ${2 * (NX - 1) * (NY - 1)}\\n`));
  const first = new DataView(ply.bytes, headerEnd, 12);
  assert.deepEqual([0, 1, 2].map((c) => first.getFloat32(4 * c, true)), shown.slice(0, 3));
  const gltf = await loadGltf((await downloadOf('#export-glb')).bytes);
  const pos = clothOf(gltf).geometry.attributes.position;
  assert.equal(pos.count, N);
  assert.deepEqual([pos.getX(N - 1), pos.getY(N - 1), pos.getZ(N - 1)], shown.slice(3 * (N - 1)));
  // The rocks dropped during the capture are in it, as spheres.
  const rocks = [];
  gltf.scene.traverse((o) => { if (/^rock-/.test(o.name)) rocks.push(o.name); });
  assert.equal(rocks.length, (await ok(daemon, 'GET', '/v1/rocks')).rocks.length);
  await ok(daemon, 'POST', '/v1/sim/resume');

  // A recording the server made: the page lists it, downloads it and plays it; the frame shown
  // is the downloaded file's, decoded here.
  assert.equal((await call(daemon, 'POST', '/v1/recordings', { seconds: 0.5, encoding: 'delta', id: 'from-server' })).status, 201);
  await until('the recording done', async () =>
    (await ok(daemon, 'GET', '/v1/recordings')).recordings.some((r) => r.id === 'from-server' && r.state === 'done'));
  const r = readRecording((await call(daemon, 'GET', '/v1/recordings/from-server')).buf);
  await page.click('#rec-server-open');
  await until('the server\'s list', () => page.evaluate(() => !document.getElementById('rec-server').hidden));
  await page.selectOption('#rec-list', 'from-server');
  await page.click('#rec-load');
  await until('the server\'s recording open', async () => (await bar()).frames === r.frames.length);
  const last = r.frames.length - 1;
  await scrub(last);
  const d = createDecoder({ meshopt: MeshoptDecoder, zstd });
  if (r.frames[last].key !== last) d.decode(r.frame(r.frames[last].key));
  assertPositions(await shownPositions(), d.decode(r.frame(last)).positions, 'the server recording\'s last frame');
  await page.click('#rec-live');
  await until('live again', async () => !(await bar()).player);
  assert.deepEqual(page.errors, []);
});
