// shadow.test.mjs - the shadows of the rocks on the cloth, seen: a paused flat cloth with a rock
// held half a metre above it, seen from the top preset; where the sun's ray through the rock's
// centre meets the cloth, the drawn frame darkens when shadows go on, and a point as far off on
// the other side does not.
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { start, stop, ok } from '../server/harness.mjs';
import { WEB_ROOT, missing, launch, openViewer, screenOf } from './browser.mjs';

const why = missing();
const opts = { skip: why ?? false };
let daemon, browser, page, scene;

before(async () => {
  if (why) return;
  daemon = await start(['--nx', '32', '--ny', '32', '--auto-drop-interval', '0', '--paused'], { webRoot: WEB_ROOT });
  scene = await ok(daemon, 'GET', '/v1/scene');
  await ok(daemon, 'POST', '/v1/rocks', { position: [0, 0, scene.height + 0.5], radius: 0.2 });
  browser = await launch();
  page = await openViewer(browser.context, daemon.url + '/');
  await page.waitForFunction(() => window.__clothd.view.rocks.size === 1);
});

after(async () => {
  await browser?.close();
  if (daemon) await stop(daemon);
});

/** Mean luminance of a 7 x 7 patch of a freshly drawn frame around each canvas point. */
const patches = (points) => page.evaluate(async (pts) => {
  const img = await createImageBitmap(await window.__clothd.view.screenshot());
  const cv = new OffscreenCanvas(img.width, img.height), g = cv.getContext('2d');
  g.drawImage(img, 0, 0);
  return pts.map(({ x, y }) => {
    const d = g.getImageData(Math.round(x) - 3, Math.round(y) - 3, 7, 7).data;
    let sum = 0;
    for (let k = 0; k < d.length; k += 4) sum += 0.2126 * d[k] + 0.7152 * d[k + 1] + 0.0722 * d[k + 2];
    return sum / 49;
  });
}, points);

test('shadows on darken the cloth where the rock shades it, and only there', opts, async () => {
  await page.evaluate(() => window.__clothd.setView('preset', 'top'));
  // The sun shines along -(4, -2, 3): the ray through the rock's centre meets the cloth's plane
  // 0.5 / 3 of that vector away.
  const h = scene.height, s = 0.5 / 3;
  const shaded = await screenOf(page, [-4 * s, 2 * s, h]), lit = await screenOf(page, [4 * s, -2 * s, h]);
  const [offShade, offLit] = await patches([shaded, lit]);
  await page.evaluate(() => window.__clothd.setView('shadows', true));
  const [onShade, onLit] = await patches([shaded, lit]);
  console.log(`luminance shaded/lit: ${offShade.toFixed(1)}/${offLit.toFixed(1)} without shadows, ${onShade.toFixed(1)}/${onLit.toFixed(1)} with`);
  assert.ok(Math.abs(offShade - offLit) < 0.1 * offLit, `without shadows both points alike: ${offShade}, ${offLit}`);
  assert.ok(onShade < 0.75 * onLit, `with shadows the shaded point darker: ${onShade} against ${onLit}`);
  assert.ok(Math.abs(onLit - offLit) < 0.15 * offLit, `the lit point about as bright: ${onLit} against ${offLit}`);
  assert.deepEqual(page.errors, []);
});
