// remote.test.mjs - the viewer opened from an address that is not loopback, as a viewer on a real
// network opens it: it subscribes to delta frames by default, decodes them (zstddec from the
// assembled vendor/ directory) and says so in its HUD. clothd listens on this machine's first
// non-loopback IPv4 address (--insecure: no token, the test's own machine); skipped where there
// is none.
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { networkInterfaces } from 'node:os';
import { start, stop, until } from '../server/harness.mjs';
import { WEB_ROOT, missing, launch, openViewer } from './browser.mjs';

const address = Object.values(networkInterfaces()).flat().find((a) => a.family === 'IPv4' && !a.internal)?.address;
const why = missing() ?? (address ? null : 'no IPv4 address other than loopback here');
let daemon, browser, page;

before(async () => {
  if (why) return;
  daemon = await start(['--listen', address, '--insecure', '--auto-drop-interval', '0.5'], { webRoot: WEB_ROOT });
  browser = await launch();
  page = await openViewer(browser.context, `${daemon.url}/`);
});

after(async () => {
  await browser?.close();
  if (daemon) await stop(daemon);
});

test('off loopback the viewer takes delta frames by default and decodes them', { skip: why ?? false }, async () => {
  assert.ok(!daemon.url.includes('127.0.0.1'), daemon.url);
  await until('delta frames decoded', () => page.evaluate(() => window.__clothd.stream.stats.decodeMs.delta.length > 20),
    { timeout: 30000, every: 100 });
  const s = await page.evaluate(() => ({ sub: window.__clothd.stream.subscription, bad: window.__clothd.stream.stats.badFrames }));
  assert.equal(s.sub.encoding, 'delta');
  assert.equal(s.bad, 0);
  await until('the HUD names delta', async () => /delta/.test(await page.textContent('#hud')), { timeout: 10000, every: 100 });
  assert.match(await page.textContent('#hud'), /kB\/s|MB\/s/); // the stream's bytes a second
  assert.deepEqual(page.errors, []);
});
