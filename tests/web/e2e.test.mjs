// e2e.test.mjs - the viewer in real headless Chromium against a real clothd (127.0.0.1, ephemeral
// ports, CPU backend), through the page's own mouse and panel: it loads without console errors
// and draws; a click drops a rock; a drag pulls the cloth through the stream; shift-drag moves a
// kinematic rock; snapshots go down and up through the panel; a panel edit
// reaches GET /v1/params and a second page; a refused value shows why and snaps back; the scene
// panel rebuilds the cloth; bad stream input is reported and the page goes on; after the daemon
// restarts the page reconnects. Screenshots go to $CLOTHD_ARTIFACTS (build/test-artifacts).
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync, writeFileSync } from 'node:fs';
import { join } from 'node:path';
import { start, stop, ok, call, until, tempDir } from '../server/harness.mjs';
import { WEB_ROOT, missing, launch, openViewer, artifact, pixelStats, screenOf, vertexOf } from './browser.mjs';

const why = missing();
let daemon, browser, page;
// No automatic drops: the rock counts below are the page's own.
const FLAGS = ['--auto-drop-interval', '0'];

before(async () => {
  if (why) return;
  daemon = await start(FLAGS, { webRoot: WEB_ROOT });
  browser = await launch();
  page = await openViewer(browser.context, daemon.url + '/');
});

after(async () => {
  await browser?.close();
  if (daemon) await stop(daemon);
});

const opts = { skip: why ?? false };
const clientCount = () => page.evaluate(() => window.__clothd.stream.stats.frames);

test('the page loads without console errors and draws the cloth', opts, async () => {
  const f0 = await clientCount();
  await until('frames', async () => (await clientCount()) > f0 + 10);
  const png = await page.screenshot({ path: artifact('viewer.png') });
  const shot = await pixelStats(page, png);
  assert.equal(shot.width, 1280);
  // The cloth, the grid and the panel over a dark background: far from one flat colour.
  assert.ok(shot.variance > 100, `screenshot luminance variance ${shot.variance.toFixed(1)}`);
  // The canvas alone (left of the panel) is not blank either: the cloth is drawn.
  const canvas = await pixelStats(page, await page.screenshot({ clip: { x: 0, y: 120, width: 900, height: 400 } }));
  assert.ok(canvas.variance > 50, `canvas luminance variance ${canvas.variance.toFixed(1)}`);
  const hud = await page.textContent('#hud');
  assert.match(hud, /4096 vertices/);
  assert.match(hud, /q16/);
  assert.deepEqual(page.errors, []);
});

// The cloth still swings in its first seconds: the mouse tests pause the simulation, so that the
// point the test aims at is where the page's picking finds it (commands apply at once while
// paused, and the page gets a frame after each).
async function pauseAndSettle() {
  await ok(daemon, 'POST', '/v1/sim/pause');
  const { step } = await ok(daemon, 'GET', '/v1/sim');
  await until('the paused frame', () => page.evaluate((s) => window.__clothd.view.lastStep === s, step));
}

test('a click on the cloth drops a rock there', opts, async () => {
  assert.equal((await ok(daemon, 'GET', '/v1/rocks')).rocks.length, 0);
  await pauseAndSettle();
  const centre = 32 * 64 + 32;
  const p = await vertexOf(page, centre);
  const at = await screenOf(page, p);
  await page.mouse.click(at.x, at.y);
  const { rocks } = await until('a rock', async () => {
    const r = await ok(daemon, 'GET', '/v1/rocks');
    return r.rocks.length ? r : null;
  });
  assert.equal(rocks.length, 1);
  const rock = rocks[0];
  assert.equal(rock.radius, 0.1); // the panel's default drop radius
  assert.equal(rock.density, 2500); // the panel's default drop density: stone
  // Dropped over the clicked point: within a rock's size of it, sideways, and above it.
  assert.ok(Math.hypot(rock.position[0] - p[0], rock.position[1] - p[1]) < 0.3, JSON.stringify(rock.position));
  assert.ok(rock.position[2] > p[2], JSON.stringify(rock.position));
  await ok(daemon, 'DELETE', '/v1/rocks');
  await ok(daemon, 'POST', '/v1/sim/resume');
});

test('a drag on the cloth grabs the nearest vertex through the stream', opts, async () => {
  await pauseAndSettle();
  const vertex = 16 * 64 + 16;
  const p = await vertexOf(page, vertex);
  const at = await screenOf(page, p);
  await page.mouse.move(at.x, at.y);
  await page.mouse.down();
  for (let k = 1; k <= 10; k++) await page.mouse.move(at.x, at.y - 8 * k);
  await ok(daemon, 'POST', '/v1/sim/resume');
  // The grabbed vertex rises toward the mouse (grab_speed 5 m/s): well above where it was.
  await until('the vertex to follow the mouse', async () => (await vertexOf(page, vertex))[2] > p[2] + 0.1);
  await page.mouse.up();
  const { entries } = await ok(daemon, 'GET', '/v1/journal');
  const grabs = entries.filter((e) => e.command.op === 'grab');
  assert.ok(grabs.length >= 1, 'grabs in the journal');
  assert.ok(grabs.every((e) => Math.abs(e.command.vertex - vertex) <= 65), `grabbed ${grabs[0].command.vertex}, pressed ${vertex}`);
  await until('the release', async () => (await ok(daemon, 'GET', '/v1/journal')).entries.some((e) => e.command.op === 'release'));
  assert.deepEqual(page.errors, []);
});

