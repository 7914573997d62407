// strict.test.mjs - HTTP as RFC 9110/9112 ask and the stream's handshake as RFC 6455 asks, over raw
// sockets (a client library would tidy the bytes): HEAD on every GET route, absolute-form
// targets, the 400 family for a request whose framing cannot be trusted (one well-formed answer,
// then the connection closes), and every refused stream upgrade answered with its status and a
// problem+json body. What libmicrohttpd answers itself (PROTOCOL.md "Conventions") is checked for
// its status.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import net from 'node:net';
import { chmodSync, writeFileSync } from 'node:fs';
import { join } from 'node:path';
import WebSocket from 'ws';
import { CLOTHD, start, stop, call, hash, metric, tempDir, execChecked, PROBLEM } from './harness.mjs';
import { daemon } from './wsclient.mjs';

// Sends bytes, reads to the close: the status lines (all of them: there must be one), head, body.
function raw(port, bytes) {
  return new Promise((resolve) => {
    const sock = net.connect(port, '127.0.0.1', () => sock.write(bytes));
    let buf = Buffer.alloc(0);
    sock.on('data', (b) => (buf = Buffer.concat([buf, b])));
    sock.on('error', () => {});
    const timer = setTimeout(() => sock.destroy(), 5000);
    sock.on('close', () => {
      clearTimeout(timer);
      const text = buf.toString('latin1');
      const end = text.indexOf('\r\n\r\n');
      const head = end < 0 ? text : text.slice(0, end);
      const headers = Object.fromEntries(head.split('\r\n').slice(1).map((l) => [l.slice(0, l.indexOf(':')).toLowerCase(),
        l.slice(l.indexOf(':') + 1).trim()]));
      resolve({ text, status: Number(/^HTTP\/1\.1 (\d{3}) /.exec(text)?.[1] ?? 0), statusLines: (text.match(/HTTP\/1\.1 \d{3} /g) ?? []).length,
        headers, body: end < 0 ? '' : text.slice(end + 4) });
    });
  });
}

function problemOf(r, status) {
  assert.equal(r.status, status, r.text.slice(0, 300));
  assert.equal(r.statusLines, 1, `one status line: ${r.text.slice(0, 300)}`);
  assert.equal(r.headers['content-type'], PROBLEM, r.text.slice(0, 300));
  assert.equal(Number(r.headers['content-length']), Buffer.byteLength(r.body, 'latin1'));
  const p = JSON.parse(r.body);
  assert.equal(p.status, status);
  return p;
}

test('HEAD on every GET route, absolute-form targets', async () => {
  const d = await start(['--paused', '--auto-drop-interval', '0']);
  const port = Number(new URL(d.url).port);
  await call(d, 'POST', '/v1/rocks', { position: [0, 0, 2], radius: 0.1 });
  await call(d, 'POST', '/v1/recordings', { seconds: 1, id: 'r' });
  const { stdout } = await execChecked(CLOTHD, ['routes']);
  const gets = stdout.trim().split('\n').filter((l) => l.startsWith('GET ')).map((l) => l.slice(4).replace('{id}', '1').replace('{scene}', 'default')
    .replace('{rid}', 'r'));
  assert.ok(gets.length >= 11);
  for (const path of [...gets, '/']) {
    const get = await raw(port, `GET ${path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n`);
    const head = await raw(port, `HEAD ${path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n`);
    assert.equal(get.status, 200, path);
    assert.equal(head.status, 200, `HEAD ${path}: ${head.text.slice(0, 200)}`);
    assert.equal(head.body, '', `HEAD ${path} has no body`);
    assert.equal(head.headers['content-type'], get.headers['content-type'], path);
  }
  // The Allow of a 405 lists HEAD beside GET.
  assert.equal((await raw(port, 'DELETE /v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n')).headers.allow,
    'GET, HEAD');
  // An absolute-form target is served; its host stands for Host (and is checked like it).
  const abs = await raw(port, `GET http://127.0.0.1:${port}/v1/rocks HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n`);
  assert.equal(abs.status, 200);
  assert.equal(JSON.parse(abs.body).rocks.length, 1);
  const rebinding = await raw(port, 'GET http://attacker.example/v1/sim HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n');
  assert.equal(problemOf(rebinding, 403).type, 'urn:clothd:problem:host-not-allowed');
  await stop(d);
});

