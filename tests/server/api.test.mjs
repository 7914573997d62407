// api.test.mjs - every route of PROTOCOL.md against the real clothd, with the response
// shapes pinned: the exact keys, their types, and values that follow from the requests.
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import { writeFileSync, mkdirSync } from 'node:fs';
import { join } from 'node:path';
import { start, stop, call, ok, pause, hash, until, tempDir, PROBLEM } from './harness.mjs';

let d;
const webRoot = tempDir();
before(async () => {
  mkdirSync(join(webRoot, 'sub'));
  writeFileSync(join(webRoot, 'index.html'), '<!doctype html><title>viewer</title>');
  writeFileSync(join(webRoot, 'sub', 'app.js'), 'export const x = 1;');
  d = await start(['--nx', '12', '--ny', '10', '--auto-drop-interval', '0'], { webRoot });
});
after(async () => {
  assert.equal((await stop(d)).code, 0);
});

const keys = (o) => Object.keys(o).sort();
const SIM_KEYS = ['backend', 'dt', 'dt_max', 'energy', 'frame', 'last_event', 'n_rocks', 'n_springs', 'n_torn',
  'n_vertices', 'realtime_factor', 'sim_time', 'solver', 'state', 'state_hash', 'step', 'substeps'];
const ROCK_KEYS = ['angular_velocity', 'density', 'id', 'kinematic', 'mass', 'orientation', 'position', 'radius',
  'velocity'];

function assertProblem(r, status, param) {
  assert.equal(r.status, status, r.text);
  assert.equal(r.type, PROBLEM);
  assert.equal(r.json.status, status);
  assert.match(r.json.type, /^urn:clothd:problem:[a-z-]+$/);
  assert.equal(typeof r.json.title, 'string');
  assert.equal(typeof r.json.detail, 'string');
  if (param) assert.equal(r.json.param, param);
}

test('GET /v1/health', async () => {
  const r = await call(d, 'GET', '/v1/health');
  assert.equal(r.status, 200);
  assert.deepEqual(keys(r.json), ['backend', 'backend_note', 'device', 'status', 'stream', 'version']);
  assert.equal(r.json.status, 'ok');
  assert.equal(r.json.backend, 'cpu');
  assert.match(r.json.backend_note, /cpu/);
});

test('GET /v1/sim while running, then pause, step, resume', async () => {
  const running = await ok(d, 'GET', '/v1/sim');
  assert.deepEqual(keys(running), SIM_KEYS);
  assert.deepEqual(keys(running.energy), ['gravity', 'kinetic', 'spring', 'total']);
  assert.equal(running.state, 'running');
  assert.equal(running.state_hash, null); // only computed when asked, or while paused
  assert.equal(running.n_vertices, 120);
  // 12 x 10: (11*10 + 12*9) structural + 2*11*9 shear + (10*10 + 12*8) bend springs
  assert.equal(running.n_springs, 110 + 108 + 198 + 100 + 96);
  assert.ok(Math.abs(running.dt * 60 * running.substeps - 1) < 1e-6); // the engine's float step
  const asked = await ok(d, 'GET', '/v1/sim?hash=1');
  assert.match(asked.state_hash, /^[0-9a-f]{16}$/);

  const paused = await pause(d);
  assert.deepEqual(keys(paused), SIM_KEYS);
  assert.equal(paused.state, 'paused');
  assert.equal(paused.realtime_factor, 0);
  assert.match(paused.state_hash, /^[0-9a-f]{16}$/);
  assert.equal((await ok(d, 'GET', '/v1/sim')).step, paused.step);

  const stepped = await ok(d, 'POST', '/v1/sim/step', { frames: 2 });
  assert.deepEqual(keys(stepped), ['frame', 'frames_run', 'interrupted', 'sim_time', 'state_hash', 'step', 'substeps_run']);
  assert.equal(stepped.step, paused.step + 2 * paused.substeps);
  assert.equal(stepped.frame, paused.frame + 2);
  assert.deepEqual([stepped.frames_run, stepped.substeps_run, stepped.interrupted], [2, 2 * paused.substeps, false]);
  const sub = await ok(d, 'POST', '/v1/sim/step', { substeps: 7 });
  assert.equal(sub.step, stepped.step + 7);
  assert.deepEqual([sub.frames_run, sub.substeps_run, sub.interrupted], [0, 7, false]);
  assert.equal((await ok(d, 'GET', '/v1/sim')).state_hash, sub.state_hash);

  const resumed = await ok(d, 'POST', '/v1/sim/resume');
  assert.equal(resumed.state, 'running');
  await until('the sim to advance', async () => (await ok(d, 'GET', '/v1/sim')).step > sub.step);
  assertProblem(await call(d, 'POST', '/v1/sim/step', { frames: 1 }), 409);
  await pause(d);
});

