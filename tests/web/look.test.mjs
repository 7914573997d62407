// look.test.mjs - the viewer's WebM recording, light theme and shadows in headless Chromium
// against the real clothd (64 x 64, running): the WebM button's download is a WebM (EBML magic)
// that Chromium's own <video> opens at the canvas's size; with prefers-color-scheme: light
// emulated the page and the scene's background are light (pixels of a drawn frame); the shadows
// toggle switches three.js's shadow map and the cloth's shadow-receiving material. It prints the
// frame rate drawn with shadows off and on (the method of bench.test.mjs: view.drawn over a
// few seconds of the running sim).
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { start, stop, ok } from '../server/harness.mjs';
import { WEB_ROOT, missing, launch, openViewer, artifact } from './browser.mjs';

const why = missing();
const opts = { skip: why ?? false };
let daemon, browser, page;

before(async () => {
  if (why) return;
  daemon = await start(['--nx', '64', '--ny', '64', '--auto-drop-interval', '0'], { webRoot: WEB_ROOT });
  await ok(daemon, 'POST', '/v1/rocks', { position: [0.2, 0.1, 1.6], radius: 0.25, density: 2000 });
  browser = await launch();
  page = await openViewer(browser.context, daemon.url + '/');
});

after(async () => {
  await browser?.close();
  if (daemon) await stop(daemon);
});

const button = (name) => page.locator('.lil-controller.lil-function button', { hasText: name });
const checkbox = (name) => page.locator('.lil-controller', { hasText: name }).locator('input[type=checkbox]');
/** Waits until the view has drawn `n` more frames. */
const drawnMore = (n) => page.evaluate((k) => window.__clothd.view.drawn, null)
  .then((d0) => page.waitForFunction((d) => window.__clothd.view.drawn >= d, d0 + n, { timeout: 15000 }));

test('the WebM button records the live view: a WebM that Chromium plays at the canvas size', opts, async () => {
  const supported = await page.evaluate(() => typeof MediaRecorder !== 'undefined' &&
    ['video/webm;codecs=vp9', 'video/webm;codecs=vp8', 'video/webm'].some((t) => MediaRecorder.isTypeSupported(t)));
  assert.ok(supported, 'headless Chromium has a MediaRecorder for video/webm');
  await button('Record WebM').click();
  await page.waitForFunction(() => [...document.querySelectorAll('.lil-controller.lil-function button')].some((b) => /Stop WebM/.test(b.textContent)));
  await drawnMore(10); // the cloth moves: frames reach the recorder
  // The recorder delivers every 500 ms; a slow machine's encoder may not have given anything yet.
  await page.waitForFunction(() => window.__clothd.webmBytes() > 2000, null, { timeout: 30000 });
  const [dl] = await Promise.all([page.waitForEvent('download'), button('Stop WebM').click()]);
  assert.match(dl.suggestedFilename(), /^clothd-default-step-\d+\.webm$/);
  const out = artifact('viewer-live.webm');
  await dl.saveAs(out);
  const webm = readFileSync(out);
  assert.deepEqual([...webm.subarray(0, 4)], [0x1a, 0x45, 0xdf, 0xa3], 'EBML magic');
  assert.ok(webm.length > 2000, `a WebM of ${webm.length} bytes`);
  const meta = await page.evaluate(async (b64) => {
    const blob = await (await fetch(`data:video/webm;base64,${b64}`)).blob();
    const v = document.createElement('video');
    v.muted = true;
    v.src = URL.createObjectURL(blob);
    await new Promise((resolve, reject) => { v.onloadeddata = resolve; v.onerror = () => reject(new Error(`video: ${v.error?.message}`)); });
    const c = window.__clothd.view.renderer.domElement;
    return { w: v.videoWidth, h: v.videoHeight, cw: c.width, ch: c.height };
  }, webm.toString('base64'));
  assert.deepEqual([meta.w, meta.h], [meta.cw, meta.ch]);
  assert.equal(await button('Record WebM').count(), 1);
});

/** Mean luminance of the top row of a freshly drawn frame (the background above the cloth). */
const topRow = () => page.evaluate(async () => {
  const img = await createImageBitmap(await window.__clothd.view.screenshot());
  const cv = new OffscreenCanvas(img.width, 4);
  cv.getContext('2d').drawImage(img, 0, 0);
  const d = cv.getContext('2d').getImageData(0, 0, img.width, 1).data;
  let sum = 0;
  for (let k = 0; k < d.length; k += 4) sum += 0.2126 * d[k] + 0.7152 * d[k + 1] + 0.0722 * d[k + 2];
  return sum / (d.length / 4);
});

test('prefers-color-scheme: light makes the page and the scene light', opts, async () => {
  // Playwright's pages prefer light unless told: dark first, then light.
  await page.emulateMedia({ colorScheme: 'dark' });
  await page.waitForFunction(() => window.__clothd.view.background === 0x1b1f27);
  const dark = await topRow();
  assert.ok(dark < 60, `dark background: luminance ${dark}`);
  await page.emulateMedia({ colorScheme: 'light' });
  await page.waitForFunction(() => window.__clothd.view.background === 0xe9ecf1);
  const light = await topRow();
  assert.ok(light > 200, `light background: luminance ${light}`);
  const body = await page.evaluate(() => getComputedStyle(document.body).backgroundColor);
  assert.equal(body, 'rgb(233, 236, 241)');
  await page.emulateMedia({ colorScheme: 'dark' });
  await page.waitForFunction(() => window.__clothd.view.background === 0x1b1f27);
});

const drawnRate = (seconds) => page.evaluate(async (s) => {
  const v = window.__clothd.view, d0 = v.drawn, t0 = performance.now();
  await new Promise((r) => setTimeout(r, s * 1000)); // a rate: counted over a fixed time
  return (v.drawn - d0) / ((performance.now() - t0) / 1000);
}, seconds);

test('the shadows toggle: the shadow map, the sun casting, the rocks casting, the cloth receiving', opts, async () => {
  const look = () => page.evaluate(() => {
    const v = window.__clothd.view;
    return { map: v.renderer.shadowMap.enabled, sun: v.sun.castShadow, receive: v.cloth.mesh.receiveShadow,
      material: v.cloth.mesh.material.type, rocks: [...v.rocks.values()].map((r) => r.mesh.castShadow) };
  });
  assert.deepEqual(await look(), { map: false, sun: false, receive: false, material: 'ShaderMaterial', rocks: [true] });
  const off = await drawnRate(3);
  await checkbox('shadows of the rocks').check();
  assert.deepEqual(await look(), { map: true, sun: true, receive: true, material: 'MeshLambertMaterial', rocks: [true] });
  await drawnMore(3);
  // The shadow map drawn: the sun's shadow has its render target.
  assert.ok(await page.evaluate(() => !!window.__clothd.view.sun.shadow.map));
  const on = await drawnRate(3);
  console.log(`viewer 64 x 64, headless Chromium software GL: ${off.toFixed(1)} frames/s drawn with shadows off, ${on.toFixed(1)} with shadows on`);
  await checkbox('shadows of the rocks').uncheck();
  assert.deepEqual(await look(), { map: false, sun: false, receive: false, material: 'ShaderMaterial', rocks: [true] });
  assert.ok(off > 0 && on > 0);
  assert.deepEqual(page.errors, []);
});