test('requests whose framing cannot be trusted get one well-formed 400 (or 501), then the connection closes', async () => {
  const d = await start(['--paused', '--auto-drop-interval', '0']);
  const port = Number(new URL(d.url).port);
  const h0 = await hash(d);
  const rock = '{"position": [0, 0, 2], "radius": 0.1}';
  const post = (head, body = rock) => `POST /v1/rocks HTTP/1.1\r\n${head}Connection: close\r\n\r\n${body}`;
  const cases = [
    ['HTTP/1.1 without Host', `POST /v1/rocks HTTP/1.1\r\nContent-Length: ${rock.length}\r\nConnection: close\r\n\r\n${rock}`, 400],
    ['two Hosts', post(`Host: 127.0.0.1\r\nHost: 127.0.0.1\r\nContent-Length: ${rock.length}\r\n`), 400],
    ['Host with a space before the colon', post(`Host : 127.0.0.1\r\nContent-Length: ${rock.length}\r\n`), 400],
    ['two Content-Lengths', post(`Host: 127.0.0.1\r\nContent-Length: ${rock.length}\r\nContent-Length: 5\r\n`), 400],
    ['Content-Length and Transfer-Encoding', post(`Host: 127.0.0.1\r\nContent-Length: ${rock.length}\r\nTransfer-Encoding: chunked\r\n`,
      `${rock.length.toString(16)}\r\n${rock}\r\n0\r\n\r\n`), 400],
    ['a NUL in the path', `GET /v1/si\0m HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n`, 400],
    ['%00 in the path', `GET /v1/sim%00 HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n`, 400],
    ['a space in the target', `GET /v1/sim x HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n`, 400],
    ['an unknown transfer coding', post('Host: 127.0.0.1\r\nTransfer-Encoding: gzip\r\n'), 501],
  ];
  for (const [name, bytes, status] of cases) {
    const r = await raw(port, bytes);
    const p = problemOf(r, status);
    assert.match(p.type, /^urn:clothd:problem:(bad-request|not-implemented)$/, name);
    assert.equal(r.headers.connection, 'close', name);
  }
  // A target longer than the server reads: 414 as a problem (longer still, libmicrohttpd's own
  // 414 in plain HTML, PROTOCOL.md).
  problemOf(await raw(port, `GET /v1/${'a'.repeat(3000)} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n`), 414);
  assert.equal((await raw(port, `GET /${'a'.repeat(70000)} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n`)).status, 414);
  assert.equal((await raw(port, `GET /v1/sim HTTP/1.1\r\nHost: 127.0.0.1\r\nX-A: ${'a'.repeat(70000)}\r\n\r\n`)).status, 431);
  assert.equal((await raw(port, 'GET /v1/sim HTTP/2.0\r\nHost: 127.0.0.1\r\n\r\n')).status, 505);
  // HTTP/1.0 needs no Host; a well-formed request on the same server still works.
  assert.equal((await raw(port, 'GET /v1/health HTTP/1.0\r\n\r\n')).status, 200);
  assert.equal(await hash(d), h0, 'a refused request changed the state');
  assert.equal((await call(d, 'GET', '/v1/sim')).json.n_rocks, 0);
  await stop(d);
});

const upgrade = (port, path = '/stream', extra = '', version = '13') => `GET ${path} HTTP/1.1\r\nHost: 127.0.0.1:${port}\r\n` +
  `Upgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: ${version}\r\n` +
  `Sec-WebSocket-Protocol: clothd.v1\r\n${extra}\r\n`;

test('a refused stream upgrade is answered with its status and a problem: 404, 426, 403, 401, 503', async () => {
  const dir = tempDir();
  const f = join(dir, 'control');
  writeFileSync(f, 'c0ntrol-t0ken-0123456789abcdef\n');
  chmodSync(f, 0o600);
  const d = await daemon(['--paused', '--token-file', f, '--stream-max-clients', '1']);
  const sp = d.streamPort;
  const tok = '?token=c0ntrol-t0ken-0123456789abcdef';
  problemOf(await raw(sp, upgrade(sp, `/nope${tok}`)), 404);
  const v8 = await raw(sp, upgrade(sp, `/stream${tok}`, '', '8'));
  problemOf(v8, 426);
  assert.equal(v8.headers['sec-websocket-version'], '13');
  problemOf(await raw(sp, upgrade(sp, `/stream${tok}`, 'Origin: http://attacker.example\r\n')), 403);
  // An Origin too long to read is refused, not taken for none.
  problemOf(await raw(sp, upgrade(sp, `/stream${tok}`, `Origin: http://${'a'.repeat(400)}.example\r\n`)), 403);
  problemOf(await raw(sp, upgrade(sp, `/stream${tok}`).replace(`Host: 127.0.0.1:${sp}`, 'Host: attacker.example')), 403);
  const noToken = await raw(sp, upgrade(sp));
  problemOf(noToken, 401);
  assert.equal(noToken.headers['www-authenticate'], 'Bearer realm="clothd"');
  // A real client (node ws) sees the status too; the one client allowed, then 503 for the next.
  const first = new WebSocket(`ws://127.0.0.1:${sp}/stream${tok}`, 'clothd.v1');
  await new Promise((res, rej) => { first.on('open', res); first.on('error', rej); });
  const status = await new Promise((res) => {
    const ws = new WebSocket(`ws://127.0.0.1:${sp}/stream${tok}`, 'clothd.v1');
    ws.on('unexpected-response', (req, resp) => res(resp.statusCode));
    ws.on('error', () => {});
  });
  assert.equal(status, 503);
  first.close();
  const m = (await call(d, 'GET', '/metrics', undefined, { Authorization: 'Bearer c0ntrol-t0ken-0123456789abcdef' })).text;
  for (const [reason, n] of [['path', 1], ['version', 1], ['origin', 2], ['host', 1], ['token', 1], ['clients', 1]])
    assert.equal(metric(m, 'clothd_stream_refused_total', `reason="${reason}"`), n, reason);
  await stop(d);
});