test('params: GET, PATCH, schema', async () => {
  await pause(d);
  const p = await ok(d, 'GET', '/v1/params');
  assert.equal(p.integrator, 'implicit_euler');
  assert.deepEqual(p.gravity, [0, 0, -9.81]);
  assert.equal(p.nx, undefined); // scene fields live at /v1/scene
  const r = await ok(d, 'PATCH', '/v1/params', { k_bend: 25, wind: [1, 0, 0], integrator: 'symplectic_euler' });
  assert.deepEqual(keys(r), ['applied_step', 'params']);
  assert.equal(r.params.k_bend, 25);
  assert.deepEqual(r.params.wind, [1, 0, 0]);
  const again = await ok(d, 'GET', '/v1/params');
  assert.equal(again.k_bend, 25);
  assert.equal(again.integrator, 'symplectic_euler');
  assert.equal(again.k_shear, p.k_shear);
  await ok(d, 'PATCH', '/v1/params', { integrator: 'implicit_euler', wind: [0, 0, 0] });

  const schema = await ok(d, 'GET', '/v1/params/schema');
  const byName = Object.fromEntries(schema.params.map((q) => [q.name, q]));
  for (const q of schema.params) {
    assert.deepEqual(keys(q), ['choices', 'default', 'help', 'kind', 'max', 'min', 'name', 'type', 'unit']);
  }
  assert.deepEqual(byName.k_structural.kind, 'live');
  assert.equal(byName.k_structural.unit, 'N/m');
  assert.equal(byName.nx.kind, 'scene');
  assert.equal(byName.nx.min, 2);
  assert.equal(byName.nx.max, 4096);
  assert.deepEqual(byName.pins.choices, ['corners', 'edges', 'top-edge', 'none']);
  assert.equal(byName.port.kind, 'startup');
  assert.equal(byName.port.default, 8080);
  // Every live parameter of GET /v1/params is in the schema, and the other way round.
  const live = schema.params.filter((q) => q.kind === 'live').map((q) => q.name).sort();
  assert.deepEqual(live, keys(p));
});

test('scene: GET and PUT rebuild', async () => {
  await pause(d);
  const s = await ok(d, 'GET', '/v1/scene');
  assert.deepEqual(keys(s), ['areal_density', 'height', 'nx', 'ny', 'orientation', 'pins', 'size_x', 'size_y']);
  assert.equal(s.nx, 12);
  await ok(d, 'POST', '/v1/rocks', { position: [0, 0, 2], radius: 0.1 });
  const r = await ok(d, 'PUT', '/v1/scene', { nx: 8, orientation: 'vertical' });
  assert.equal(r.nx, 8);
  assert.equal(r.ny, 10);
  assert.equal(r.orientation, 'vertical');
  assert.equal(typeof r.applied_step, 'number');
  const sim = await ok(d, 'GET', '/v1/sim');
  assert.equal(sim.step, 0);
  assert.equal(sim.n_rocks, 0);
  assert.equal(sim.n_vertices, 80);
  await ok(d, 'PUT', '/v1/scene', { nx: 12, orientation: 'horizontal' });
});

test('rocks: POST, GET, PATCH, DELETE', async () => {
  await pause(d);
  const created = await call(d, 'POST', '/v1/rocks', { position: [0.1, 0.2, 2], radius: 0.1, density: 500 });
  assert.equal(created.status, 201);
  assert.deepEqual(keys(created.json), ['applied_step', 'id', 'rock']);
  const rock = created.json.rock;
  assert.deepEqual(keys(rock), ROCK_KEYS);
  assert.deepEqual(rock.position, [0.1, 0.2, 2]);
  assert.equal(rock.kinematic, false);
  // M = rho 4/3 pi R^3
  assert.ok(Math.abs(rock.mass - (500 * 4 / 3) * Math.PI * 0.001) < 1e-6);
  const id = created.json.id;
  const list = await ok(d, 'GET', '/v1/rocks');
  assert.deepEqual(keys(list), ['rocks']);
  assert.ok(list.rocks.some((q) => q.id === id));
  const one = await ok(d, 'GET', `/v1/rocks/${id}`);
  assert.deepEqual(one, rock);
  const patched = await ok(d, 'PATCH', `/v1/rocks/${id}`, { radius: 0.2, kinematic: true, velocity: [1, 0, 0] });
  assert.deepEqual(keys(patched), ['applied_step', 'rock']);
  assert.equal(patched.rock.radius, 0.2);
  assert.equal(patched.rock.kinematic, true);
  assert.deepEqual(patched.rock.position, [0.1, 0.2, 2]); // the rest kept
  const removed = await ok(d, 'DELETE', `/v1/rocks/${id}`);
  assert.deepEqual(keys(removed), ['applied_step', 'id']);
  assertProblem(await call(d, 'GET', `/v1/rocks/${id}`), 404, 'id');
  await ok(d, 'POST', '/v1/rocks', { position: [0, 0, 2], radius: 0.1 });
  await ok(d, 'POST', '/v1/rocks', { position: [0.5, 0, 2], radius: 0.1 });
  const cleared = await ok(d, 'DELETE', '/v1/rocks');
  assert.deepEqual(keys(cleared), ['applied_step', 'removed']);
  assert.equal(cleared.removed, 2);
  assert.deepEqual((await ok(d, 'GET', '/v1/rocks')).rocks, []);
});