test('shift-drag moves a kinematic rock', opts, async () => {
  await pauseAndSettle();
  const { id } = await ok(daemon, 'POST', '/v1/rocks', { position: [0.4, 0, 1.5], radius: 0.15, kinematic: true });
  await until('the rock in the page', () => page.evaluate((i) => window.__clothd.view.rocks.has(i), id));
  const at = await screenOf(page, [0.4, 0, 1.5]);
  await page.keyboard.down('Shift');
  await page.mouse.move(at.x, at.y);
  await page.mouse.down();
  for (let k = 1; k <= 10; k++) await page.mouse.move(at.x - 10 * k, at.y);
  await page.mouse.up();
  await page.keyboard.up('Shift');
  // Dragged leftwards on the screen, in the plane facing the camera through the rock's centre.
  const { rock } = await until('the rock to move', async () => {
    const r = await ok(daemon, 'GET', `/v1/rocks/${id}`);
    return Math.hypot(r.position[0] - 0.4, r.position[1]) > 0.1 ? { rock: r } : null;
  });
  const left = await screenOf(page, rock.position);
  assert.ok(left.x < at.x - 50, `on screen from ${at.x.toFixed(0)} to ${left.x.toFixed(0)}`);
  assert.ok(Math.abs(left.y - at.y) < 10, `stayed at the mouse's height: ${at.y.toFixed(0)} -> ${left.y.toFixed(0)}`);
  assert.equal(rock.kinematic, true);
  // The page's last move may still be on its way: deleting the rock under it would answer 404.
  await until('the page\'s moves to finish', () => page.evaluate(() => !window.__clothd.rockMoving()));
  await ok(daemon, 'DELETE', '/v1/rocks');
  await ok(daemon, 'POST', '/v1/sim/resume');
  assert.deepEqual(page.errors, []);
});

test('snapshot download and upload from the panel', opts, async () => {
  await pauseAndSettle();
  const [download] = await Promise.all([page.waitForEvent('download'), page.click('text=Download snapshot')]);
  const file = artifact('viewer.snapshot');
  await download.saveAs(file);
  const saved = readFileSync(file);
  const current = await call(daemon, 'GET', '/v1/snapshot');
  assert.equal(saved.length, current.buf.length);
  assert.ok(saved.equals(current.buf), 'the download is GET /v1/snapshot of the paused state');
  const { state_hash: hash } = await ok(daemon, 'GET', '/v1/sim');
  await ok(daemon, 'PUT', '/v1/scene', { nx: 24 });
  const [chooser] = await Promise.all([page.waitForEvent('filechooser'), page.click('text=Upload snapshot')]);
  await chooser.setFiles(file);
  await until('the snapshot restored', async () => (await ok(daemon, 'GET', '/v1/scene')).nx === 64);
  assert.equal((await ok(daemon, 'GET', '/v1/sim')).state_hash, hash);
  await until('the page to follow', () => page.evaluate(() => window.__clothd.view.cloth.n === 64 * 64));
  await ok(daemon, 'POST', '/v1/sim/resume');
  assert.deepEqual(page.errors, []);
});

test('a panel edit reaches GET /v1/params and a second page', opts, async () => {
  const second = await openViewer(browser.context, daemon.url + '/');
  try {
    const input = page.locator('[data-param="k_bend"] input');
    await input.fill('31.5');
    await input.press('Enter');
    await until('k_bend 31.5', async () => (await ok(daemon, 'GET', '/v1/params')).k_bend === 31.5);
    // A slider's box keeps every digit typed (no rounding to the slider's step).
    const mu = page.locator('[data-param="mu"] input');
    await mu.fill('0.5375');
    await mu.press('Enter');
    await until('mu 0.5375', async () => (await ok(daemon, 'GET', '/v1/params')).mu === 0.5375);
    // The second page learns it from the stream's params event.
    await until('the second page to show it', async () => (await second.inputValue('[data-param="k_bend"] input')) === '31.5');
    assert.deepEqual(second.errors, []);
  } finally {
    await second.close();
  }
});

