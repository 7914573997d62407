// snapshots.test.mjs - a snapshot (PUT /v1/snapshot, the state file) is refused for whatever the
// API would refuse, with a clear problem and no change; rock ids and the step count stop at their
// limits with a clear 422, never in a state the daemon cannot save; and for any state the API
// reaches, GET /v1/snapshot then PUT succeeds and restores the same state (a property test over
// random command sequences, seeded: CLOTHD_PROPERTY_SEED reruns one).
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { join } from 'node:path';
import { start, stop, call, ok, hash, tempDir, PROBLEM } from './harness.mjs';
import { layout, edited, exactStep } from './snapshot.mjs';

const OCTETS = { 'Content-Type': 'application/octet-stream' };
const STEP_MAX = (1n << 63n) - 1n;
const ID_MAX = 4294967294; // the last rock id given

async function snapshot(d) {
  const r = await call(d, 'GET', '/v1/snapshot');
  assert.equal(r.status, 200, r.text);
  return r.buf;
}

// A refusal: the status, type and param expected, and the state hash as it was.
async function refused(d, body, status, slug, param) {
  const h0 = await hash(d);
  const r = await call(d, 'PUT', '/v1/snapshot', body, OCTETS);
  assert.equal(r.status, status, r.text);
  assert.equal(r.type, PROBLEM);
  assert.equal(r.json.type, `urn:clothd:problem:${slug}`);
  if (param) assert.equal(r.json.param, param);
  assert.ok(r.json.detail.length > 10, r.json.detail);
  assert.equal(await hash(d), h0);
  return r.json;
}

test('a snapshot is refused for what the API refuses: rocks past max_rocks, a next rock id of 0, a step past 2^63 - 1', async () => {
  const flags = ['--paused', '--nx', '6', '--ny', '6', '--auto-drop-interval', '0'];
  const a = await start(flags);
  const at = await layout(a);
  const bare = await snapshot(a);
  for (const x of [-0.5, 0, 0.5]) await ok(a, 'POST', '/v1/rocks', { position: [x, 0, 2], radius: 0.1 });
  const three = await snapshot(a);
  await stop(a);

  const d = await start([...flags, '--max-rocks', '2']);
  const p = await refused(d, three, 422, 'limit', 'max_rocks');
  assert.match(p.detail, /3 rocks, more than max_rocks \(2\)/);
  assert.match((await refused(d, edited(bare, { [at.nextId]: ['u32', 0] }), 400, 'bad-snapshot')).detail, /next rock id of 0/);
  assert.match((await refused(d, edited(bare, { [at.step]: ['u64', STEP_MAX + 2n] }), 400, 'bad-snapshot')).detail,
    /step 9223372036854775809, past 2\^63 - 1/);
  await refused(d, edited(bare, { [at.time]: ['f64', -1] }), 400, 'bad-snapshot');
  // The same snapshots within the rules load.
  await ok(d, 'PUT', '/v1/snapshot', edited(bare, { [at.step]: ['u64', 12345n] }), OCTETS);
  assert.equal((await ok(d, 'GET', '/v1/sim')).step, 12345);
  await stop(d);
});

test('rock ids stop at 4294967294: the next POST /v1/rocks is 422, and the state saves and resumes', async () => {
  const dir = tempDir();
  const state = join(dir, 'state.bin');
  const d = await start(['--paused', '--nx', '6', '--ny', '6', '--auto-drop-interval', '0', '--state-file', state]);
  const at = await layout(d);
  await ok(d, 'PUT', '/v1/snapshot', edited(await snapshot(d), { [at.nextId]: ['u32', ID_MAX - 1] }), OCTETS);
  assert.equal((await ok(d, 'POST', '/v1/rocks', { position: [0, 0, 2], radius: 0.1 })).id, ID_MAX - 1);
  assert.equal((await ok(d, 'POST', '/v1/rocks', { position: [0.5, 0, 2], radius: 0.1 })).id, ID_MAX);
  const h = await hash(d);
  const r = await call(d, 'POST', '/v1/rocks', { position: [-0.5, 0, 2], radius: 0.1 });
  assert.equal(r.status, 422);
  assert.equal(r.json.type, 'urn:clothd:problem:limit');
  assert.equal(r.json.param, 'id');
  assert.match(r.json.detail, /rock ids are used up/);
  assert.equal(await hash(d), h);
  // Its own snapshot loads, and so does the state file SIGTERM writes.
  const own = await snapshot(d);
  assert.equal((await ok(d, 'PUT', '/v1/snapshot', own, OCTETS)).state_hash, h);
  assert.equal((await ok(d, 'GET', `/v1/rocks/${ID_MAX}`)).id, ID_MAX);
  assert.equal((await stop(d)).code, 0);
  const b = await start(['--state-file', state, '--paused']);
  assert.equal((await ok(b, 'GET', '/v1/sim')).state_hash, h);
  // A reset starts the ids again from 1.
  await ok(b, 'POST', '/v1/sim/reset');
  assert.equal((await ok(b, 'POST', '/v1/rocks', { position: [0, 0, 2], radius: 0.1 })).id, 1);
  await stop(b);
});

