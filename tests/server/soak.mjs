// soak.mjs - load, slow clients and hostile input at once against one real clothd (loopback only,
// bounded in time and count; everything stops by itself). Used by bench/soak.mjs (the long run,
// figures in docs/performance.md) and tests/server/soak.test.mjs (the short run in ctest).
//
// Two phases over one daemon (CPU backend, a control token set):
//  1. running, `seconds` long: wrk reads the API (GET /v1/sim, /v1/params, /v1/rocks, /metrics,
//     with the token), a changer makes valid changes (PATCH /v1/params, rocks) at a few per
//     second, `clients` stream clients (most read, some read slowly, some never read) and a
//     stream of hostile requests (bad JSON, NaN, out of range, oversized and chunked bodies, bad
//     Host, no or wrong token, wrong methods, unknown ids, deep nesting, garbage, huge headers,
//     slow partial requests). The sim's real-time factor and the daemon's RSS are sampled.
//  2. paused, `pausedSeconds` long: the same reads, clients and hostile requests, and nothing
//     valid that changes state; the state hash must not move.
// Every answer is checked: a well-formed HTTP/1.1 response with an expected status, and for the
// API's own errors problem+json whose status matches.
import { spawn } from 'node:child_process';
import { connect as tcp } from 'node:net';
import { writeFileSync } from 'node:fs';
import { join } from 'node:path';
import WebSocket from 'ws';
import { start, stop, tempDir, rssKiB, metric } from './harness.mjs';

const TOKEN = 'soak-control-token-0123456789';
const AUTH = `Bearer ${TOKEN}`;
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

async function api(d, method, path, body) {
  const res = await fetch(d.url + path, {
    method, headers: { Authorization: AUTH }, body: body === undefined ? undefined : JSON.stringify(body),
  });
  const text = await res.text();
  return { status: res.status, json: text && res.headers.get('content-type')?.includes('json') ? JSON.parse(text) : null };
}

// One raw request over its own connection. Resolves with { status, headers, body } parsed from
// whatever the server sent, or { status: null } when it closed without a byte.
function raw(d, bytes, { hold = 0, timeout = 20000 } = {}) {
  const { port } = new URL(d.url);
  return new Promise((resolve) => {
    const sock = tcp(Number(port), '127.0.0.1');
    const chunks = [];
    let done = false;
    const finish = () => {
      if (done) return;
      done = true;
      clearTimeout(timer);
      sock.destroy();
      resolve(parseResponse(Buffer.concat(chunks)));
    };
    const timer = setTimeout(finish, timeout);
    sock.on('data', (b) => chunks.push(b));
    sock.on('error', finish);
    sock.on('close', finish);
    sock.on('connect', async () => {
      for (const part of Array.isArray(bytes) ? bytes : [bytes]) {
        if (sock.destroyed) return;
        sock.write(part, 'latin1'); // bytes as given: the hostile cases include invalid UTF-8
        if (hold) await sleep(hold);
      }
    });
  });
}

function parseResponse(buf) {
  if (buf.length === 0) return { status: null };
  const text = buf.toString('latin1');
  const end = text.indexOf('\r\n\r\n');
  const m = /^HTTP\/1\.[01] (\d{3}) [^\r\n]*\r\n/.exec(text);
  if (!m || end < 0) return { status: 'malformed', head: text.slice(0, 80) };
  const headers = {};
  for (const line of text.slice(0, end).split('\r\n').slice(1)) {
    const i = line.indexOf(':');
    if (i <= 0) return { status: 'malformed', head: line.slice(0, 80) };
    headers[line.slice(0, i).trim().toLowerCase()] = line.slice(i + 1).trim();
  }
  let body = buf.subarray(end + 4);
  if (/chunked/i.test(headers['transfer-encoding'] ?? '')) body = unchunk(body);
  return { status: Number(m[1]), headers, body: body.toString('utf8') };
}

function unchunk(b) {
  const out = [];
  let at = 0;
  for (;;) {
    const eol = b.indexOf('\r\n', at);
    if (eol < 0) break;
    const n = parseInt(b.subarray(at, eol).toString(), 16);
    if (!(n > 0)) break;
    out.push(b.subarray(eol + 2, eol + 2 + n));
    at = eol + 2 + n + 2;
  }
  return Buffer.concat(out);
}