test('rocks: a placement into another rock or into the cloth is 409 overlap and changes nothing', async () => {
  await pause(d);
  await ok(d, 'POST', '/v1/sim/reset'); // the cloth flat again, no rocks
  const scene = await ok(d, 'GET', '/v1/scene');
  const { contact_offset: offset } = await ok(d, 'GET', '/v1/params');
  const z = scene.height; // a flat cloth at rest, in the plane z = height
  const before = await hash(d);
  // Its centre 2 cm above the cloth, radius 10 cm: the cloth 8 cm inside it.
  const into = await call(d, 'POST', '/v1/rocks', { position: [0, 0, z + 0.02], radius: 0.1 });
  assertProblem(into, 409, 'position');
  assert.equal(into.json.type, 'urn:clothd:problem:overlap');
  assert.match(into.json.detail, /cloth .* inside it, near vertex \d+/);
  assert.equal(await hash(d), before);
  // Just inside the contact layer (half of contact_offset into it) is allowed.
  const a = await call(d, 'POST', '/v1/rocks', { position: [0, 0, z + 0.1 + offset / 2], radius: 0.1 });
  assert.equal(a.status, 201, a.text);
  // A second rock 15 cm from the first's centre (radii 10 + 10 cm) overlaps it, and is named.
  const b = await call(d, 'POST', '/v1/rocks', { position: [0.15, 0, z + 0.3], radius: 0.1 });
  assert.equal(b.status, 201, b.text);
  const onto = await call(d, 'POST', '/v1/rocks', { position: [0, 0.15, z + 0.1 + offset / 2], radius: 0.1 });
  assertProblem(onto, 409, 'position');
  assert.match(onto.json.detail, new RegExp(`overlap rock ${a.json.id} `));
  // A teleport into the first, or a radius that reaches it, is refused the same way.
  const moved = await call(d, 'PATCH', `/v1/rocks/${b.json.id}`, { position: [0.1, 0, z + 0.2] });
  assertProblem(moved, 409, 'position');
  const grown = await call(d, 'PATCH', `/v1/rocks/${b.json.id}`, { radius: 0.25 });
  assertProblem(grown, 409, 'radius');
  assert.deepEqual((await ok(d, 'GET', `/v1/rocks/${b.json.id}`)).position, [0.15, 0, z + 0.3]);
  assert.equal((await ok(d, 'GET', '/v1/rocks')).rocks.length, 2);
  await ok(d, 'DELETE', '/v1/rocks');
});

test('pins and grab', async () => {
  await pause(d);
  const corners = await ok(d, 'PUT', '/v1/pins', { preset: 'corners' });
  assert.deepEqual(keys(corners), ['applied_step', 'pinned']);
  assert.equal(corners.pinned, 4);
  assert.equal((await ok(d, 'PUT', '/v1/pins', { vertices: [5, 6, 7], pinned: true })).pinned, 7);
  assert.equal((await ok(d, 'PUT', '/v1/pins', { vertices: [5], pinned: false })).pinned, 6);
  assert.equal((await ok(d, 'PUT', '/v1/pins', { preset: 'edges' })).pinned, 2 * 12 + 2 * 10 - 4);
  const g = await ok(d, 'PUT', '/v1/grab', { vertex: 30, target: [0, 0, 1.5] });
  assert.deepEqual(keys(g), ['applied_step', 'target', 'vertex']);
  await ok(d, 'POST', '/v1/sim/step', { frames: 30 });
  const state = await ok(d, 'GET', '/v1/cloth/state');
  assert.ok(state.positions[30][2] > 1.1, `the grabbed vertex rose: ${state.positions[30]}`);
  const rel = await ok(d, 'DELETE', '/v1/grab');
  assert.deepEqual(keys(rel), ['applied_step']);
});

