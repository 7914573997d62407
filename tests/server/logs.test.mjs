// logs.test.mjs - clothd's log (docs/operating.md "Logs"): --log-format json writes one JSON object
// per line (time in RFC 3339 UTC, level, msg, scene and request_id where known), one access line
// per HTTP request with the route's pattern (never the raw path), status, duration and the request
// id it answered with in X-Request-Id (the client's, or one made per request); --log-level drops
// what is below it; an unknown format or level refuses to start.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { start, stop, call, until, refusedStart } from './harness.mjs';

const small = ['--nx', '16', '--ny', '16', '--auto-drop-interval', '0', '--paused'];
const RFC3339 = /^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z$/;
const lines = (d) => d.log.split('\n').filter((l) => l.length > 0);
const accessOf = (d, id) => lines(d).map((l) => JSON.parse(l)).find((o) => o.request_id === id && o.route);

test('--log-format json: one object per line, and an access line per request with the route pattern', async () => {
  const d = await start([...small, '--log-format', 'json']);
  const a = await call(d, 'GET', '/v1/scenes/default/rocks/7', undefined, { 'X-Request-Id': 'mine-1' });
  assert.equal(a.status, 404);
  assert.equal(a.headers.get('x-request-id'), 'mine-1');
  const b = await call(d, 'GET', '/v1/sim');
  const made = b.headers.get('x-request-id');
  assert.match(made, /^[0-9a-f]{8}-\d+$/); // none was sent: one is made
  const c = await call(d, 'GET', '/v1/sim');
  assert.notEqual(c.headers.get('x-request-id'), made);
  const bad = await call(d, 'GET', '/v1/sim', undefined, { 'X-Request-Id': 'no spaces "or quotes"' });
  assert.match(bad.headers.get('x-request-id'), /^[0-9a-f]{8}-\d+$/); // not echoed: replaced
  await until('the access lines', () => accessOf(d, 'mine-1') && accessOf(d, made));
  for (const l of lines(d)) {
    const o = JSON.parse(l); // every line is JSON
    assert.match(o.time, RFC3339, l);
    assert.ok(['debug', 'info', 'warn', 'error'].includes(o.level), l);
    assert.equal(typeof o.msg, 'string', l);
  }
  const one = accessOf(d, 'mine-1');
  assert.equal(one.method, 'GET');
  assert.equal(one.route, '/v1/scenes/{scene}/rocks/{id}'); // the pattern, not the path
  assert.equal(one.status, 404);
  assert.equal(one.scene, 'default');
  assert.equal(one.level, 'info');
  assert.ok(typeof one.duration_ms === 'number' && one.duration_ms >= 0);
  const two = accessOf(d, made);
  assert.equal(two.route, '/v1/sim');
  assert.equal(two.status, 200);
  await call(d, 'GET', '/no/such/file/../x');
  await stop(d);
  assert.ok(lines(d).every((l) => !l.includes('/no/such')), 'a raw path is never logged');
});

test('text lines carry the level and the access line; --log-level warn drops info and the access log', async () => {
  const d = await start(small);
  await call(d, 'GET', '/v1/sim', undefined, { 'X-Request-Id': 'text-1' });
  await until('the access line', () => /clothd: http GET \/v1\/sim 200 [\d.]+ ms scene=default id=text-1$/m.test(d.log));
  await stop(d);
  const q = await start([...small, '--log-level', 'warn']);
  await call(q, 'GET', '/v1/sim', undefined, { 'X-Request-Id': 'quiet-1' });
  await stop(q);
  assert.doesNotMatch(q.log, /quiet-1/);
  // The line naming the port is written at every level (a supervisor of --port 0 needs it).
  assert.deepEqual(lines(q).map((l) => /listening on/.test(l)), [true]);
});

test('an unknown --log-format or --log-level refuses to start, saying what is allowed', async () => {
  for (const [flag, value] of [['--log-format', 'xml'], ['--log-level', 'loud'], ['--log-format', '']]) {
    const r = await refusedStart([flag, value]);
    assert.notEqual(r.code, 0);
    assert.match(r.log, flag === '--log-format' ? /log_format.*text\|json/ : /log_level.*debug\|info\|warn\|error/, r.log);
  }
});