// The hostile requests: [name, request bytes (or parts sent with pauses), statuses allowed,
// whether the answer is the API's own problem+json, only while running].
function hostile(host) {
  const req = (method, path, body, { auth = AUTH, hostHeader = host, extra = '' } = {}) =>
    `${method} ${path} HTTP/1.1\r\nHost: ${hostHeader}\r\n${auth ? `Authorization: ${auth}\r\n` : ''}${extra}` +
    `Connection: close\r\n${body !== undefined ? `Content-Length: ${Buffer.byteLength(body, 'latin1')}\r\n` : ''}\r\n${body ?? ''}`;
  const huge = 'x'.repeat(2 * 1024 * 1024);
  const chunked = (n) => {
    const piece = 'y'.repeat(64 * 1024);
    return `${(64 * 1024).toString(16)}\r\n${piece}\r\n`.repeat(n) + '0\r\n\r\n';
  };
  return [
    ['NaN', req('PATCH', '/v1/params', '{"k_bend": NaN}'), [422], true],
    ['1e999', req('PATCH', '/v1/params', '{"k_bend": 1e999}'), [422], true],
    ['out of range', req('PATCH', '/v1/params', '{"k_bend": -5}'), [422], true],
    ['wrong type', req('PATCH', '/v1/params', '{"wind": "east"}'), [422], true],
    ['unknown field', req('PATCH', '/v1/params', '{"k_bendy": 1}'), [400], true],
    ['duplicate key', req('PATCH', '/v1/params', '{"k_bend": 1, "k_bend": 2}'), [400], true],
    ['not JSON', req('POST', '/v1/rocks', '{"position": [0, 0,'), [400], true],
    ['invalid UTF-8', req('POST', '/v1/rocks', Buffer.from([0x7b, 0x22, 0xff, 0xfe, 0x22, 0x3a, 0x31, 0x7d]).toString('latin1')), [400], true],
    ['deep nesting', req('PATCH', '/v1/params', '['.repeat(5000) + ']'.repeat(5000)), [400], true],
    ['NaN rock', req('POST', '/v1/rocks', '{"position": [0, 0, NaN]}'), [422], true],
    ['huge rock', req('POST', '/v1/rocks', '{"position": [0, 0, 1], "radius": 1e30}'), [422], true],
    ['huge scene', req('PUT', '/v1/scene', '{"nx": 100000, "ny": 100000}'), [422], true],
    ['bad snapshot', req('PUT', '/v1/snapshot', 'CLOTHSIM but not really'), [400], true],
    ['oversized body', req('POST', '/v1/rocks', huge), [413, null], true],
    ['oversized chunked body', `POST /v1/rocks HTTP/1.1\r\nHost: ${host}\r\nAuthorization: ${AUTH}\r\nTransfer-Encoding: chunked\r\nConnection: close\r\n\r\n${chunked(24)}`, [413, null], true],
    ['rebinding Host', req('GET', '/v1/sim', undefined, { hostHeader: 'attacker.example' }), [403], true],
    ['no token', req('POST', '/v1/sim/reset', '{}', { auth: '' }), [401], true],
    ['wrong token', req('PATCH', '/v1/params', '{"k_bend": 33}', { auth: 'Bearer not-the-token-at-all-000' }), [401], true],
    ['unknown rock', req('DELETE', '/v1/rocks/999999', undefined), [404], true],
    ['non-numeric id', req('GET', '/v1/rocks/abc', undefined), [404], true],
    ['unknown route', req('GET', '/v1/../../etc/passwd', undefined), [400, 404], false],
    ['wrong method', req('DELETE', '/v1/sim', undefined), [405], true],
    ['step while running', req('POST', '/v1/sim/step', '{"frames": 1}'), [409], true, 'running'],
    ['grab out of range', req('PUT', '/v1/grab', '{"vertex": -1, "target": [0, 0, 1]}'), [400, 422], true],
    ['garbage', 'GARBAGE\r\n\r\n', [400, null], false],
    ['bad version', `GET /v1/sim HTTP/9.9\r\nHost: ${host}\r\n\r\n`, [505], false],
    ['bad header line', `GET /v1/sim HTTP/1.1\r\nHost: ${host}\r\nNo colon here\r\n\r\n`, [400], false],
    // libmicrohttpd waits for the rest of a request line with a NUL in it until connection_timeout:
    // sent as a slow request (held, not waited for).
    ['binary garbage', ['\x00\x01\x02 GARBAGE \xff\r\n\r\n'], [400, 505, null], false],
    ['huge header', `GET /v1/sim HTTP/1.1\r\nHost: ${host}\r\nX-Pad: ${'z'.repeat(200000)}\r\n\r\n`, [400, 413, 431, null], false],
    ['slow partial request', ['GET /v1/sim HTTP/1.1\r\n', `Host: ${host}\r\n`, 'X-Slow: 1\r\n'], [null, 408, 400], false],
  ];
}

