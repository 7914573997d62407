// source.test.mjs - promises of docs/security.md that are about the source itself.
//
// CVE-2025-11677: libwebsockets up to 4.3.x (Debian 12 ships 4.1.6) frees memory that a callback
// handling LWS_CALLBACK_HTTP_CONFIRM_UPGRADE may still read through `in`. clothd never handles
// that callback; its upgrade checks are in LWS_CALLBACK_FILTER_PROTOCOL_CONNECTION.
//
// libmicrohttpd 0.9.75 (Debian 12) in epoll mode with a thread pool aborts in MHD_quiesce_daemon,
// which clothd calls on SIGTERM before saving the state, when a worker thread removed the listen
// socket from its epoll set first: a race, seen twice in 160 shutdowns under strace, too rare for
// a test of behaviour to catch. clothd's HTTP server polls instead.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { readdirSync, readFileSync } from 'node:fs';
import { join } from 'node:path';

const server = join(process.env.CLOTHD_SOURCE, 'server');
// Every source file of server/ and its rooms (core/, sim/, http/, stream/), named by its path there.
const sources = readdirSync(server, { recursive: true }).filter((f) => /\.[ch]$/.test(f))
  .map((f) => ({ f, text: readFileSync(join(server, f), 'utf8') }));

test('no callback handles LWS_CALLBACK_HTTP_CONFIRM_UPGRADE (CVE-2025-11677)', () => {
  assert.ok(sources.length > 5);
  for (const { f, text } of sources)
    assert.doesNotMatch(text, /case\s+LWS_CALLBACK_HTTP_CONFIRM_UPGRADE|==\s*LWS_CALLBACK_HTTP_CONFIRM_UPGRADE/, f);
  const stream = sources.find((s) => s.f === 'stream/stream.c').text;
  assert.match(stream, /case LWS_CALLBACK_FILTER_PROTOCOL_CONNECTION:/, 'the upgrade checks are where this test says');
});

test('the HTTP server does not use libmicrohttpd\'s epoll mode (0.9.75 can abort when quiesced)', () => {
  const http = sources.find((s) => s.f === 'http/http.c').text;
  assert.match(http, /MHD_quiesce_daemon/, 'the shutdown quiesces, as this test says');
  assert.match(http, /MHD_USE_POLL\b/);
  assert.doesNotMatch(http.replace(/\/\*[\s\S]*?\*\//g, ''), /MHD_USE_EPOLL|MHD_USE_AUTO/);
});
