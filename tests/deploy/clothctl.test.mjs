// clothctl.test.mjs - scripts/clothctl (README's tour) against the real clothd, guarded by a
// token: each command's effect is checked through the API itself.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { execFile } from 'node:child_process';
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { start, stop, ok, call, tempDir } from '../server/harness.mjs';
import { SOURCE, cleanEnv, tokenFile } from './support.mjs';

const TOKEN = 'clothctl-t0ken-0123456789abcdef';
const CLOTHCTL = join(SOURCE, 'scripts/clothctl');

// Runs clothctl; resolves to { code, stdout, stderr } whatever the exit status.
function clothctl(env, ...args) {
  return new Promise((resolve) => {
    execFile(CLOTHCTL, args, { env: cleanEnv(env), encoding: 'buffer' }, (err, stdout, stderr) => {
      resolve({ code: err ? err.code : 0, stdout: stdout.toString('latin1'), raw: stdout, stderr: stderr.toString() });
    });
  });
}

test('clothctl: the tour, each command checked through the API', async () => {
  const dir = tempDir();
  const token = tokenFile(join(dir, 'token'), TOKEN);
  const d = await start(['--token-file', token, '--paused']);
  const auth = { Authorization: `Bearer ${TOKEN}` };
  const api = (method, path, body) => ok(d, method, path, body, auth);
  const env = { CLOTHD_URL: d.url, CLOTHD_TOKEN_FILE: token };
  const ctl = async (...args) => {
    const r = await clothctl(env, ...args);
    assert.equal(r.code, 0, `clothctl ${args.join(' ')}: ${r.stderr}`);
    return r;
  };
  try {
    // Refusals: no token is 401 (exit 1); nobody listening (exit 2); not NAME=VALUE (exit 2).
    let r = await clothctl({ CLOTHD_URL: d.url }, 'sim');
    assert.equal(r.code, 1);
    assert.match(r.stderr, /HTTP 401/);
    r = await clothctl({ CLOTHD_URL: 'http://127.0.0.1:1' }, 'health');
    assert.equal(r.code, 2);
    r = await clothctl(env, 'params', 'wind');
    assert.equal(r.code, 2);

    assert.equal(JSON.parse((await ctl('health')).stdout).status, 'ok');
    assert.equal(JSON.parse((await ctl('sim')).stdout).state, 'paused');

    await ctl('rock', '0.3', '0', '1.8', '0.12');
    const rocks = (await api('GET', '/v1/rocks')).rocks;
    assert.equal(rocks.length, 1);
    assert.equal(rocks[0].radius, 0.12);
    assert.deepEqual(JSON.parse((await ctl('rocks')).stdout).rocks.map((x) => x.id), rocks.map((x) => x.id));

    await ctl('params', 'wind=3,0,0', 'tear_strain=0.5', 'friction_model=coulomb_viscous');
    const params = await api('GET', '/v1/params');
    assert.deepEqual(params.wind, [3, 0, 0]);
    assert.equal(params.tear_strain, 0.5);

    const before = await api('GET', '/v1/sim');
    await ctl('step', '30');
    const after = await api('GET', '/v1/sim');
    assert.equal(after.frame - before.frame, 30);
    const hash = JSON.parse((await ctl('hash')).stdout).state_hash;
    assert.equal(hash, after.state_hash);

    const saved = join(dir, 'state.bin');
    await ctl('save', saved);
    assert.equal(readFileSync(saved).subarray(0, 4).toString(), 'CSNP');

    await ctl('scene', 'nx=32', 'ny=32', 'orientation=vertical', 'pins=top-edge');
    const scene = await api('GET', '/v1/scene');
    assert.equal(scene.nx, 32);
    assert.equal(scene.orientation, 'vertical');
    assert.equal(scene.pins, 'top-edge');

    await ctl('load', saved);
    assert.equal((await api('GET', '/v1/sim')).state_hash, hash, 'back to the saved state');

    await ctl('clear');
    assert.equal((await api('GET', '/v1/rocks')).rocks.length, 0);

    const m = await ctl('metrics', '^clothd_realtime_factor');
    assert.ok(m.stdout.trim().split('\n').every((l) => l.startsWith('clothd_realtime_factor')), m.stdout);

    await ctl('resume');
    assert.equal((await api('GET', '/v1/sim')).state, 'running');
    await ctl('pause');
    assert.equal(JSON.parse((await ctl('get', '/v1/sim')).stdout).state, 'paused');

    // A refused change: the problem+json on stdout, exit 1, nothing changed.
    r = await clothctl(env, 'params', 'k_bend=-1');
    assert.equal(r.code, 1);
    assert.match(r.stdout, /k_bend/);
    assert.equal((await api('GET', '/v1/params')).k_bend, params.k_bend);
  } finally {
    await stop(d);
  }
});

test('clothctl: scenes (list, create, delete) and --scene, each checked through the API', async () => {
  const d = await start(['--paused', '--nx', '8', '--ny', '8']);
  const env = { CLOTHD_URL: d.url };
  const ctl = async (...args) => {
    const r = await clothctl(env, ...args);
    assert.equal(r.code, 0, `clothctl ${args.join(' ')}: ${r.stderr}`);
    return JSON.parse(r.stdout);
  };
  try {
    assert.equal((await ctl('scenes', 'create', 'small', 'nx=6', 'ny=5')).id, 'small');
    assert.equal((await ok(d, 'GET', '/v1/scenes/small/sim')).n_vertices, 30);
    assert.match((await ctl('scenes', 'create')).id, /^scene-\d+$/);
    assert.deepEqual((await ctl('scenes')).scenes.map((s) => s.id).slice(0, 2), ['default', 'small']);
    await ctl('--scene', 'small', 'pause');
    const { step, substeps } = await ok(d, 'GET', '/v1/scenes/small/sim');
    await ctl('--scene', 'small', 'step', '2');
    assert.equal((await ok(d, 'GET', '/v1/scenes/small/sim')).step, step + 2 * substeps);
    await ctl('--scene', 'small', 'params', 'seed=9');
    assert.equal((await ok(d, 'GET', '/v1/scenes/small/params')).seed, 9);
    assert.equal((await ok(d, 'GET', '/v1/params')).seed, 1); // default untouched
    // (counted while paused: the scene ran before its pause, and may have dropped its own rock)
    const before = (await ok(d, 'GET', '/v1/scenes/small/rocks')).rocks.length;
    const viaEnv = await clothctl({ ...env, CLOTHD_SCENE: 'small' }, 'rock', '0', '0', '3', '0.1');
    assert.equal(viaEnv.code, 0, viaEnv.stderr);
    assert.equal((await ok(d, 'GET', '/v1/scenes/small/rocks')).rocks.length, before + 1);
    // A bad id never reaches the server (exit 2); an unknown one is the server's 404 (exit 1).
    let r = await clothctl(env, '--scene', 'Bad', 'sim');
    assert.equal(r.code, 2);
    r = await clothctl(env, '--scene', 'nope', 'sim');
    assert.equal(r.code, 1);
    assert.match(r.stderr, /HTTP 404/);
    assert.deepEqual(await ctl('scenes', 'delete', 'small'), { id: 'small', deleted: true });
    assert.equal((await call(d, 'GET', '/v1/scenes/small/sim')).status, 404);
  } finally {
    await stop(d);
  }
});
