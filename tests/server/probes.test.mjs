// probes.test.mjs - GET /livez and GET /readyz (PROTOCOL.md "GET /livez, GET /readyz"): liveness
// follows the sim thread's heartbeat (a thread wedged by clothd-testhooks turns /livez 503 after
// liveness_timeout, and 200 again once it goes on, while /v1/health still says ok); readiness
// follows room for another scene (max_scenes, max_state_mb); both answer without a token, tell
// nothing but state, and keep the Host check and the methods of any read.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { chmodSync, writeFileSync } from 'node:fs';
import { request } from 'node:http';
import { join } from 'node:path';
import { start, stop, call, ok, until, tempDir, refusedStart, TESTHOOKS, PROBLEM } from './harness.mjs';

const hooks = TESTHOOKS ? {} : { skip: 'CLOTHD_TESTHOOKS_BIN is not set (ctest sets it to build/tests/server/clothd-testhooks)' };
const small = ['--nx', '16', '--ny', '16', '--auto-drop-interval', '0'];

test('/livez goes 503 while the sim thread is wedged and 200 once it turns again; /v1/health does not see it', hooks, async () => {
  // After frame 5 the hook stops the sim thread for 2.5 s; liveness_timeout is 1 s.
  const d = await start([...small, '--liveness-timeout', '1'],
    { bin: TESTHOOKS, env: { CLOTHD_TEST_WEDGE_FRAME: '5', CLOTHD_TEST_WEDGE_MS: '2500' } });
  await until('the wedge', () => /sim thread wedged/.test(d.log));
  const dead = await until('/livez 503', async () => {
    const r = await call(d, 'GET', '/livez');
    return r.status === 503 && r;
  }, { every: 50 });
  assert.equal(dead.type, PROBLEM);
  assert.equal(dead.json.type.endsWith('not-live'), true);
  assert.match(dead.json.detail, /has not turned for [\d.]+ s \(liveness_timeout: 1 s\)/);
  assert.equal((await call(d, 'GET', '/v1/health')).status, 200); // what /livez is for
  await until('/livez 200 again', async () => (await call(d, 'GET', '/livez')).status === 200, { every: 50 });
  assert.match(d.log, /sim thread goes on/);
  assert.deepEqual(await ok(d, 'GET', '/livez'), { status: 'live' });
  await stop(d);
});

test('/livez stays 200 while every scene is paused: the idle thread still turns', async () => {
  const d = await start([...small, '--paused', '--liveness-timeout', '1']);
  // The port may open before the sim thread's first turn (until then /livez says it has not
  // started): from that turn on, three timeouts of idleness, each probe answered 200 (the thread
  // turns at least four times a second, well within the timeout of 1 s).
  await until('the first turn', async () => (await call(d, 'GET', '/livez')).status === 200, { every: 50 });
  const t0 = Date.now();
  while (Date.now() - t0 < 3000) {
    assert.equal((await call(d, 'GET', '/livez')).status, 200);
    await new Promise((r) => setTimeout(r, 250)); // sampling idleness, not waiting for a condition
  }
  await stop(d);
});

test('/readyz: 200 with room for a scene, 503 with the reason at max_scenes or max_state_mb', async () => {
  const d = await start([...small, '--paused', '--max-scenes', '2']);
  assert.deepEqual(await ok(d, 'GET', '/readyz'), { status: 'ready', scenes: 1, max_scenes: 2 });
  assert.equal((await call(d, 'POST', '/v1/scenes', { id: 'two' })).status, 201);
  const full = await call(d, 'GET', '/readyz');
  assert.equal(full.status, 503);
  assert.equal(full.type, PROBLEM);
  assert.equal(full.json.param, 'max_scenes');
  assert.match(full.json.detail, /max_scenes \(2\)/);
  assert.equal((await call(d, 'DELETE', '/v1/scenes/two')).status, 200);
  assert.equal((await call(d, 'GET', '/readyz')).status, 200);
  await stop(d);

  // A 24 x 24 cloth (1.7 MB under implicit_euler, with one rock) fits once in 2 MiB, not twice.
  const e = await start(['--nx', '24', '--ny', '24', '--auto-drop-interval', '0', '--paused', '--max-state-mb', '2', '--max-rocks', '1']);
  const room = await call(e, 'GET', '/readyz');
  assert.equal(room.status, 503, room.text);
  assert.equal(room.json.param, 'max_state_mb');
  assert.match(room.json.detail, /does not fit in what max_state_mb \(2 MiB\) leaves/);
  await stop(e);
});

test('probes need no token, keep the Host check, answer GET only, and reveal nothing else', async () => {
  const dir = tempDir();
  const f = join(dir, 'control');
  writeFileSync(f, 'c0ntrol-t0ken-0123456789abcdef\n');
  chmodSync(f, 0o600);
  const d = await start([...small, '--paused', '--token-file', f]);
  assert.equal((await call(d, 'GET', '/v1/sim')).status, 401);
  for (const path of ['/livez', '/readyz']) {
    const r = await call(d, 'GET', path);
    assert.equal(r.status, 200, path);
    assert.deepEqual(Object.keys(r.json).sort(), path === '/livez' ? ['status'] : ['max_scenes', 'scenes', 'status']);
    const post = await call(d, 'POST', path, {});
    assert.equal(post.status, 405, path); // no row changes anything there
    assert.equal(post.headers.get('allow'), 'GET, HEAD');
  }
  const port = new URL(d.url).port;
  const withHost = (host) => new Promise((resolve, reject) => {
    const r = request({ host: '127.0.0.1', port, path: '/livez', headers: { Host: host } }, (res) => {
      res.resume();
      res.on('end', () => resolve(res.statusCode));
    });
    r.on('error', reject);
    r.end();
  });
  assert.equal(await withHost('attacker.example'), 403);
  await stop(d);
});

test('liveness_timeout out of range refuses to start', async () => {
  for (const v of ['0', '3601', 'soon']) {
    const r = await refusedStart(['--liveness-timeout', v]);
    assert.notEqual(r.code, 0);
    assert.match(r.log, /liveness_timeout/);
  }
});
