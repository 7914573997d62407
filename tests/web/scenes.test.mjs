// scenes.test.mjs - the viewer's scenes in headless Chromium against the real clothd: the picker
// makes a new scene from the shown one's settings and shows it (#scene= in the URL), a link with
// #scene= opens that scene, back goes to the scene before, and the overview page shows one live
// thumbnail per scene. Prints the overview's cost in the browser (ms of script a second).
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { start, stop, ok, call, until } from '../server/harness.mjs';
import { WEB_ROOT, missing, launch, openViewer } from './browser.mjs';

const why = missing();
let daemon, browser;

before(async () => {
  if (why) return;
  daemon = await start(['--nx', '20', '--ny', '16', '--auto-drop-interval', '0'], { webRoot: WEB_ROOT });
  browser = await launch();
});

after(async () => {
  await browser?.close();
  if (daemon) await stop(daemon);
});

const shown = (page) => page.evaluate(() => ({ id: window.__clothd.scene(), hash: location.hash,
  nx: window.__clothd.state.scene?.nx, n: window.__clothd.view.cloth?.position.count }));

test('the picker makes a scene from the shown one, the URL names it, a link and back open scenes', { skip: why ?? false }, async () => {
  await ok(daemon, 'PATCH', '/v1/params', { k_bend: 0.0125 }); // a live parameter the new scene must take
  const page = await openViewer(browser.context, `${daemon.url}/`);
  assert.deepEqual(await shown(page), { id: 'default', hash: '', nx: 20, n: 320 });
  await page.waitForSelector('#scenes:not([hidden])');
  // The shown scene is on this clothd: once the list is in, its label says so (not "not on this
  // clothd", the label it has before the list arrives).
  await page.waitForFunction(() => /^default \((running|paused), 320 vertices\)$/.test(document.querySelector('#scene-select option[value="default"]')?.textContent ?? ''),
    null, { timeout: 15000 });
  await page.fill('#scene-new-id', 'copy-1');
  await page.click('#scene-new');
  await until('the new scene shown', async () => (await shown(page)).id === 'copy-1' && (await shown(page)).hash === '#scene=copy-1',
    { timeout: 15000, every: 100 });
  // The server has it, with the shown scene's fields and live parameters.
  const list = (await ok(daemon, 'GET', '/v1/scenes')).scenes.map((s) => s.id).sort();
  assert.deepEqual(list, ['copy-1', 'default']);
  assert.equal((await ok(daemon, 'GET', '/v1/scenes/copy-1/scene')).nx, 20);
  assert.equal((await ok(daemon, 'GET', '/v1/scenes/copy-1/params')).k_bend, 0.0125);
  // A rock dropped now goes to copy-1, not default.
  await page.evaluate(() => window.__clothd.api.scene(window.__clothd.scene()).addRock({ position: [0, 0, 1.5], radius: 0.1 }));
  assert.equal((await ok(daemon, 'GET', '/v1/scenes/copy-1/rocks')).rocks.length, 1);
  assert.equal((await ok(daemon, 'GET', '/v1/rocks')).rocks.length, 0);

  // A link to another scene of another size opens it, frames and all.
  assert.equal((await call(daemon, 'POST', '/v1/scenes', { id: 'small', scene: { nx: 6, ny: 5 } })).status, 201);
  const linked = await openViewer(browser.context, `${daemon.url}/#scene=small`);
  assert.deepEqual(await shown(linked), { id: 'small', hash: '#scene=small', nx: 6, n: 30 });
  // Switching in the picker, then back: each time the scene's own cloth.
  await linked.selectOption('#scene-select', 'copy-1');
  await until('copy-1 drawn', async () => (await shown(linked)).n === 320 && (await shown(linked)).hash === '#scene=copy-1',
    { timeout: 15000, every: 100 });
  await linked.goBack();
  await until('back to small', async () => (await shown(linked)).n === 30 && (await shown(linked)).id === 'small',
    { timeout: 15000, every: 100 });
  assert.deepEqual(page.errors, []);
  assert.deepEqual(linked.errors, []);
  await page.close();
  await linked.close();
});

test('the overview shows every scene as a live thumbnail', { skip: why ?? false }, async () => {
  for (const id of ['ov-a', 'ov-b', 'ov-c'])
    assert.equal((await call(daemon, 'POST', '/v1/scenes', { id, scene: { nx: 16, ny: 12 } })).status, 201);
  const ids = (await ok(daemon, 'GET', '/v1/scenes')).scenes.map((s) => s.id).sort();
  const page = await browser.context.newPage();
  const errors = [];
  page.on('pageerror', (e) => errors.push(e.message));
  await page.goto(`${daemon.url}/overview.html`);
  await page.waitForFunction(() => window.__overview?.ready);
  // One thumbnail per scene, each drawing frames of its own.
  await until('every thumbnail drawn twice', () => page.evaluate(() => [...window.__overview.tiles.values()].every((t) => t.frames >= 2)),
    { timeout: 20000, every: 200 });
  const tiles = await page.evaluate(() => [...document.querySelectorAll('#thumbs .thumb')].map((a) => a.dataset.scene).sort());
  assert.deepEqual(tiles, ids);
  // A deleted scene's thumbnail goes.
  assert.ok((await call(daemon, 'DELETE', '/v1/scenes/ov-c')).status < 300);
  await until('its thumbnail gone', () => page.evaluate(() => !document.querySelector('.thumb[data-scene="ov-c"]')),
    { timeout: 10000, every: 100 });
  // The cost: script time drawing and decoding, per second, over 3 s.
  const c = await page.evaluate(async () => {
    const o = window.__overview.cost, f0 = o.frames, b0 = o.busyMs, t0 = performance.now();
    await new Promise((r) => setTimeout(r, 3000));
    const s = (performance.now() - t0) / 1000;
    return { fps: (o.frames - f0) / s, msPerS: (o.busyMs - b0) / s, tiles: window.__overview.tiles.size };
  });
  console.log(`overview: ${c.tiles} thumbnails, ${c.fps.toFixed(1)} frames/s drawn, ${c.msPerS.toFixed(2)} ms of script a second (provisional: shared machine)`);
  assert.deepEqual(errors, []);
  await page.close();
});