function checkAnswer(name, r, allowed, problem) {
  if (r.status === 'malformed') return `${name}: malformed response ${JSON.stringify(r.head)}`;
  // Rate limited (a changing request past the limit): a problem with Retry-After.
  if (r.status === 429 && !r.headers['retry-after']) return `${name}: 429 without Retry-After`;
  if (r.status === 429) allowed = [429];
  if (!allowed.includes(r.status)) return `${name}: status ${r.status}, expected ${allowed.join(' or ')}`;
  if (r.status === null || !problem) return null;
  if (!(r.headers['content-type'] ?? '').startsWith('application/problem+json'))
    return `${name}: ${r.status} with content-type ${r.headers['content-type']}`;
  let p;
  try {
    p = JSON.parse(r.body);
  } catch {
    return `${name}: a problem body that is not JSON: ${r.body.slice(0, 80)}`;
  }
  if (p.status !== r.status || typeof p.type !== 'string' || typeof p.detail !== 'string')
    return `${name}: problem ${JSON.stringify(p).slice(0, 120)} does not match status ${r.status}`;
  return null;
}

// Stream clients: kind 'read' (subscribes to q16 at 30 fps and reads everything), 'slow' (reads
// for 100 ms of every second), 'never' (never reads after the hello).
function streamClient(d, kind) {
  return new Promise((resolve) => {
    const ws = new WebSocket(`ws://127.0.0.1:${d.streamPort}/stream`, ['clothd.v1', `bearer.${TOKEN}`]);
    const c = { kind, frames: 0, bytes: 0, closed: false, refused: false, held: false, ws, timer: null };
    ws.on('message', (data, binary) => {
      if (binary) {
        c.frames++;
        c.bytes += data.length;
      } else if (kind !== 'read' && c.frames === 0 && !c.held) {
        // After the hello: stop reading (the socket's buffers and then the server's bound fill).
        // Once: more texts may come before the first frame (a slow sim, an event), and a second
        // interval would outlive the client and keep node from exiting.
        c.held = true;
        if (kind === 'never') ws._socket.pause();
        else c.timer = setInterval(() => {
          ws._socket.pause();
          setTimeout(() => ws._socket?.resume(), 900);
        }, 1000);
      }
    });
    ws.on('open', () => {
      ws.send(JSON.stringify({ type: 'subscribe', encoding: 'q16', max_fps: 30 }));
      resolve(c);
    });
    ws.on('close', () => {
      c.closed = true;
      clearInterval(c.timer);
    });
    ws.on('error', () => {
      c.refused = true;
      resolve(c);
    });
  });
}

function wrk(d, seconds, delayMs) {
  const dir = tempDir();
  const script = join(dir, 'soak.lua');
  writeFileSync(script, `
local paths = {"/v1/sim", "/v1/params", "/v1/rocks", "/metrics"}
local k = 0
wrk.headers["Authorization"] = "${AUTH}"
request = function()
  k = k + 1
  return wrk.format("GET", paths[(k % #paths) + 1])
end
${delayMs > 0 ? `function delay() return ${delayMs} end` : ''}
`);
  return new Promise((resolve, reject) => {
    const p = spawn('wrk', ['-t1', '-c16', `-d${seconds}s`, '-s', script, d.url], { stdio: ['ignore', 'pipe', 'pipe'] });
    let out = '';
    p.stdout.on('data', (b) => (out += b));
    p.stderr.on('data', (b) => (out += b));
    p.on('error', reject);
    p.on('exit', () => {
      const num = (re) => Number(re.exec(out)?.[1] ?? 0);
      resolve({
        requests: num(/(\d+) requests in/),
        rps: num(/Requests\/sec:\s+([\d.]+)/),
        non2xx: num(/Non-2xx or 3xx responses: (\d+)/),
        socketErrors: /Socket errors: connect (\d+), read (\d+), write (\d+), timeout (\d+)/.exec(out)?.slice(1).map(Number) ?? [0, 0, 0, 0],
        out,
      });
    });
  });
}

/**
 * Runs the soak and returns its report. Options: seconds (running phase), pausedSeconds, clients
 * (stream clients: 3/4 read, 1/8 slow, 1/8 never), wrkDelayMs (0 saturates; default 8 ms a
 * request per connection, about 2,000 requests per second), flags (extra clothd flags), hostileConcurrency.
 */