test('a refused value shows the server\'s reason and the control snaps back', opts, async () => {
  // velocity_verlet's guard refuses a stiffness it cannot serve in max_substeps (implicit_euler,
  // the default, takes any in range)
  await ok(daemon, 'PATCH', '/v1/params', { integrator: 'velocity_verlet' });
  const input = page.locator('[data-param="k_structural"] input');
  await input.fill('1000000000');
  await input.press('Enter');
  const message = page.locator('[data-param="k_structural"] .refused');
  await message.waitFor();
  assert.match(await message.textContent(), /unstable.*max_substeps/);
  await until('the control to snap back', async () => (await input.inputValue()) === '2000');
  assert.equal((await ok(daemon, 'GET', '/v1/params')).k_structural, 2000);
  // Chromium logs the refused request itself as a console error: that one is expected.
  const refusedLog = page.errors.filter((e) => /status of 422/.test(e));
  assert.equal(refusedLog.length, 1, page.errors.join('\n'));
  page.errors = page.errors.filter((e) => !refusedLog.includes(e));
  // The next accepted edit clears the message.
  await input.fill('410');
  await input.press('Enter');
  await message.waitFor({ state: 'detached' });
  assert.equal((await ok(daemon, 'GET', '/v1/params')).k_structural, 410);
  await ok(daemon, 'PATCH', '/v1/params', { integrator: 'implicit_euler' });
});

test('the scene panel rebuilds the cloth', opts, async () => {
  await page.click('text=Scene (rebuilds the cloth)');
  const nx = page.locator('[data-param="nx"] input');
  await nx.fill('40');
  await nx.press('Enter');
  await page.click('text=Apply scene');
  await until('nx 40', async () => (await ok(daemon, 'GET', '/v1/scene')).nx === 40);
  await until('the page to rebuild', () => page.evaluate(() => window.__clothd.view.cloth.n === 40 * 64 &&
    window.__clothd.view.cloth.hasFrame));
  await ok(daemon, 'PUT', '/v1/scene', { nx: 64 });
  await until('the page to follow', () => page.evaluate(() => window.__clothd.view.cloth.n === 64 * 64));
  assert.deepEqual(page.errors, []);
});

test('bad stream input is reported in the page and the page goes on', opts, async () => {
  const before = await page.evaluate(() => window.__clothd.stream.stats.decoded);
  await page.evaluate(() => {
    const c = window.__clothd;
    c.inject(new Uint8Array([0x43, 0x4c, 0x46, 0x31, 72, 0, 0, 0]).buffer); // truncated header
    const bad = new Uint8Array(72);
    bad.set([0x58, 0x58, 0x58, 0x58]); // wrong magic
    c.inject(bad.buffer);
    c.inject('{"type":"no-such-message"}');
    c.inject('not json');
  });
  const shown = await page.textContent('#problems');
  assert.match(shown, /bad frame \(8 bytes\)/);
  assert.match(shown, /not a clothd frame/);
  assert.match(shown, /unknown stream message type "no-such-message"/);
  assert.match(shown, /not JSON/);
  await until('frames to go on', async () => (await page.evaluate(() => window.__clothd.stream.stats.decoded)) > before + 5);
  // Reported as warnings, not errors: the page itself is fine.
  assert.deepEqual(page.errors, []);
});

test('after the daemon restarts the page reconnects', opts, async () => {
  const ports = await ok(daemon, 'GET', '/v1/health');
  const port = new URL(daemon.url).port;
  await stop(daemon);
  await page.locator('#status.show').waitFor();
  assert.match(await page.textContent('#status'), /disconnected|connecting/);
  daemon = await start([...FLAGS, '--port', port, '--stream-port', String(ports.stream.port), '--nx', '48'], { webRoot: WEB_ROOT });
  // The new daemon's hello rebuilds the cloth (48 x 64 now) and frames flow again.
  await until('the page to reconnect', () => page.evaluate(() => window.__clothd.view.cloth.n === 48 * 64 &&
    window.__clothd.view.cloth.hasFrame), { timeout: 30000 });
  const f0 = await clientCount();
  await until('frames again', async () => (await clientCount()) > f0 + 5);
  await page.locator('#status.show').waitFor({ state: 'hidden' });
  writeFileSync(artifact('viewer-console.txt'), page.errors.join('\n'));
  // While the daemon was away Chromium logged the refused connections itself; nothing else.
  assert.deepEqual(page.errors.filter((e) => !/ERR_CONNECTION_REFUSED|WebSocket connection to .* failed/.test(e)), []);
});

test('with a token: the page asks for it once, then the API and the stream both take it', opts, async () => {
  const dir = tempDir();
  const token = 'e2e-token-0123456789abcdef';
  writeFileSync(join(dir, 'token'), token + '\n');
  const locked = await start([...FLAGS, '--token-file', join(dir, 'token')], { webRoot: WEB_ROOT });
  const second = await browser.context.newPage();
  const errors = [];
  second.on('pageerror', (e) => errors.push(`exception: ${e.message}`));
  try {
    await second.goto(locked.url + '/');
    // The first API read is 401; the page asks for the token.
    await second.locator('#token').waitFor();
    await second.fill('#token-input', token);
    await second.click('#token button');
    await until('frames through the token-checked stream', () =>
      second.evaluate(() => window.__clothd.stream.stats.frames > 5));
    const panelEdit = await ok(locked, 'GET', '/v1/params', undefined, { Authorization: `Bearer ${token}` });
    assert.equal(typeof panelEdit.k_bend, 'number');
    assert.deepEqual(errors, []);
  } finally {
    await second.close();
    await stop(locked);
  }
});
