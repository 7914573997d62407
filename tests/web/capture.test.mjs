// capture.test.mjs - the viewer's capture and inspection in headless Chromium against the real
// clothd: the PNG screenshot button (a PNG the size of the canvas, not blank), the camera presets
// and the camera kept in the URL (a reload restores it), and the vertex probe (its numbers against
// GET /v1/cloth/state of a paused scene).
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { start, stop, ok, until } from '../server/harness.mjs';
import { WEB_ROOT, missing, launch, openViewer, artifact, pixelStats, screenOf } from './browser.mjs';

const why = missing();
const opts = { skip: why ?? false };
let daemon, browser, page;

before(async () => {
  if (why) return;
  daemon = await start(['--nx', '16', '--ny', '16', '--auto-drop-interval', '0', '--paused'], { webRoot: WEB_ROOT });
  // A rock on the cloth and a few frames: the cloth moves and stretches.
  await ok(daemon, 'POST', '/v1/rocks', { position: [0, 0, 1.5], radius: 0.2, density: 3000 });
  await ok(daemon, 'POST', '/v1/sim/step', { frames: 40 });
  browser = await launch();
  page = await openViewer(browser.context, daemon.url + '/');
});

after(async () => {
  await browser?.close();
  if (daemon) await stop(daemon);
});

const button = (name) => page.locator('.lil-controller.lil-function button', { hasText: name });
const select = (name) => page.locator('.lil-controller', { hasText: name }).locator('select');

test('the screenshot button downloads a PNG of the canvas that is not blank', opts, async () => {
  const [dl] = await Promise.all([page.waitForEvent('download'), button('Screenshot (PNG)').click()]);
  assert.match(dl.suggestedFilename(), /^clothd-default-step-\d+\.png$/);
  const out = artifact('viewer-screenshot.png');
  await dl.saveAs(out);
  const png = readFileSync(out);
  assert.deepEqual([...png.subarray(0, 8)], [0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a]);
  assert.equal(png.toString('latin1', 12, 16), 'IHDR');
  const canvas = await page.evaluate(() => {
    const c = window.__clothd.view.renderer.domElement;
    return { width: c.width, height: c.height };
  });
  assert.deepEqual({ width: png.readUInt32BE(16), height: png.readUInt32BE(20) }, canvas);
  const stats = await pixelStats(page, png);
  assert.ok(stats.variance > 20, `the screenshot's luminance varies (variance ${stats.variance})`);
});

test('a camera preset goes into the URL and a reload restores it', opts, async () => {
  const cam = () => page.evaluate(() => window.__clothd.view.cameraState());
  const fit = await cam();
  await select('camera preset').selectOption('top');
  const top = await cam();
  // Straight down on the target, as far as the fit's eye is.
  const d = (c) => Math.hypot(c[0] - c[3], c[1] - c[4], c[2] - c[5]);
  assert.ok(Math.abs(d(top) - d(fit)) < 1e-6 * d(fit) + 1e-9);
  assert.ok(top[2] - top[5] > 0.999 * d(top), `the eye above the target: ${top}`);
  const hash = await page.evaluate(() => location.hash);
  assert.match(hash, /scene=default/);
  assert.match(hash, /cam=(-?[\d.e-]+,){5}-?[\d.e-]+/);

  await select('camera preset').selectOption('side');
  const side = await cam();
  assert.ok(side[0] - side[3] > 0.999 * d(side), `the eye on +x of the target: ${side}`);

  await page.reload();
  await page.waitForFunction(() => window.__clothd?.ready && window.__clothd.view.cloth?.hasFrame && window.__clothd.view.drawn > 2);
  const back = await cam();
  for (let k = 0; k < 6; k++) assert.ok(Math.abs(back[k] - side[k]) < 1e-3, `camera ${k}: ${back[k]} after the reload, ${side[k]} before`);
  assert.equal(await page.evaluate(() => window.__clothd.view.camera2d), false);
});

test('the vertex probe shows the hovered vertex as GET /v1/cloth/state has it', opts, async () => {
  await select('camera preset').selectOption('fit');
  const s = await ok(daemon, 'GET', '/v1/cloth/state');
  // The viewer shows the paused scene's last frame.
  await until('the viewer at the paused step', () => page.evaluate((step) => window.__clothd.view.lastStep === step, s.step));
  const { nx, ny } = s;
  const v = Math.floor(ny / 2) * nx + Math.floor(nx / 2) + 3;
  const at = await screenOf(page, s.positions[v]);
  await page.mouse.move(at.x, at.y);
  await until('the probe on the vertex', () => page.evaluate((k) => window.__clothd.probe()?.vertex === k, v));
  const shown = await page.evaluate(() => window.__clothd.probe());
  for (let k = 0; k < 3; k++) assert.ok(Math.abs(shown.position[k] - s.positions[v][k]) < 1e-6, `position ${k}`);
  const speed = Math.hypot(...s.velocities[v]);
  assert.ok(speed > 1e-3, `the cloth moves at the probed vertex (${speed} m/s)`);
  assert.ok(Math.abs(shown.speed - speed) < 1e-5 * Math.max(1, speed), `speed ${shown.speed} against ${speed}`);
  // Strain as PROTOCOL.md defines the scalar, from the state's positions and the grid spacing.
  const scene = await ok(daemon, 'GET', '/v1/scene');
  const i = v % nx, j = Math.floor(v / nx), hx = scene.size_x / (nx - 1), hy = scene.size_y / (ny - 1);
  let strain = 0;
  for (const [a, b, l0] of [[i + 1, j, hx], [i - 1, j, hx], [i, j + 1, hy], [i, j - 1, hy]]) {
    const p = s.positions[b * nx + a], q = s.positions[v];
    strain = Math.max(strain, (Math.hypot(p[0] - q[0], p[1] - q[1], p[2] - q[2]) - l0) / l0);
  }
  assert.ok(Math.abs(shown.strain - strain) < 1e-4, `strain ${shown.strain} against ${strain}`);
  const text = await page.textContent('#probe');
  assert.match(text, new RegExp(`vertex +${v} `));
  assert.match(text, new RegExp(`speed +${speed.toFixed(4)} m/s`));
  assert.equal(await page.isVisible('#probe'), true);
  assert.deepEqual(page.errors, []);
});

test('a scene preset from the panel: its scene, rocks and self_collision, shown in the panel', opts, async () => {
  await page.locator('.lil-title', { hasText: 'Scene (rebuilds the cloth)' }).click();
  const preset = page.locator('.lil-controller').filter({ has: page.locator('.lil-name', { hasText: /^preset$/ }) });
  await preset.locator('select').selectOption('cloth-over-stone');
  await button('Load preset').click();
  await until('the preset to be loaded', async () => (await ok(daemon, 'GET', '/v1/scene')).height === 0.9);
  const rocks = (await ok(daemon, 'GET', '/v1/rocks')).rocks;
  assert.equal(rocks.length, 1);
  assert.equal(rocks[0].radius, 0.25);
  assert.equal((await ok(daemon, 'GET', '/v1/params')).self_collision, true);
  await until('the panel to show self_collision on', () => page.evaluate(() => window.__clothd.panel.params.self_collision === true));
});