export async function soak({ seconds = 20, pausedSeconds = 8, clients = 64, wrkDelayMs = 8, flags = [],
  hostileConcurrency = 3, env = {}, closeWaitMs = 10000, log = () => {} } = {}) {
  const dir = tempDir();
  writeFileSync(join(dir, 'token'), TOKEN);
  // Every client here is 127.0.0.1, so the valid changes share the per-address rate limit with the
  // hostile requests: the limit is raised so that hostile requests reach the validators and valid
  // changes are not refused (the limiter itself is tested in limits.test.mjs). A 429 is still a
  // well-formed answer to a hostile request.
  const d = await start(['--token-file', join(dir, 'token'), '--stream-max-clients', String(clients),
    '--stream-stall-timeout', '5', '--rate-limit', '1000', '--rate-burst', '2000', ...flags], { env });
  d.streamPort = (await (await fetch(d.url + '/v1/health')).json()).stream.port;
  const host = new URL(d.url).host;
  const report = {
    seconds, pausedSeconds, errors: [], hostile: { sent: 0, byStatus: {} }, changes: { sent: 0, refused: 0 },
    rss: { startKiB: rssKiB(d.proc.pid), samplesKiB: [] }, rtf: [],
  };
  const cases = hostile(host);
  let phase = 'running';
  let stopAll = false;

  // Hostile requests, round robin over the cases, a few at a time.
  let nextCase = 0;
  const slow = new Set();
  const hostileLoop = async () => {
    while (!stopAll) {
      const [name, bytes, allowed, problem, only] = cases[nextCase++ % cases.length];
      if (only && only !== phase) continue;
      const answered = (r) => {
        report.hostile.sent++;
        report.hostile.byStatus[r.status] = (report.hostile.byStatus[r.status] ?? 0) + 1;
        const wrong = checkAnswer(name, r, allowed, problem);
        if (wrong && report.errors.length < 50) report.errors.push(wrong);
      };
      if (Array.isArray(bytes)) {
        // A slow partial request holds its connection for seconds: a few at a time, not waited for.
        if (slow.size < 8) {
          const p = raw(d, bytes, { hold: 3000 }).then(answered).finally(() => slow.delete(p));
          slow.add(p);
        }
        continue;
      }
      answered(await raw(d, bytes));
      await sleep(20);
    }
  };
  // Valid changes while running (a person at the panel, several times faster).
  const changer = async () => {
    for (let k = 0; !stopAll; k++) {
      if (phase === 'running') {
        // The rock above where automatic drops appear (height + 0.8 m), so it overlaps none (that
        // would be refused, 409); the one before it is gone (DELETE, five turns later).
        const r = k % 10 === 0
          ? await api(d, 'POST', '/v1/rocks', { position: [0.2 * Math.sin(k), 0.2 * Math.cos(k), 2.5], radius: 0.08 })
          : k % 10 === 5 ? await api(d, 'DELETE', '/v1/rocks')
            : await api(d, 'PATCH', '/v1/params', { wind: [Math.sin(k / 7), 0, 0] });
        report.changes.sent++;
        if (r.status !== 200 && r.status !== 201) {
          report.changes.refused++;
          if (report.errors.length < 50) report.errors.push(`valid change refused: ${r.status} ${JSON.stringify(r.json)}`);
        }
      }
      await sleep(200);
    }
  };
  const sampler = async () => {
    while (!stopAll) {
      const kib = rssKiB(d.proc.pid);
      if (kib !== null) report.rss.samplesKiB.push(kib);
      if (phase === 'running') {
        const sim = await api(d, 'GET', '/v1/sim');
        if (sim.status === 200 && Number.isFinite(sim.json.realtime_factor)) report.rtf.push(sim.json.realtime_factor);
      }
      await sleep(1000);
    }
  };

  const kinds = Array.from({ length: clients }, (_, k) => (k % 8 === 6 ? 'slow' : k % 8 === 7 ? 'never' : 'read'));
  const conns = await Promise.all(kinds.map((k) => streamClient(d, k)));
  report.clientsRefusedAtStart = conns.filter((c) => c.refused).length;
  log(`soak: ${conns.length - report.clientsRefusedAtStart} stream clients connected; running phase ${seconds} s`);
  report.rss.afterClientsKiB = rssKiB(d.proc.pid);

  const loops = [changer(), sampler(), ...Array.from({ length: hostileConcurrency }, () => hostileLoop())];
  const wrkRunning = await wrk(d, seconds, wrkDelayMs);
  report.wrk = { running: wrkRunning };

  // Paused: nothing valid changes state; the hash must stay.
  phase = 'paused';
  const paused = await api(d, 'POST', '/v1/sim/pause');
  if (paused.status !== 200) report.errors.push(`pause: ${paused.status}`);
  const h0 = (await api(d, 'GET', '/v1/sim')).json?.state_hash;
  log(`soak: paused phase ${pausedSeconds} s (state hash ${h0})`);
  report.wrk.paused = await wrk(d, pausedSeconds, wrkDelayMs);
  stopAll = true;
  await Promise.all(loops);
  await Promise.all([...slow]);
  const h1 = (await api(d, 'GET', '/v1/sim')).json?.state_hash;
  report.hash = { before: h0, after: h1, held: typeof h0 === 'string' && h0 === h1 };
  if (!report.hash.held) report.errors.push(`the state hash moved while paused: ${h0} -> ${h1}`);

  const metrics = await (await fetch(d.url + '/metrics', { headers: { Authorization: AUTH } })).text();
  report.stream = {
    framesReceived: conns.reduce((s, c) => s + c.frames, 0),
    bytesReceived: conns.reduce((s, c) => s + c.bytes, 0),
    byKind: Object.fromEntries(['read', 'slow', 'never'].map((k) => {
      const of = conns.filter((c) => c.kind === k);
      return [k, { clients: of.length, frames: of.reduce((s, c) => s + c.frames, 0), closed: of.filter((c) => c.closed).length }];
    })),
    framesSent: metric(metrics, 'clothd_stream_frames_sent_total'),
    framesSkipped: metric(metrics, 'clothd_stream_frames_skipped_total'),
    disconnected: metric(metrics, 'clothd_stream_disconnected_total'),
  };
  // A client that never read has not seen its close yet: read now, and the server's close is there.
  const silent = conns.filter((c) => c.kind === 'never');
  for (const c of silent) c.ws._socket?.resume();
  const t0 = Date.now();
  while (silent.some((c) => !c.closed) && Date.now() - t0 < closeWaitMs) await sleep(50);
  report.stream.byKind.never.closed = silent.filter((c) => c.closed).length;
  for (const c of conns) {
    clearInterval(c.timer); // also where no 'close' comes (a socket paused when it was destroyed)
    c.ws.terminate();
  }
  report.rss.peakKiB = rssKiB(d.proc.pid, 'VmHWM');
  report.rss.endKiB = rssKiB(d.proc.pid);
  report.alive = d.exited === null;
  if (!report.alive) report.errors.push(`clothd died: ${JSON.stringify(d.exited)}\n${d.log.slice(-2000)}`);
  const exit = await stop(d);
  report.exit = exit;
  if (report.alive && exit.code !== 0) report.errors.push(`clothd exited ${JSON.stringify(exit)} on SIGTERM`);
  const rtf = report.rtf.slice(2); // the first samples include start-up
  report.rtfSummary = rtf.length ? {
    min: Math.min(...rtf), mean: rtf.reduce((a, b) => a + b, 0) / rtf.length, samples: rtf.length,
  } : null;
  return report;
}