test('the step count stops at 2^63 - 1: a step past it is 422, running into it pauses with an event', async () => {
  const d = await start(['--paused', '--nx', '6', '--ny', '6', '--auto-drop-interval', '0']);
  const at = await layout(d);
  await ok(d, 'PUT', '/v1/snapshot', edited(await snapshot(d), { [at.step]: ['u64', STEP_MAX - 100n] }), OCTETS);
  assert.equal(exactStep((await call(d, 'GET', '/v1/sim')).text), STEP_MAX - 100n);
  const h = await hash(d);
  const past = await call(d, 'POST', '/v1/sim/step', { substeps: 101 });
  assert.equal(past.status, 422);
  assert.equal(past.json.type, 'urn:clothd:problem:limit');
  assert.equal(past.json.param, 'substeps');
  assert.equal(await hash(d), h);
  const last = await call(d, 'POST', '/v1/sim/step', { substeps: 100 });
  assert.equal(last.status, 200);
  assert.equal(exactStep(last.text), STEP_MAX);
  // Its snapshot loads.
  const h2 = await hash(d);
  assert.equal((await ok(d, 'PUT', '/v1/snapshot', await snapshot(d), OCTETS)).state_hash, h2);
  // Running into the limit: paused at once, with the event.
  await ok(d, 'PUT', '/v1/snapshot', edited(await snapshot(d), { [at.step]: ['u64', STEP_MAX - 1000n] }), OCTETS);
  await ok(d, 'POST', '/v1/sim/resume');
  let sim;
  for (;;) {
    sim = await ok(d, 'GET', '/v1/sim');
    if (sim.state === 'paused') break;
    await new Promise((r) => setTimeout(r, 20));
  }
  assert.equal(sim.last_event.type, 'step_limit');
  assert.match(d.log, /would pass 2\^63 - 1.*; paused/);
  await stop(d);
});

// ---- the property test ----

// A small deterministic generator (mulberry32), so that a printed seed reruns the same sequence.
function generator(seed) {
  let a = seed >>> 0;
  const next = () => {
    a = (a + 0x6d2b79f5) >>> 0;
    let t = a;
    t = Math.imul(t ^ (t >>> 15), t | 1);
    t ^= t + Math.imul(t ^ (t >>> 7), t | 61);
    return ((t ^ (t >>> 14)) >>> 0) / 4294967296;
  };
  const int = (lo, hi) => lo + Math.floor(next() * (hi - lo + 1));
  const real = (lo, hi) => lo + next() * (hi - lo);
  return { next, int, real, pick: (list) => list[int(0, list.length - 1)] };
}

