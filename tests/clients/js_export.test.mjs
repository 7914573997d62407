// js_export.test.mjs - a recording of the real clothd exported to USD and MCAP
// (clients/js/src/recording-export.js, scripts/clothd-export.mjs), read back by real parsers:
// the .usda by TinyUSDZ (npm tinyusdz, its WebAssembly build: the stage's metadata, the mesh and
// the rocks' transforms it evaluates, and each attribute's time samples as it prints the layer it
// parsed), the .mcap by @mcap/core's reader with every message checked against
// @foxglove/schemas' JSON Schema by ajv. Values are checked against the recording's frames as
// proto/frame.mjs decodes them, the torn springs against the daemon's count, the triangles against
// web/src/topology.js, and the rock's pose against the daemon's GET /v1/rocks. Bad input: a cut
// file, a corrupt frame, no frames, one frame, a hostile recording id.
import { before, after, test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync, writeFileSync, mkdtempSync, readdirSync, rmSync, statSync } from 'node:fs';
import { execFile } from 'node:child_process';
import { promisify } from 'node:util';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import Ajv from 'ajv';
import { ZSTDDecoder } from 'zstddec';
import { McapIndexedReader } from '@mcap/core';
import { until } from '../server/harness.mjs';
import { pausedDaemon } from './support.mjs';
import { tinyusdz, parseUsd, samples } from './usd.mjs';
import { exportUsd, exportMcap, f32 } from '../../clients/js/src/recording-export.js';
import { readRecording, buildRecording } from '../../proto/recording.mjs';
import { createDecoder } from '../../proto/frame.mjs';
import { triangleIndices } from '../../web/src/topology.js';

const SOURCE = process.env.CLOTHD_SOURCE ?? new URL('../..', import.meta.url).pathname;
const SCRIPT = join(SOURCE, 'scripts', 'clothd-export.mjs');
const run = promisify(execFile);
const started = pausedDaemon();
const dir = mkdtempSync(join(tmpdir(), 'clothd-export-'));
after(() => rmSync(dir, { recursive: true, force: true }));

let client, rec, bytes, decoded, usd, rate, nTorn, rockAtEnd;
const NX = 12, NY = 9;

before(async () => {
  client = await started;
  usd = await tinyusdz();
  // A scene of its own: a cloth that tears under a grab, and a rock falling onto it.
  const scene = client.scene('exp');
  await client.createScene({ id: 'exp', scene: { nx: NX, ny: NY } });
  await scene.pause();
  await scene.setParams({ tear_strain: 0.3 });
  const rock = await scene.addRock({ position: [0.2, 0.1, 1.6], radius: 0.15, orientation: [0, 0.6, 0, 0.8] });
  rate = (await scene.params()).frame_rate;
  await client.record({ seconds: 0.5, id: 'exp-rec', scene: 'exp' });
  await scene.step({ frames: 10 });
  await scene.grab(0, [-3, -3, 3]);
  await scene.step({ frames: 20 }); // 30 frames: the recording's 0.5 s, so the daemon ends where it does
  await until('the recording done', async () => (await client.recordings()).recordings.find((r) => r.id === 'exp-rec' && r.state === 'done'));
  bytes = new Uint8Array(await client.recording('exp-rec'));
  nTorn = (await scene.sim()).n_torn;
  rockAtEnd = (await scene.rock(rock.id ?? rock.rock?.id ?? 0));
  rec = readRecording(bytes);
  const zstd = new ZSTDDecoder();
  await zstd.init();
  const decoder = createDecoder({ zstd });
  decoded = [];
  for (let k = 0; k < rec.frames.length; k++) {
    const f = decoder.decode(rec.frame(k));
    decoded.push({ positions: Float32Array.from(f.positions), rocks: f.rocks, simTime: f.simTime });
  }
});

/** Exports to a file with the node script; answers {code, stdout, stderr}. */
async function script(input, output, ...more) {
  try {
    const r = await run(process.execPath, [SCRIPT, input, output, ...more]);
    return { code: 0, ...r };
  } catch (e) {
    return { code: e.code, stdout: e.stdout, stderr: e.stderr };
  }
}