test('cloth state as JSON and as float32', async () => {
  await pause(d);
  const j = await ok(d, 'GET', '/v1/cloth/state');
  assert.deepEqual(keys(j), ['nx', 'ny', 'positions', 'step', 'velocities']);
  assert.equal(j.positions.length, 120);
  assert.equal(j.velocities.length, 120);
  const b = await call(d, 'GET', '/v1/cloth/state', undefined, { Accept: 'application/octet-stream' });
  assert.equal(b.status, 200);
  assert.equal(b.type, 'application/octet-stream');
  assert.equal(b.buf.length, 120 * 6 * 4);
  const f = new Float32Array(b.buf.buffer, b.buf.byteOffset, 120 * 6);
  for (let v = 0; v < 120; v++) {
    for (let c = 0; c < 3; c++) {
      assert.equal(f[3 * v + c], Math.fround(j.positions[v][c]));
      assert.equal(f[360 + 3 * v + c], Math.fround(j.velocities[v][c]));
    }
  }
});

test('snapshot GET then PUT restores the state', async () => {
  await pause(d);
  const before = await hash(d);
  const snap = await call(d, 'GET', '/v1/snapshot');
  assert.equal(snap.status, 200);
  assert.equal(snap.type, 'application/octet-stream');
  assert.equal(snap.buf.subarray(0, 4).toString('latin1'), 'CSNP');
  await ok(d, 'POST', '/v1/sim/step', { frames: 5 });
  assert.notEqual(await hash(d), before);
  const put = await ok(d, 'PUT', '/v1/snapshot', snap.buf, { 'Content-Type': 'application/octet-stream' });
  assert.deepEqual(keys(put), ['applied_step', 'state_hash', 'step']);
  assert.equal(put.state_hash, before);
  assert.equal(await hash(d), before);
});

test('journal lists accepted commands with their steps', async () => {
  await pause(d);
  await ok(d, 'POST', '/v1/sim/reset');
  const at = (await ok(d, 'GET', '/v1/sim')).step;
  await ok(d, 'PATCH', '/v1/params', { k_shear: 90 });
  await ok(d, 'POST', '/v1/rocks', { position: [0, 0, 2], radius: 0.1 });
  const j = await ok(d, 'GET', '/v1/journal');
  assert.deepEqual(keys(j), ['base_step', 'entries']);
  assert.equal(j.base_step, 0);
  const ops = j.entries.map((e) => [e.step, e.command.op]);
  assert.deepEqual(ops, [[at, 'params'], [at, 'rock_add']]);
  assert.equal(j.entries[0].command.params.k_shear, 90);
});

test('metrics in Prometheus text format', async () => {
  const r = await call(d, 'GET', '/metrics');
  assert.equal(r.status, 200);
  assert.match(r.type, /^text\/plain/);
  assert.match(r.text, /^# TYPE clothd_steps_total counter$/m);
  assert.match(r.text, /^clothd_steps_total \d+$/m);
  assert.match(r.text, /^clothd_substep_seconds_bucket\{le="\+Inf"\} \d+$/m);
  assert.match(r.text, /^clothd_http_requests_total\{route="\/v1\/sim",method="GET",status="200"\} \d+$/m);
  assert.match(r.text, /^clothd_realtime_factor\{scene="default"\} [0-9.e+-]+$/m);
});

test('X-Request-Id is echoed, on success and on error', async () => {
  const a = await call(d, 'GET', '/v1/sim', undefined, { 'X-Request-Id': 'req-123' });
  assert.equal(a.headers.get('x-request-id'), 'req-123');
  const b = await call(d, 'PATCH', '/v1/params', { nope: 1 }, { 'X-Request-Id': 'abc.456' });
  assert.equal(b.status, 400);
  assert.equal(b.headers.get('x-request-id'), 'abc.456');
  const c = await call(d, 'POST', '/v1/rocks', { position: [0, 0, 3], radius: 0.1 }, { 'X-Request-Id': 'r7' });
  assert.equal(c.headers.get('x-request-id'), 'r7');
});

test('unknown routes are 404, wrong methods 405 with Allow (HEAD with every GET)', async () => {
  assertProblem(await call(d, 'GET', '/v1/nothing'), 404);
  const r = await call(d, 'DELETE', '/v1/sim');
  assertProblem(r, 405);
  assert.equal(r.headers.get('allow'), 'GET, HEAD');
  assert.equal((await call(d, 'POST', '/v1/params')).headers.get('allow'), 'GET, HEAD, PATCH');
});

test('static files from web_root', async () => {
  const index = await call(d, 'GET', '/');
  assert.equal(index.status, 200);
  assert.match(index.type, /^text\/html/);
  assert.match(index.text, /viewer/);
  const js = await call(d, 'GET', '/sub/app.js');
  assert.match(js.type, /^text\/javascript/);
  assert.equal(js.text, 'export const x = 1;');
  assert.equal((await call(d, 'GET', '/sub/missing.js')).status, 404);
  assert.equal((await call(d, 'POST', '/index.html')).status, 405);
});