// One random command that the API takes (or refuses: a refusal is a move too), against the
// daemon's current state.
async function randomMove(d, g, at, saved) {
  const sim = await ok(d, 'GET', '/v1/sim');
  const n = sim.n_vertices;
  const rocks = (await ok(d, 'GET', '/v1/rocks')).rocks;
  const vec = (s) => [g.real(-s, s), g.real(-s, s), g.real(-s, s)];
  const moves = [
    ['PATCH', '/v1/params', () => g.pick([{ k_bend: g.real(0, 60) }, { wind: vec(5) }, { gravity: vec(12) },
      { tear_strain: g.pick([0, g.real(0.05, 0.5)]) }, { plastic_yield: g.pick([0, g.real(0.01, 0.3)]), plastic_rate: g.real(0, 30) },
      { friction_model: g.pick(['coulomb_viscous', 'resultant']) }, { integrator: g.pick(['velocity_verlet', 'symplectic_euler']) },
      { drag: g.real(0, 2), mu: g.real(0, 1) }, { ground: g.next() < 0.5, ground_z: g.real(-1, 0.5) },
      { auto_drop_interval: g.pick([0, 0.05, 0.2]), seed: g.int(0, 99) }, { substeps: g.int(5, 60) }])],
    ['POST', '/v1/rocks', () => ({ position: [g.real(-1, 1), g.real(-1, 1), g.real(0.5, 2.5)], radius: g.real(0.03, 0.3),
      density: g.real(50, 2000), velocity: vec(3), angular_velocity: vec(5), kinematic: g.next() < 0.2 })],
    ['PATCH', rocks.length ? `/v1/rocks/${g.pick(rocks).id}` : '/v1/rocks/1', () => ({ position: [g.real(-1, 1), g.real(-1, 1), g.real(0.5, 2)],
      velocity: vec(2) })],
    ['DELETE', rocks.length ? `/v1/rocks/${g.pick(rocks).id}` : '/v1/rocks/1'],
    ['DELETE', '/v1/rocks'],
    ['PUT', '/v1/pins', () => (g.next() < 0.4 ? { preset: g.pick(['corners', 'edges', 'top-edge', 'none']) }
      : { vertices: Array.from({ length: g.int(1, 6) }, () => g.int(0, n - 1)), pinned: g.next() < 0.6 })],
    ['PUT', '/v1/grab', () => ({ vertex: g.int(0, n - 1), target: [g.real(-1, 1), g.real(-1, 1), g.real(0, 2)] })],
    ['DELETE', '/v1/grab'],
    ['POST', '/v1/sim/step', () => (g.next() < 0.5 ? { frames: g.int(1, 8) } : { substeps: g.int(1, 90) })],
    ['POST', '/v1/sim/step', () => ({ frames: g.int(1, 8) })],
    ['PUT', '/v1/scene', () => ({ nx: g.int(2, 12), ny: g.int(2, 12), orientation: g.pick(['horizontal', 'vertical']),
      pins: g.pick(['corners', 'edges', 'top-edge', 'none']) })],
    ['POST', '/v1/sim/reset'],
    // A snapshot taken earlier, and the current one moved to the edges of what the rules allow.
    ['PUT', '/v1/snapshot', () => (saved.length ? g.pick(saved) : null)],
    ['PUT', '/v1/snapshot', async () => edited(await snapshot(d), g.next() < 0.5
      ? { [at.nextId]: ['u32', ID_MAX - g.int(0, 2) + 1] } : { [at.step]: ['u64', STEP_MAX - BigInt(g.int(0, 3000))] })],
  ];
  // Rocks and the edges more often than the rest: the rules at the edges are what can break.
  const [method, path, body] = g.pick([...moves, moves[1], moves[1], moves[moves.length - 1]]);
  const b = body ? await body() : undefined;
  if (b === null) return `${method} ${path} (nothing saved yet)`;
  const r = await call(d, method, path, b, b instanceof Uint8Array ? OCTETS : {});
  if (r.status >= 500) throw new Error(`${method} ${path} -> ${r.status}: ${r.text}`);
  return `${method} ${path} ${b instanceof Uint8Array ? `(${b.length} bytes)` : JSON.stringify(b ?? '')} -> ${r.status}`;
}

test('for any state the API reaches, GET /v1/snapshot then PUT restores it (random command sequences)', async () => {
  const seed = Number(process.env.CLOTHD_PROPERTY_SEED ?? Math.floor(Math.random() * 2 ** 31));
  console.log(`property test seed ${seed} (CLOTHD_PROPERTY_SEED=${seed} reruns it)`);
  const g = generator(seed);
  const d = await start(['--paused', '--nx', '8', '--ny', '8', '--auto-drop-interval', '0', '--max-rocks', '16']);
  const at = await layout(d);
  const saved = [];
  const history = [];
  for (let k = 0; k < 150; k++) {
    history.push(await randomMove(d, g, at, saved));
    const before = await ok(d, 'GET', '/v1/sim');
    const snap = await snapshot(d);
    const put = await call(d, 'PUT', '/v1/snapshot', snap, OCTETS);
    const context = `seed ${seed}, after:\n  ${history.slice(-6).join('\n  ')}`;
    assert.equal(put.status, 200, `PUT of its own snapshot: ${put.text}; ${context}`);
    assert.equal(put.json.state_hash, before.state_hash, context);
    assert.ok((await snapshot(d)).equals(snap), `the snapshot after the PUT is the one put; ${context}`);
    if (g.next() < 0.15) saved.push(snap);
  }
  const statuses = {};
  for (const h of history) {
    const s = / -> (\d+)$/.exec(h)?.[1] ?? 'skipped';
    statuses[s] = (statuses[s] ?? 0) + 1;
  }
  console.log(`150 moves, answers ${JSON.stringify(statuses)}`);
  await stop(d);
});