export function summary(r) {
  const w = r.wrk.running, wp = r.wrk.paused;
  const mib = (k) => (k / 1024).toFixed(1);
  const s = r.stream;
  return [
    `API reads (wrk, 16 connections): running ${w.rps.toFixed(0)} req/s (${w.requests} requests, ${w.non2xx} non-2xx, socket errors ${w.socketErrors.join('/')}); paused ${wp.rps.toFixed(0)} req/s (${wp.non2xx} non-2xx)`,
    `valid changes: ${r.changes.sent} sent, ${r.changes.refused} refused`,
    `hostile requests: ${r.hostile.sent} sent; answers by status ${JSON.stringify(r.hostile.byStatus)}`,
    `stream: ${s.byKind.read.clients + s.byKind.slow.clients + s.byKind.never.clients} clients (refused at start ${r.clientsRefusedAtStart}); frames received: read ${s.byKind.read.frames}, slow ${s.byKind.slow.frames}, never ${s.byKind.never.frames}; server sent ${s.framesSent}, skipped ${s.framesSkipped}; disconnected for stalling ${s.disconnected} (closed: slow ${s.byKind.slow.closed}, never ${s.byKind.never.closed})`,
    `RSS: start ${mib(r.rss.startKiB)} MiB, with clients ${mib(r.rss.afterClientsKiB)} MiB, end ${mib(r.rss.endKiB)} MiB, peak ${mib(r.rss.peakKiB)} MiB`,
    `real-time factor while running: ${r.rtfSummary ? `mean ${r.rtfSummary.mean.toFixed(2)}, min ${r.rtfSummary.min.toFixed(2)} (${r.rtfSummary.samples} samples)` : 'no samples'}`,
    `state hash while paused: ${r.hash.held ? 'held' : 'MOVED'}; daemon ${r.alive ? `alive, exit ${r.exit.code}` : 'DIED'}`,
    `problems: ${r.errors.length ? '\n  ' + r.errors.join('\n  ') : 'none'}`,
  ].join('\n');
}
