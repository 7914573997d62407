// crosssite.test.mjs - the cross-site rule from a real page in headless Chromium: a page served by a
// second HTTP server on another port (another origin, as any site the user visits would be) sends
// what a hostile page can without a preflight - fetch with mode no-cors and a text/plain body, a
// form POST - and cannot read the API's answers; the daemon's state does not change. The viewer's
// own page, served by clothd, still changes it. The headers one by one: server/crosssite.test.mjs.
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { createServer } from 'node:http';
import { start, stop, ok, call, hash, until } from '../server/harness.mjs';
import { WEB_ROOT, missing, launch } from './browser.mjs';

const why = missing();
let daemon, browser, other;

const hostilePage = (api) => `<!doctype html><meta charset=utf-8><title>another site</title>
<form id=f method=POST action="${api}/v1/sim/reset" enctype=text/plain target=sink><input name='{"a":' value='1}'></form>
<iframe name=sink></iframe>
<script>
window.results = (async () => {
  const out = {};
  const rock = JSON.stringify({ position: [0, 0, 2], radius: 0.1 });
  // POST needs no preflight in no-cors mode: the request goes out, the page sees nothing of it.
  for (const [name, path, body] of [['rock', '/v1/rocks', rock], ['resume', '/v1/sim/resume', '{}'],
    ['step', '/v1/sim/step', '{"frames": 2}']]) {
    const r = await fetch('${api}' + path, { method: 'POST', mode: 'no-cors', headers: { 'Content-Type': 'text/plain' }, body });
    out[name] = r.type; // "opaque"
  }
  // PATCH and DELETE cannot go no-cors; in cors mode the browser asks first (OPTIONS), and the
  // answer (405, no CORS headers) stops it.
  for (const [name, method, body] of [['params', 'PATCH', '{"k_bend": 33}'], ['clear', 'DELETE', undefined]]) {
    try {
      await fetch('${api}' + (name === 'params' ? '/v1/params' : '/v1/rocks'), { method, body });
      out[name] = 'sent';
    } catch (e) {
      out[name] = 'refused';
    }
  }
  try {
    await (await fetch('${api}/v1/sim')).json();
    out.read = 'read';
  } catch (e) {
    out.read = 'refused';
  }
  document.getElementById('f').submit();
  return out;
})();
</script>`;

before(async () => {
  if (why) return;
  daemon = await start(['--paused', '--auto-drop-interval', '0'], { webRoot: WEB_ROOT });
  other = createServer((req, res) => {
    res.writeHead(200, { 'Content-Type': 'text/html; charset=utf-8' });
    res.end(hostilePage(daemon.url));
  });
  await new Promise((r) => other.listen(0, '127.0.0.1', r));
  browser = await launch();
});

after(async () => {
  await browser?.close();
  other?.close();
  if (daemon) await stop(daemon);
});

test('a page of another origin in Chromium cannot change the state; the viewer\'s own page can', { skip: why ?? false }, async () => {
  await ok(daemon, 'POST', '/v1/rocks', { position: [0.5, 0, 2], radius: 0.1 });
  const h0 = await hash(daemon);
  const seen = [];
  const page = await browser.context.newPage();
  // The requests the browser really sent, and what came back (the page itself sees nothing).
  page.on('response', (r) => { if (r.url().startsWith(daemon.url)) seen.push(`${r.request().method()} ${new URL(r.url()).pathname} ${r.status()}`); });
  await page.goto(`http://127.0.0.1:${other.address().port}/`);
  const results = await page.evaluate(() => window.results);
  assert.deepEqual(results, { rock: 'opaque', resume: 'opaque', step: 'opaque', params: 'refused', clear: 'refused', read: 'refused' });
  await until('the form post answered', async () => seen.some((s) => s.startsWith('POST /v1/sim/reset')));
  const changes = seen.filter((x) => x.startsWith('POST'));
  assert.equal(changes.length, 4, seen.join(', '));
  for (const s of changes) assert.match(s, / 403$/, s);
  assert.equal(await hash(daemon), h0, 'a cross-site page changed the state');
  const sim = (await call(daemon, 'GET', '/v1/sim')).json;
  assert.equal(sim.state, 'paused');
  assert.equal(sim.n_rocks, 1);
  // The viewer's own origin (the page clothd serves) changes it.
  const own = await browser.context.newPage();
  await own.goto(`${daemon.url}/`);
  const status = await own.evaluate(async () => (await fetch('/v1/rocks', { method: 'POST',
    body: JSON.stringify({ position: [-0.5, 0, 2], radius: 0.1 }) })).status);
  assert.equal(status, 201);
  assert.equal((await call(daemon, 'GET', '/v1/sim')).json.n_rocks, 2);
});