test('f32 formats every float32 so that it reads back the same', () => {
  const v = new Float32Array(200000);
  const dv = new DataView(v.buffer);
  for (let k = 0; k < v.length; k++) dv.setUint32(4 * k, (Math.random() * 2 ** 32) >>> 0);
  let checked = 0;
  for (const x of [...v, 0.1, 1 / 3, 1e-30, 3e38, 1.001953125].map(Math.fround)) {
    if (!Number.isFinite(x)) continue;
    assert.equal(Math.fround(Number(f32(x))), x, `${x} -> ${f32(x)}`);
    checked++;
  }
  assert.ok(checked > 190000);
  assert.deepEqual([0.5, 0.1, 100, 1e-7, -2.5, 0].map((x) => f32(Math.fround(x))), ['0.5', '0.1', '100', '1e-7', '-2.5', '0']);
});

test('USD: TinyUSDZ reads the stage, the points of chosen frames, the topology and the rock', async () => {
  const path = join(dir, 'run.usda');
  const r = await script(join(dir, 'in.clr'), path).catch(() => null);
  writeFileSync(join(dir, 'in.clr'), bytes);
  const done = await script(join(dir, 'in.clr'), path);
  assert.equal(done.code, 0, done.stderr);
  assert.ok(r.code !== 0); // before the file existed: refused
  assert.ok(nTorn > 0, 'the grab tore springs');
  const { stage, text } = parseUsd(usd, new Uint8Array(readFileSync(path)));

  // The stage's metadata, as TinyUSDZ parsed it.
  const t0 = rec.frames[0].simTime;
  const last = Math.round((rec.frames.at(-1).simTime - t0) * rate);
  const meta = Object.fromEntries([...text.slice(0, text.indexOf(')')).matchAll(/(\w+) = ("[^"]*"|\S+)/g)].map((m) => [m[1], m[2]]));
  assert.deepEqual([meta.upAxis, Number(meta.metersPerUnit), Number(meta.timeCodesPerSecond), Number(meta.startTimeCode), Number(meta.endTimeCode), meta.defaultPrim],
    ['"Z"', 1, rate, 0, last, '"clothd"']);
  assert.equal(last, Math.round(0.5 * rate));

  // The mesh TinyUSDZ evaluates (its first time sample): frame 0, bit for bit, all triangles.
  assert.equal(stage.numMeshes(), 1);
  const mesh = stage.getMesh(0);
  assert.equal(mesh.absPath, '/clothd/cloth');
  assert.deepEqual(Float32Array.from(mesh.points), decoded[0].positions);
  assert.equal(mesh.faceVertexIndices.length, 6 * (NX - 1) * (NY - 1));

  // The points at chosen time codes: the frame at that sim time, exactly.
  const points = samples(text, 'points');
  const byTime = new Map();
  rec.frames.forEach((f, k) => byTime.set(Math.round((f.simTime - t0) * rate), k)); // the last frame at each time
  assert.equal(points.size, byTime.size);
  for (const tc of [0, 1, 7, 12, 20, last]) {
    const k = byTime.get(tc);
    assert.deepEqual(Float32Array.from(points.get(tc)), decoded[k].positions, `points at time ${tc} (frame ${k})`);
  }
  // The topology: first the whole grid, last the grid less what the daemon tore.
  const counts = samples(text, 'faceVertexCounts'), indices = samples(text, 'faceVertexIndices');
  assert.deepEqual([...counts.keys()], [...indices.keys()]);
  assert.ok(indices.size >= 2, 'the topology changed');
  assert.deepEqual(indices.get(0), Array.from(triangleIndices(NX, NY, new Set())));
  const tornIds = new Set();
  for (let t = 1; t < rec.texts.length; t++) for (const id of rec.text(t).springs ?? []) tornIds.add(id);
  assert.equal(tornIds.size, nTorn);
  // Written at the first frame and where the torn springs changed, nowhere else.
  const changes = [0], seen = new Set();
  for (const [tc, k] of byTime) {
    const before = seen.size;
    for (let t = 1; t < rec.frames[k].textsBefore; t++) for (const id of rec.text(t).springs ?? []) seen.add(id);
    if (tc > 0 && seen.size > before) changes.push(tc);
  }
  assert.deepEqual([...indices.keys()], changes);
  const lastTopo = [...indices.keys()].at(-1);
  assert.deepEqual(indices.get(lastTopo), Array.from(triangleIndices(NX, NY, tornIds)));
  for (const [t, c] of counts) assert.deepEqual(c, new Array(indices.get(t).length / 3).fill(3));

  // The rock: a sphere of its radius under an Xform whose evaluated matrix is frame 0's pose
  // (translate, then orient: x, y, z, w in the frame, real first in USD), and its last samples
  // the daemon's own rock now.
  const root = stage.getDefaultRootNode();
  const rocks = root.children.filter((c) => c.primName.startsWith('rock_'));
  assert.equal(rocks.length, 1);
  const r0 = decoded[0].rocks[0];
  const [x, y, z, w] = r0.orientation;
  const rot = [1 - 2 * (y * y + z * z), 2 * (x * y + z * w), 2 * (x * z - y * w), 0,
    2 * (x * y - z * w), 1 - 2 * (x * x + z * z), 2 * (y * z + x * w), 0,
    2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y), 0, ...r0.position, 1];
  rocks[0].localMatrix.forEach((v, i) => assert.ok(Math.abs(v - rot[i]) < 1e-5, `matrix[${i}] ${v} vs ${rot[i]}`));
  const radius = /def Sphere "sphere"[^}]*double radius = ([-0-9.e+]+)/.exec(text);
  assert.ok(radius, 'a Sphere with its radius');
  assert.equal(Math.fround(Number(radius[1])), Math.fround(0.15));
  const translate = samples(text, 'xformOp:translate'), orient = samples(text, 'xformOp:orient');
  assert.deepEqual(translate.get(last).map(Math.fround), rockAtEnd.position.map(Math.fround));
  const q = rockAtEnd.orientation;
  orient.get(last).forEach((v, i) => assert.ok(Math.abs(v - [q[3], q[0], q[1], q[2]][i]) < 1e-6));
  assert.match(text, /uniform token\[\] xformOpOrder = \["xformOp:translate", "xformOp:orient"\]/);
});

test('MCAP: @mcap/core reads it back; every message is a valid foxglove.SceneUpdate of the frames', async () => {
  const path = join(dir, 'run.mcap');
  writeFileSync(join(dir, 'in.clr'), bytes);
  const done = await script(join(dir, 'in.clr'), path);
  assert.equal(done.code, 0, done.stderr);
  const file = readFileSync(path);
  const zstd = new ZSTDDecoder(); // another zstd than the writer's
  await zstd.init();
  const reader = await McapIndexedReader.Initialize({ readable: {
    size: async () => BigInt(file.length),
    read: async (offset, length) => file.subarray(Number(offset), Number(offset + length)),
  }, decompressHandlers: { zstd: (data, size) => zstd.decode(data, Number(size)) } });
  assert.ok(reader.chunkIndexes.length > 0 && reader.chunkIndexes.every((c) => c.compression === 'zstd'));
  const channels = [...reader.channelsById.values()];
  assert.deepEqual(channels.map((c) => [c.topic, c.messageEncoding]), [['/clothd/exp', 'json']]);
  const schema = reader.schemasById.get(channels[0].schemaId);
  assert.deepEqual([schema.name, schema.encoding], ['foxglove.SceneUpdate', 'jsonschema']);
  const { default: schemas } = await import('@foxglove/schemas/jsonschema.js');
  assert.deepEqual(JSON.parse(new TextDecoder().decode(schema.data)), schemas.SceneUpdate);
  const validate = new Ajv({ strict: false }).compile(schemas.SceneUpdate);
  const messages = [];
  for await (const m of reader.readMessages()) messages.push(m);
  const t0 = rec.frames[0].simTime, base = BigInt(rec.info.started_ns);
  const keep = rec.frames.map((f, k) => k).filter((k) => k + 1 === rec.frames.length || rec.frames[k + 1].simTime !== rec.frames[k].simTime);
  assert.equal(messages.length, keep.length);
  let tornSeen = false;
  messages.forEach((m, i) => {
    const msg = JSON.parse(new TextDecoder().decode(m.data));
    assert.ok(validate(msg), JSON.stringify(validate.errors));
    const k = keep[i];
    const off = m.logTime - (base + BigInt(Math.round((rec.frames[k].simTime - t0) * 1e9)));
    assert.ok(off >= -1000n && off <= 1000n, `message ${i} at ${m.logTime}, ${off} ns from its frame's sim time`);
    const cloth = msg.entities.find((e) => e.id === 'cloth').triangles[0];
    if (i % 7 === 0 || i === messages.length - 1) {
      assert.deepEqual(Float32Array.from(cloth.points.flatMap((p) => [p.x, p.y, p.z])), decoded[k].positions, `message ${i}`);
      const rock = msg.entities.find((e) => e.id.startsWith('rock-')).spheres[0];
      assert.deepEqual([rock.pose.position.x, rock.pose.position.y, rock.pose.position.z], decoded[k].rocks[0].position);
      assert.equal(rock.size.x, 2 * decoded[k].rocks[0].radius);
    }
    if (cloth.indices.length < 6 * (NX - 1) * (NY - 1)) tornSeen = true;
  });
  assert.ok(tornSeen);
  const tornIds = new Set();
  for (let t = 1; t < rec.texts.length; t++) for (const id of rec.text(t).springs ?? []) tornIds.add(id);
  const lastCloth = JSON.parse(new TextDecoder().decode(messages.at(-1).data)).entities[0].triangles[0];
  assert.deepEqual(lastCloth.indices, Array.from(triangleIndices(NX, NY, tornIds)));
});

/** The Python client's Recording.to_usd of `file` into `usda`: its stdout (the samples written), or null without libzstd. */
async function pythonUsd(file, usda) {
  const python = ['/usr/bin/python3', 'python3'].find((p) => { try { return !!statSync(p); } catch { return p === 'python3'; } });
  writeFileSync(join(dir, 'py.clr'), file);
  const code = `import sys; sys.path.insert(0, ${JSON.stringify(join(SOURCE, 'clients', 'python'))})
import clothd
if not clothd.frames.zstd_available(): sys.exit(77)
print(clothd.read_recording(open(sys.argv[1], 'rb').read()).to_usd(sys.argv[2])['written'])`;
  const out = await run(python, ['-c', code, join(dir, 'py.clr'), usda]).catch((e) => e);
  if (out.code === 77) return null;
  assert.equal(out.stderr, '', String(out));
  return out.stdout;
}

test("the Python client's Recording.to_usd: TinyUSDZ reads it, the same stage and samples as this one", async (t) => {
  const out = { stdout: await pythonUsd(bytes, join(dir, 'py.usda')) };
  if (out.stdout === null) return t.skip('the Python client finds no libzstd for delta frames');
  const py = parseUsd(usd, new Uint8Array(readFileSync(join(dir, 'py.usda'))));
  const js = parseUsd(usd, new Uint8Array(readFileSync(join(dir, 'run.usda'))));
  assert.equal(Number(out.stdout), samples(js.text, 'points').size);
  // TinyUSDZ's print of each layer: the same numbers wherever the two formats agree on a value.
  assert.equal(py.text, js.text);
  assert.deepEqual(Float32Array.from(py.stage.getMesh(0).points), decoded[0].positions);
});

/** An MCAP file's channels, schemas and messages as @mcap/core's indexed reader gives them. */
async function readMcap(file) {
  const zstd = new ZSTDDecoder();
  await zstd.init();
  const reader = await McapIndexedReader.Initialize({ readable: {
    size: async () => BigInt(file.length),
    read: async (offset, length) => file.subarray(Number(offset), Number(offset + length)),
  }, decompressHandlers: { zstd: (data, size) => zstd.decode(data, Number(size)) } });
  const messages = [];
  for await (const m of reader.readMessages()) messages.push(m);
  return { reader, messages };
}

test("the Python client's Recording.to_mcap: @mcap/core reads it, the JavaScript exporter's messages byte for byte", async (t) => {
  const python = ['/usr/bin/python3', 'python3'].find((p) => { try { return !!statSync(p); } catch { return p === 'python3'; } });
  writeFileSync(join(dir, 'py-mcap.clr'), bytes);
  const code = `import sys; sys.path.insert(0, ${JSON.stringify(join(SOURCE, 'clients', 'python'))})
import clothd
if not clothd.frames.zstd_available(): sys.exit(77)
r = clothd.read_recording(open(sys.argv[1], 'rb').read()).to_mcap(sys.argv[2])
print(r['written'], r['compression'], r['cut'])`;
  const out = await run(python, ['-c', code, join(dir, 'py-mcap.clr'), join(dir, 'py.mcap')]).catch((e) => e);
  if (out.code === 77) return t.skip('the Python client finds no libzstd for delta frames');
  assert.equal(out.stderr, '', String(out));
  const js = await exportMcap(bytes, (() => {
    const chunks = []; let at = 0n;
    return { chunks, position: () => at, write: async (b) => { chunks.push(Uint8Array.from(b)); at += BigInt(b.length); } };
  })(), { triangles: triangleIndices, compression: 'none' });
  const jsFile = join(dir, 'js-none.mcap');
  await script(join(dir, 'py-mcap.clr'), jsFile);
  const py = await readMcap(readFileSync(join(dir, 'py.mcap')));
  const ref = await readMcap(readFileSync(jsFile));
  assert.equal(out.stdout.trim(), `${js.written} zstd False`);
  assert.ok(py.reader.chunkIndexes.length > 0 && py.reader.chunkIndexes.every((c) => c.compression === 'zstd'));
  assert.equal(py.reader.statistics.messageCount, BigInt(js.written));
  const chans = (r) => [...r.reader.channelsById.values()].map((c) => [c.topic, c.messageEncoding, [...c.metadata]]);
  assert.deepEqual(chans(py), chans(ref));
  const schema = (r) => { const s = r.reader.schemasById.get([...r.reader.channelsById.values()][0].schemaId); return [s.name, s.encoding, Buffer.from(s.data).toString()]; };
  assert.deepEqual(schema(py), schema(ref));
  assert.equal(py.messages.length, ref.messages.length);
  py.messages.forEach((m, i) => {
    const o = ref.messages[i];
    assert.deepEqual([m.sequence, m.logTime, m.publishTime], [o.sequence, o.logTime, o.publishTime], `message ${i}`);
    assert.equal(Buffer.from(m.data).toString(), Buffer.from(o.data).toString(), `message ${i}'s JSON`);
  });
});

test('a reset in the middle of a recording: the time codes go on, the tears before it are mended', async () => {
  const scene = client.scene('exp-reset');
  await client.createScene({ id: 'exp-reset', scene: { nx: 6, ny: 5 } });
  await scene.pause();
  await scene.setParams({ tear_strain: 0.3 });
  await scene.step({ frames: 10 });
  await client.record({ seconds: 0.2, id: 'exp-reset-rec', scene: 'exp-reset' });
  await scene.grab(0, [-3, -3, 3]);
  await scene.step({ frames: 5 });
  await scene.reset(); // sim time back to 0
  await scene.step({ frames: 30 });
  await until('the recording done', async () => (await client.recordings()).recordings.find((r) => r.id === 'exp-reset-rec' && r.state !== 'recording'));
  const file = new Uint8Array(await client.recording('exp-reset-rec'));
  await client.deleteScene('exp-reset');
  const r = readRecording(file);
  const back = r.frames.findIndex((f, k) => k > 0 && f.simTime < r.frames[k - 1].simTime);
  assert.ok(back > 0, 'the sim time goes back in the file');
  const chunks = [];
  const out = await exportUsd(file, { write: (x) => { chunks.push(x); } }, { triangles: triangleIndices });
  assert.equal(out.cut, false);
  const { text } = parseUsd(usd, new TextEncoder().encode(chunks.join('')));
  const times = [...samples(text, 'points').keys()];
  assert.ok(times.every((t, i) => i === 0 || t > times[i - 1]), `increasing: ${times}`);
  assert.equal(times.length, out.written);
  const indices = samples(text, 'faceVertexIndices');
  assert.ok(indices.size >= 3, 'whole, torn, whole again');
  assert.deepEqual([...indices.values()].at(-1), Array.from(triangleIndices(6, 5, new Set())));
  if (await pythonUsd(file, join(dir, 'py-reset.usda')) !== null)
    assert.equal(parseUsd(usd, new Uint8Array(readFileSync(join(dir, 'py-reset.usda')))).text, text, "the Python client's, as TinyUSDZ reads it");
});

test('bad input: cut, corrupt, empty, one frame, a hostile id', async () => {
  const sink = () => { const chunks = []; return { chunks, write: (s) => { chunks.push(s); } }; };
  // Cut inside frame 9's record (no index): frames 0..8 export, and it says so.
  const cut = bytes.slice(0, rec.frames[9].offset + 40);
  const a = sink();
  const ra = await exportUsd(cut, a, { triangles: triangleIndices });
  assert.equal(ra.frames, 9);
  assert.equal(ra.cut, true);
  assert.match(ra.problem, /cut/);
  const parsed = parseUsd(usd, new TextEncoder().encode(a.chunks.join('')));
  assert.equal(samples(parsed.text, 'points').size, new Set(rec.frames.slice(0, 9).map((f) => f.simTime)).size);
  writeFileSync(join(dir, 'cut.clr'), cut);
  const sc = await script(join(dir, 'cut.clr'), join(dir, 'cut.usda'));
  assert.equal(sc.code, 3, sc.stderr);
  assert.match(sc.stderr, /warning: .*cut/);
  // A frame record whose magic is broken: the frames before it.
  const bad = bytes.slice();
  bad[rec.frames[5].offset + 8] ^= 0xff;
  const rb = await exportUsd(bad, sink(), { triangles: triangleIndices });
  assert.equal(rb.frames, 5);
  assert.match(rb.problem, /frame 5/);
  // A delta frame whose compressed body is garbage (the record is whole): the frames before it.
  const garbled = bytes.slice();
  const f7 = rec.frames[7];
  garbled.fill(0x55, f7.offset + 8 + 72 + 44, f7.offset + 8 + f7.length - 36 * decoded[7].rocks.length);
  const rg = await exportMcap(garbled, { position: () => 0n, write: async () => {} }, { triangles: triangleIndices }).catch((e) => e);
  assert.equal(rg.frames, 7, `stopped at frame ${rg.frames}: ${rg.problem ?? rg}`);
  assert.match(rg.problem, /frame 7 does not decode/);
  assert.equal(rg.cut, true);
  // The hello alone: a clear error, no file left.
  const hello = buildRecording([rec.hello]);
  await assert.rejects(exportUsd(hello, sink(), { triangles: triangleIndices }), /no frames/);
  writeFileSync(join(dir, 'empty.clr'), hello);
  const se = await script(join(dir, 'empty.clr'), join(dir, 'empty.usda'));
  assert.equal(se.code, 1);
  assert.match(se.stderr, /no frames/);
  assert.ok(!readdirSync(dir).some((n) => n.startsWith('empty.usda')));
  // One frame, with a recording id that is a path: exports, named inside the directory given.
  const keyframe = rec.frame(0);
  const one = buildRecording([rec.hello, keyframe], { recording: { ...rec.info, id: '../../evil"\n)name é\u0001' } });
  const outDir = mkdtempSync(join(dir, 'out-'));
  writeFileSync(join(dir, 'one.clr'), one);
  const so = await script(join(dir, 'one.clr'), outDir);
  assert.equal(so.code, 0, so.stderr);
  const names = readdirSync(outDir);
  assert.equal(names.length, 1);
  assert.match(names[0], /^[A-Za-z0-9._-]+\.usda$/);
  const oneUsd = parseUsd(usd, new Uint8Array(readFileSync(join(outDir, names[0]))));
  assert.deepEqual(Float32Array.from(oneUsd.stage.getMesh(0).points), decoded[0].positions);
  assert.match(oneUsd.text, /endTimeCode = 0/);
  assert.ok(oneUsd.text.includes('string recording = """../../evil"\n)name é\ufffd"""'), 'the id, as TinyUSDZ read it');
  const sm = await script(join(dir, 'one.clr'), outDir, '--format', 'mcap');
  assert.equal(sm.code, 0, sm.stderr);
});
