// limits.test.mjs - every limit of docs/security.md "Limits" hit by a test: connections (in all, per
// address, idle time), changing requests per second (429 with Retry-After), rocks, the memory a
// scene or a snapshot would take, stream clients. A refused request changes nothing (the state
// hash of a paused daemon stays). Bodies over max_body, oversized stream messages and stalled
// stream clients are in errors.test.mjs and stream.test.mjs.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { connect as tcp } from 'node:net';
import { start, stop, call, ok, hash, until, metric } from './harness.mjs';
import { connect, next, daemon } from './wsclient.mjs';

// An open TCP connection to the daemon that sends nothing; `closed` resolves when the server
// closes it (with `answered`: whether any bytes came first).
function idle(d) {
  const { port } = new URL(d.url);
  return new Promise((resolve, reject) => {
    const sock = tcp(Number(port), '127.0.0.1');
    const c = { sock, answered: false };
    c.closed = new Promise((r) => sock.on('close', r));
    sock.on('data', () => (c.answered = true));
    sock.on('error', () => {});
    sock.on('connect', () => resolve(c));
    setTimeout(() => reject(new Error('no connection')), 5000);
  });
}

// A whole request over its own connection, from `from` (any 127/8 address reaches a daemon on
// 127.0.0.1): the status, or null when the server closed it unanswered; `text` the whole answer.
function rawAnswer(d, method = 'GET', path = '/v1/sim', from = '127.0.0.1') {
  const { port } = new URL(d.url);
  return new Promise((resolve) => {
    const sock = tcp({ port: Number(port), host: '127.0.0.1', localAddress: from });
    let text = '';
    sock.on('data', (b) => (text += b));
    sock.on('error', () => {});
    sock.on('close', () => resolve({ status: /^HTTP\/1\.1 (\d+)/.exec(text)?.[1] ?? null, text }));
    sock.on('connect', () => sock.write(`${method} ${path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n`));
  });
}
const rawStatus = async (d, method, path) => (await rawAnswer(d, method, path)).status;

test('connections: at most max_connections_per_ip from one address, idle ones closed after connection_timeout',
  async () => {
    const d = await start(['--paused', '--max-connections-per-ip', '3', '--connection-timeout', '2']);
    const held = [await idle(d), await idle(d), await idle(d)];
    // The client's connect() returns once the kernel has the connection; wait until the daemon
    // has taken all three (asked from another address: 3 idle + the asking one), or a fourth could
    // race a third into a worker thread and be counted first.
    await until('the daemon holds the three idle connections', async () =>
      metric((await rawAnswer(d, 'GET', '/metrics', '127.0.0.2')).text, 'clothd_http_connections') === 4);
    assert.equal(await rawStatus(d), null, 'a fourth connection from this address is closed unanswered');
    // Idle connections go after connection_timeout, and then there is room again.
    await Promise.all(held.map((c) => c.closed));
    assert.ok(held.every((c) => !c.answered));
    assert.equal(await rawStatus(d), '200');
    await stop(d);
  });

test('connections: at most max_connections in all; past it the connection waiting longest makes room', async (t) => {
  // One HTTP thread: one address holds both places with connections that send nothing. A third
  // connection is not left in the backlog behind them: the one that has waited longest for a
  // request is closed (unanswered), and the third is served at once.
  const d = await start(['--paused', '--max-connections', '2', '--connection-timeout', '30', '--http-threads', '1']);
  const held = [await idle(d), await idle(d)];
  t.after(() => { held.forEach((c) => c.sock.destroy()); return stop(d); });
  assert.equal(await rawStatus(d), '200');
  await held[0].closed;
  assert.equal(held[0].answered, false);
  assert.equal(held[1].sock.destroyed, false, 'the newer idle connection stays');
  assert.equal(metric((await call(d, 'GET', '/metrics')).text, 'clothd_http_connections_closed_total', 'reason="evicted"'), 1);
});

