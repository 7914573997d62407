// browser.mjs - headless Chromium for the viewer's end-to-end tests: Debian's /usr/bin/chromium
// (or $CLOTHD_CHROMIUM) driven by playwright-core, with a fresh profile per launch, and clothd
// started with the assembled viewer as its web root ($CLOTHD_WEB_ROOT, which ctest sets).
import { existsSync, mkdirSync, mkdtempSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { chromium } from 'playwright-core';
import { start, ok, call, until } from '../server/harness.mjs';

export const CHROMIUM = process.env.CLOTHD_CHROMIUM || '/usr/bin/chromium';
export const WEB_ROOT = process.env.CLOTHD_WEB_ROOT;
export const ARTIFACTS = process.env.CLOTHD_ARTIFACTS || join(tmpdir(), 'clothd-artifacts');

/** Why the e2e tests cannot run here, or null. */
export function missing() {
  if (!existsSync(CHROMIUM)) return `no Chromium at ${CHROMIUM} (apt install chromium)`;
  if (!WEB_ROOT || !existsSync(join(WEB_ROOT, 'vendor', 'three.module.js')))
    return `the viewer is not assembled in ${WEB_ROOT} (scripts/setup.sh runs npm ci in web/)`;
  return null;
}

export async function launch() {
  const profile = mkdtempSync(join(tmpdir(), 'clothd-chromium-'));
  // launchPersistentContext: the fresh user-data-dir is ours, and goes with close().
  const context = await chromium.launchPersistentContext(profile, {
    executablePath: CHROMIUM,
    headless: true,
    viewport: { width: 1280, height: 720 },
    args: ['--no-sandbox', '--disable-gpu', '--disable-background-networking', '--disable-component-update',
      '--disable-sync', '--no-first-run',
      // WebGL without a GPU: ANGLE on SwiftShader, Chromium's CPU renderer.
      '--use-angle=swiftshader', '--enable-unsafe-swiftshader'],
  });
  const close = async () => {
    await context.close();
    rmSync(profile, { recursive: true, force: true });
  };
  return { context, close };
}

/**
 * Opens the viewer and waits until it draws frames. Console errors and uncaught exceptions are
 * collected in page.errors (the tests assert there are none).
 */
export async function openViewer(context, url) {
  const page = await context.newPage();
  page.errors = [];
  page.on('console', (m) => { if (m.type() === 'error') page.errors.push(`console: ${m.text()}`); });
  page.on('pageerror', (e) => page.errors.push(`exception: ${e.message}`));
  await page.goto(url);
  await page.waitForFunction(() => window.__clothd?.ready && window.__clothd.view.drawn > 2 &&
    window.__clothd.view.cloth?.hasFrame, null, { timeout: 30000 });
  return page;
}

export function artifact(name) {
  mkdirSync(ARTIFACTS, { recursive: true });
  return join(ARTIFACTS, name);
}

/**
 * A short recording the real clothd makes for the export buttons' tests (a 10 x 8 cloth, a rock
 * falling, 15 frames), saved as the artifact id.clr: the daemon (paused), the file's bytes and its
 * path.
 */
export async function exportableRecording(id) {
  const daemon = await start(['--nx', '10', '--ny', '8', '--auto-drop-interval', '0', '--paused'], { webRoot: WEB_ROOT });
  await call(daemon, 'POST', '/v1/rocks', { position: [0, 0, 1.5], radius: 0.12 });
  await ok(daemon, 'POST', '/v1/recordings', { seconds: 0.25, id });
  await ok(daemon, 'POST', '/v1/sim/step', { frames: 15 });
  await until('the recording done', async () => (await ok(daemon, 'GET', '/v1/recordings')).recordings.some((r) => r.id === id && r.state === 'done'));
  const bytes = new Uint8Array(await (await fetch(`${daemon.url}/v1/recordings/${id}`)).arrayBuffer());
  const path = artifact(`${id}.clr`);
  writeFileSync(path, bytes);
  return { daemon, bytes, path };
}

/**
 * Opens the recording at path in the page's player, clicks an export button and saves its
 * download as the artifact out: the name the page suggested. Resolves once the bar says the
 * recording was exported as what (USD, MCAP).
 */
export async function exportFromPlayer(page, path, button, out, what) {
  await page.setInputFiles('#rec-file', path);
  await until('the recording open', () => page.evaluate(() => !document.getElementById('rec-player').hidden));
  const [dl] = await Promise.all([page.waitForEvent('download'), page.click(button)]);
  await dl.saveAs(artifact(out));
  await until('the bar says so', () => page.evaluate((w) => new RegExp(`exported \\d+ frames as ${w}`).test(document.getElementById('rec-message').textContent), what));
  return dl.suggestedFilename();
}

/**
 * Mean and variance of the luminance of a screenshot, decoded by the browser itself (no PNG
 * decoder of our own): a blank or single-colour canvas has a variance near 0.
 */
export async function pixelStats(page, png) {
  return page.evaluate(async (b64) => {
    const blob = await (await fetch(`data:image/png;base64,${b64}`)).blob();
    const img = await createImageBitmap(blob);
    const cv = new OffscreenCanvas(img.width, img.height);
    const g = cv.getContext('2d');
    g.drawImage(img, 0, 0);
    const d = g.getImageData(0, 0, img.width, img.height).data;
    let sum = 0, sq = 0;
    const n = d.length / 4;
    for (let k = 0; k < d.length; k += 4) {
      const y = 0.2126 * d[k] + 0.7152 * d[k + 1] + 0.0722 * d[k + 2];
      sum += y; sq += y * y;
    }
    const mean = sum / n;
    return { mean, variance: sq / n - mean * mean, width: img.width, height: img.height };
  }, png.toString('base64'));
}

/** The screen position (page pixels) of a world point, through the viewer's own camera. */
export async function screenOf(page, world) {
  return page.evaluate((w) => {
    const v = window.__clothd.view;
    const p = v.cloth.mesh.position.clone().set(w[0], w[1], w[2]).project(v.camera);
    const r = v.renderer.domElement.getBoundingClientRect();
    return { x: r.left + (p.x + 1) / 2 * r.width, y: r.top + (1 - p.y) / 2 * r.height };
  }, world);
}

/** The current position of a cloth vertex as the page shows it. */
export async function vertexOf(page, vertex) {
  return page.evaluate((k) => Array.from(window.__clothd.view.cloth.position.array.slice(3 * k, 3 * k + 3)), vertex);
}
