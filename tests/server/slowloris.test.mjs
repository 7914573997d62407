// slowloris.test.mjs - clients that send slowly cannot hold the HTTP server (docs/security.md "Limits"):
// a request's head must arrive within header_timeout whatever its pace (connection_timeout counts
// idle gaps only, which a byte every half second never leaves), a body must keep min_body_rate,
// and when max_connections are taken by connections that wait, a new client from another address
// is answered at once. Linux routes all of 127/8 to lo: the tricklers bind 127.0.0.2-9.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import net from 'node:net';
import { start, stop, call, hash, metric, until } from './harness.mjs';

// A connection from `from` that sends `text` one byte every `every` ms and never finishes (the
// text has no blank line). `closed` resolves with the time the server closed it.
function trickle(d, { from = '127.0.0.1', text = 'GET /v1/sim HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ', every = 500 } = {}) {
  const { port } = new URL(d.url);
  const c = { answered: false, connected: false, closedAt: null };
  c.sock = net.connect({ port: Number(port), host: '127.0.0.1', localAddress: from });
  c.sock.on('error', () => {});
  c.sock.on('data', () => (c.answered = true));
  let k = 0;
  const send = () => {
    if (c.sock.destroyed) return;
    c.sock.write(text[k % text.length] ?? 'a');
    k = Math.min(k + 1, text.length); // past the request line and Host, the header's value goes on
  };
  c.opened = new Promise((resolve) => c.sock.on('connect', () => {
    c.connected = true;
    c.openedAt = Date.now();
    send();
    c.timer = setInterval(send, every);
    resolve(c);
  }));
  c.closed = new Promise((resolve) => c.sock.on('close', () => {
    clearInterval(c.timer);
    c.closedAt = Date.now();
    resolve(c.closedAt);
  }));
  return c;
}

// One request on a fresh connection from 127.0.0.1: its status, body and how long the answer took.
function timed(d, path = '/v1/health') {
  const { port } = new URL(d.url);
  return new Promise((resolve) => {
    const t0 = performance.now();
    const sock = net.connect(Number(port), '127.0.0.1');
    let text = '';
    sock.on('data', (b) => (text += b));
    sock.on('close', () => {
      const m = /^HTTP\/1\.1 (\d+)/.exec(text);
      resolve({ status: m ? Number(m[1]) : null, ms: performance.now() - t0, body: text.slice(text.indexOf('\r\n\r\n') + 4) });
    });
    sock.on('error', () => {});
    sock.on('connect', () => sock.write(`GET ${path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n`));
    setTimeout(() => sock.destroy(), 5000); // no answer in 5 s: status null
  });
}

test('a head that trickles in is cut off after header_timeout; so is a body slower than min_body_rate', async () => {
  const d = await start(['--paused', '--header-timeout', '2', '--min-body-rate', '200', '--connection-timeout', '60',
    '--auto-drop-interval', '0']);
  const h0 = await hash(d);
  // Never idle for long (a byte every 0.5 s, connection_timeout 60 s), but never done: closed
  // unanswered within header_timeout and the sweep's tenth of a second (a second of slack for a
  // loaded machine).
  const slow = trickle(d);
  await slow.opened;
  await slow.closed;
  const held = slow.closedAt - slow.openedAt;
  assert.ok(held >= 1900 && held < 3500, `closed after ${held} ms`);
  assert.equal(slow.answered, false);
  // A body of 4000 bytes sent at 50 bytes a second: past header_timeout it falls behind 200 B/s.
  const body = trickle(d, { text: `POST /v1/rocks HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 4000\r\n\r\n`, every: 20 });
  await body.opened;
  await body.closed;
  assert.equal(body.answered, false);
  // A keep-alive connection that goes idle after an answer is closed after header_timeout too.
  const { port } = new URL(d.url);
  const idle = net.connect(Number(port), '127.0.0.1');
  let reply = '';
  idle.on('data', (b) => (reply += b));
  const idleClosed = new Promise((r) => idle.on('close', r));
  idle.on('connect', () => idle.write('GET /v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n'));
  await idleClosed;
  assert.match(reply, /^HTTP\/1\.1 200 /);
  const m = (await call(d, 'GET', '/metrics')).text;
  // The trickler, the idle keep-alive one, and any of the test's own idle keep-alive connections.
  assert.ok(metric(m, 'clothd_http_connections_closed_total', 'reason="header_timeout"') >= 2);
  assert.equal(metric(m, 'clothd_http_connections_closed_total', 'reason="body_rate"'), 1);
  // A body at a sound pace is taken, and nothing the slow ones sent changed the state.
  assert.equal(await hash(d), h0);
  assert.equal((await call(d, 'POST', '/v1/rocks', { position: [0, 0, 2], radius: 0.1 })).status, 201);
  await stop(d);
});

test('512 trickling connections from 127.0.0.2-9 (64 each): a fresh client from 127.0.0.1 is answered within 1 s', async (t) => {
  // The defaults: max_connections 512, max_connections_per_ip 64, header_timeout 10 s.
  const d = await start(['--paused']);
  const conns = [];
  t.after(() => {
    for (const c of conns) c.sock.destroy();
    return stop(d);
  });
  for (let a = 2; a <= 9; a++) for (let k = 0; k < 64; k++) conns.push(trickle(d, { from: `127.0.0.${a}` }));
  const t0 = Date.now();
  await Promise.all(conns.map((c) => Promise.race([c.opened, c.closed])));
  const accepted = conns.filter((c) => c.connected).length;
  // All 512 are the server's before the fresh client comes (the server counts them; each look
  // is a client too, and takes a waiting place once the server is full).
  await until('the server holding every trickler', async () =>
    metric((await timed(d, '/metrics')).body, 'clothd_http_connections') >= 512);
  const droppedBefore = conns.filter((c) => c.closedAt).length;
  const fresh = await timed(d);
  const droppedAfter = conns.filter((c) => c.closedAt).length;
  const m = (await timed(d, '/metrics')).body;
  const evicted = metric(m, 'clothd_http_connections_closed_total', 'reason="evicted"');
  const open = metric(m, 'clothd_http_connections');
  console.log(`slowloris: ${conns.length} trickling connections from 8 addresses, ${accepted} accepted in ` +
    `${Date.now() - t0} ms; closed by the server before the fresh request ${droppedBefore}, after it ${droppedAfter} ` +
    `(evicted to make room: ${evicted}); fresh client from 127.0.0.1: ${fresh.status} in ${fresh.ms.toFixed(1)} ms; ` +
    `connections open ${open}`);
  assert.equal(accepted, 512);
  assert.equal(fresh.status, 200);
  assert.ok(fresh.ms < 1000, `the fresh client waited ${fresh.ms} ms`);
  assert.ok(evicted >= 1 && evicted <= 16, `evicted ${evicted}`);
  assert.ok(open <= 512, `${open} connections open, more than max_connections`);
  // The tricklers are all gone within header_timeout (10 s) of their start, and the server is
  // answering as before.
  await Promise.all(conns.map((c) => c.closed));
  assert.ok(conns.every((c) => !c.answered));
  assert.equal((await timed(d)).status, 200);
});