test('changing requests past rate_burst, then rate_limit per second, are 429 with Retry-After; reads are not limited',
  async () => {
    const d = await start(['--paused', '--rate-limit', '2', '--rate-burst', '5']);
    const h0 = await hash(d);
    for (let k = 0; k < 5; k++) assert.equal((await call(d, 'POST', '/v1/sim/pause')).status, 200, `request ${k + 1}`);
    const r = await call(d, 'PATCH', '/v1/params', { k_bend: 33 });
    assert.equal(r.status, 429);
    assert.equal(r.json.type, 'urn:clothd:problem:rate-limited');
    const wait = Number(r.headers.get('retry-after'));
    assert.equal(wait, 1); // one request at 2 per second: within a second
    // Refused: nothing changed. Reads go on.
    for (let k = 0; k < 20; k++) assert.equal((await call(d, 'GET', '/v1/params')).status, 200);
    assert.equal((await ok(d, 'GET', '/v1/params')).k_bend, 20);
    assert.equal(await hash(d), h0);
    // After Retry-After the bucket has a token again.
    await new Promise((res) => setTimeout(res, wait * 1000)); // the wait the server asked for
    assert.equal((await call(d, 'PATCH', '/v1/params', { k_bend: 33 })).status, 200);
    await stop(d);
  });

test('at most max_rocks rocks', async () => {
  const d = await start(['--paused', '--max-rocks', '2', '--auto-drop-interval', '0']);
  for (const x of [-0.5, 0.5]) await ok(d, 'POST', '/v1/rocks', { position: [x, 0, 2], radius: 0.1 });
  const h0 = await hash(d);
  const r = await call(d, 'POST', '/v1/rocks', { position: [0, 0, 2], radius: 0.1 });
  assert.equal(r.status, 422);
  assert.equal(r.json.param, 'max_rocks');
  assert.equal(await hash(d), h0);
  await stop(d);
});

test('a scene or a snapshot past max_state_mb is refused before anything is allocated', async () => {
  // A 200 x 200 cloth costs some 70 MB (its state, implicit_euler's workspace, the stream's
  // buffers): a 2 MiB limit refuses it, a 128 MiB one does not.
  const big = await start(['--paused', '--nx', '200', '--ny', '200', '--max-state-mb', '128']);
  const snapshot = (await call(big, 'GET', '/v1/snapshot')).buf;
  await stop(big);
  const d = await start(['--paused', '--nx', '16', '--ny', '16', '--max-state-mb', '2', '--max-body', String(64 << 20)]);
  const h0 = await hash(d);
  const r = await call(d, 'PUT', '/v1/scene', { nx: 200, ny: 200 });
  assert.equal(r.status, 422);
  assert.equal(r.json.type, 'urn:clothd:problem:limit');
  assert.equal(r.json.param, 'nx');
  assert.match(r.json.detail, /200 x 200 cloth needs \d+ MiB, more than the memory limit of 2 MiB/);
  const s = await call(d, 'PUT', '/v1/snapshot', snapshot, { 'Content-Type': 'application/octet-stream' });
  assert.equal(s.status, 422);
  assert.match(s.json.detail, /memory limit/);
  // Even the largest grid the table allows: the estimate is overflow-checked, nothing allocated.
  assert.equal((await call(d, 'PUT', '/v1/scene', { nx: 4096, ny: 4096 })).status, 422);
  assert.equal(await hash(d), h0);
  assert.equal((await ok(d, 'GET', '/v1/scene')).nx, 16);
  await stop(d);
});

test('at most stream_max_clients stream clients', async () => {
  const d = await daemon(['--paused', '--stream-max-clients', '2']);
  const a = await connect(d), b = await connect(d);
  await next(a, 'text', (m) => m.type === 'hello');
  await next(b, 'text', (m) => m.type === 'hello');
  // Refused connections, however many, take no place: the count stays right.
  for (let k = 0; k < 3; k++) await assert.rejects(connect(d));
  assert.equal(metric((await call(d, 'GET', '/metrics')).text, 'clothd_stream_refused_total', 'reason="clients"'), 3);
  assert.match((await call(d, 'GET', '/metrics')).text, /clothd_stream_clients 2/);
  a.ws.close();
  await until('room again', async () => /clothd_stream_clients 1/.test((await call(d, 'GET', '/metrics')).text));
  const c = await connect(d);
  await next(c, 'text', (m) => m.type === 'hello');
  b.ws.close();
  c.ws.close();
  await stop(d);
});
