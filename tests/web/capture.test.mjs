// capture.test.mjs - the viewer's capture and inspection in headless Chromium against the real
// clothd: the PNG screenshot button (a PNG the size of the canvas, not blank), the camera presets
// and the camera kept in the URL (a reload restores it), the vertex probe (its numbers against
// GET /v1/cloth/state of a paused scene), the stretch colouring (each vertex's colour against its
// springs' extensions computed here) and a recording's range as WebM video (its blocks read here,
// decoded back by the page's WebCodecs: one video frame per recording frame at its frame rate).
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { start, stop, ok, until } from '../server/harness.mjs';
import { WEB_ROOT, missing, launch, openViewer, artifact, pixelStats, screenOf, exportableRecording } from './browser.mjs';
import { stretchRgb } from '../../web/src/colors.js';

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

const named = (name) => page.locator('.lil-controller').filter({ has: page.locator('.lil-name', { hasText: new RegExp(`^${name.replace(/[()]/g, '\\$&')}$`) }) });

test('the stretch colouring: blue - white - red by the mean extension of each vertex\'s springs', opts, async () => {
  // The paused cloth of the probe test, the rock pressed into it: its pixels with the lit surface
  // kept in the page, to compare with the stretch colouring's.
  const shoot = () => page.evaluate(async () => {
    const img = await createImageBitmap(await window.__clothd.view.screenshot());
    const cv = new OffscreenCanvas(img.width, img.height);
    cv.getContext('2d').drawImage(img, 0, 0);
    const d = cv.getContext('2d').getImageData(0, 0, img.width, img.height).data, was = window.__shot;
    window.__shot = d;
    if (!was) return null;
    let changed = 0;
    for (let k = 0; k < d.length; k += 4)
      if (Math.abs(d[k] - was[k]) + Math.abs(d[k + 1] - was[k + 1]) + Math.abs(d[k + 2] - was[k + 2]) > 60) changed++;
    return { changed, of: d.length / 4 };
  });
  await shoot();
  await named('cloth').locator('select').selectOption({ label: 'stretch (blue - white - red)' });
  await named('stretch range (%)').locator('input').fill('20');
  await until('the range to apply', () => page.evaluate(() => window.__clothd.view.stretchRange === 0.2));
  const { p, rgb } = await page.evaluate(() => {
    const v = window.__clothd.view;
    return { p: Array.from(v.cloth.position.array), rgb: Array.from(v.cloth.color.array) };
  });
  // Each vertex: the mean (|d| - L0) / L0 of its structural springs (none torn here), L0 the grid
  // spacing of GET /v1/scene, from the positions the page shows.
  const { nx, ny, size_x: sx, size_y: sy } = await ok(daemon, 'GET', '/v1/scene');
  assert.equal(p.length, 3 * nx * ny);
  const hx = sx / (nx - 1), hy = sy / (ny - 1);
  let worst = 0, red = 0, blue = 0, lo = Infinity, hi = -Infinity;
  for (let v = 0; v < nx * ny; v++) {
    const i = v % nx, j = Math.floor(v / nx), e = [];
    for (const [a, b, l0] of [[i + 1, j, hx], [i - 1, j, hx], [i, j + 1, hy], [i, j - 1, hy]]) {
      if (a < 0 || b < 0 || a >= nx || b >= ny) continue;
      const w = b * nx + a;
      e.push((Math.hypot(p[3 * w] - p[3 * v], p[3 * w + 1] - p[3 * v + 1], p[3 * w + 2] - p[3 * v + 2]) - l0) / l0);
    }
    const mean = e.reduce((x, y) => x + y, 0) / e.length;
    lo = Math.min(lo, mean); hi = Math.max(hi, mean);
    const want = stretchRgb(mean / 0.2), got = rgb.slice(3 * v, 3 * v + 3);
    worst = Math.max(worst, ...want.map((c, k) => Math.abs(c - got[k])));
    if (mean > 0.1) { red++; assert.ok(got[0] > got[2] + 40, `vertex ${v} stretched ${mean}: red, not ${got}`); }
    if (mean < -0.1) { blue++; assert.ok(got[2] > got[0] + 40, `vertex ${v} compressed ${mean}: blue, not ${got}`); }
  }
  console.log(`stretch: mean extensions ${lo.toFixed(4)} .. ${hi.toFixed(4)}, ${red} vertices red, ${blue} blue; colours within ${worst} of the map`);
  assert.ok(worst <= 4, `every vertex's colour the map's for its extension (worst by ${worst})`);
  assert.ok(red + blue > 0, 'some of the cloth is stretched or compressed by more than half the range');
  const { changed, of } = await shoot();
  assert.ok(changed > 0.01 * of, `the stretch colouring changes the drawn pixels (${changed} of ${of})`);
  await named('cloth').locator('select').selectOption({ label: 'lit surface' });
  assert.deepEqual(page.errors, []);
});

test('a recording range as WebM video: one frame per recording frame at its frame rate, decoded back', opts, async () => {
  const rec = await exportableRecording('capture-video');
  try {
    await page.setInputFiles('#rec-file', rec.path);
    await until('the recording open', () => page.evaluate(() => !document.getElementById('rec-player').hidden));
    const fps = await page.evaluate(() => window.__clothd.playback().info.frame_rate);
    await page.fill('#rec-from', '3');
    await page.fill('#rec-to', '12');
    await page.evaluate(() => window.__clothd.bar.seek(5));
    const message = () => page.textContent('#rec-message');
    // Without WebCodecs: a clear error, nothing downloaded.
    await page.evaluate(() => { window.__savedEncoder = window.VideoEncoder; delete window.VideoEncoder; });
    await page.click('#export-webm');
    await until('the bar to say why', async () => /WebM export failed: this browser has no WebCodecs/.test(await message()));
    await page.evaluate(() => { window.VideoEncoder = window.__savedEncoder; });
    const encoder = await page.evaluate(async () => {
      for (const codec of ['vp09.00.10.08', 'vp8'])
        if ((await VideoEncoder.isConfigSupported({ codec, width: 640, height: 360 }).catch(() => ({})))?.supported) return codec;
      return null;
    });
    if (!encoder) {
      await page.click('#export-webm');
      await until('the bar to say why', async () => /WebM export failed: .*no VP9 or VP8 encoder/.test(await message()));
      console.log('headless Chromium has no VP9 or VP8 encoder in WebCodecs: the error path checked instead');
      return;
    }
    const t0 = Date.now();
    const [dl] = await Promise.all([page.waitForEvent('download'), page.click('#export-webm')]);
    console.log(`WebM export of 10 frames (${encoder}): ${Date.now() - t0} ms`);
    assert.equal(dl.suggestedFilename(), 'capture-video-frames-3-12.webm');
    const out = artifact('capture-video-frames-3-12.webm');
    await dl.saveAs(out);
    await until('the bar says so', async () => /exported frames 3 \.\. 12 as WebM \(10 frames/.test(await message()));
    assert.equal(await page.evaluate(() => window.__clothd.playback().k), 5, 'the frame shown before is shown again');
    const webm = readWebm(readFileSync(out));
    assert.equal(webm.codec, encoder.startsWith('vp09') ? 'V_VP9' : 'V_VP8');
    assert.equal(webm.blocks.length, 10, 'one block per frame of the range');
    // Frame j at j / frame_rate (the file's clock in ms), whatever the wall clock did.
    webm.blocks.forEach((b, j) => assert.ok(Math.abs(b.ms - j * 1000 / fps) < 1, `block ${j} at ${b.ms} ms, frame ${j} of ${fps}/s`));
    assert.ok(Math.abs(webm.defaultDuration - 1e9 / fps) < 1, `DefaultDuration ${webm.defaultDuration} ns`);
    assert.ok(webm.blocks[0].key, 'the first frame a keyframe');
    // The page's own decoder takes the blocks back: ten frames of the file's size, not all alike.
    const decoded = await page.evaluate(async ({ blocks, codec, width, height }) => {
      const frames = [];
      const dec = new VideoDecoder({
        output: (f) => {
          const cv = new OffscreenCanvas(64, 36);
          cv.getContext('2d').drawImage(f, 0, 0, 64, 36);
          frames.push({ w: f.displayWidth, h: f.displayHeight, t: f.timestamp, px: Array.from(cv.getContext('2d').getImageData(0, 0, 64, 36).data) });
          f.close();
        },
        error: (e) => frames.push({ error: e.message }),
      });
      dec.configure({ codec, codedWidth: width, codedHeight: height });
      for (const b of blocks)
        dec.decode(new EncodedVideoChunk({ type: b.key ? 'key' : 'delta', timestamp: b.ms * 1000, data: Uint8Array.from(atob(b.data), (c) => c.charCodeAt(0)) }));
      await dec.flush();
      return frames;
    }, { blocks: webm.blocks.map((b) => ({ ms: b.ms, key: b.key, data: Buffer.from(b.data).toString('base64') })), codec: encoder, width: webm.width, height: webm.height });
    assert.equal(decoded.length, 10, `ten frames decoded: ${JSON.stringify(decoded.map((f) => f.error ?? f.t))}`);
    for (const f of decoded) assert.deepEqual([f.w, f.h], [webm.width, webm.height]);
    const canvas = await page.evaluate(() => [window.__clothd.view.renderer.domElement.width, window.__clothd.view.renderer.domElement.height]);
    assert.deepEqual([webm.width, webm.height], canvas.map((x) => x & ~1));
    const diff = decoded[0].px.reduce((s, x, k) => s + Math.abs(x - decoded[9].px[k]), 0);
    assert.ok(diff > 0, 'the first and last frames differ (the rock falls)');
    assert.deepEqual(page.errors, []);
  } finally {
    await page.click('#rec-live');
    await stop(rec.daemon);
  }
});

/**
 * The WebM's track and blocks, read with a small EBML walker: codec, size, DefaultDuration (ns),
 * and each SimpleBlock's time (its cluster's timecode plus its own, in the file's ms) and key flag.
 */
function readWebm(buf) {
  const out = { blocks: [] };
  const vint = (o, strip) => {
    let len = 1;
    while (len <= 8 && !(buf[o] & (0x80 >> (len - 1)))) len++;
    let v = strip ? buf[o] & (0xff >> len) : buf[o];
    let ones = v === (0xff >> len);
    for (let k = 1; k < len; k++) { v = v * 256 + buf[o + k]; ones &&= buf[o + k] === 0xff; }
    return { v, len, unknown: strip && ones };
  };
  const uint = (o, n) => { let v = 0; for (let k = 0; k < n; k++) v = v * 256 + buf[o + k]; return v; };
  const MASTER = new Set([0x18538067, 0x1f43b675, 0x1654ae6b, 0xae, 0xe0, 0xa0]);
  let cluster = 0;
  const walk = (o, end) => {
    while (o < end) {
      const id = vint(o, false), size = vint(o + id.len, true);
      const body = o + id.len + size.len, stop = size.unknown ? end : body + size.v;
      if (MASTER.has(id.v)) walk(body, stop);
      else if (id.v === 0xe7) cluster = uint(body, size.v);
      else if (id.v === 0x86) out.codec = buf.toString('latin1', body, stop);
      else if (id.v === 0xb0) out.width = uint(body, size.v);
      else if (id.v === 0xba) out.height = uint(body, size.v);
      else if (id.v === 0x23e383) out.defaultDuration = uint(body, size.v);
      else if (id.v === 0xa3) {
        const track = vint(body, true), rel = buf.readInt16BE(body + track.len), flags = buf[body + track.len + 2];
        out.blocks.push({ ms: cluster + rel, key: !!(flags & 0x80), data: buf.subarray(body + track.len + 3, stop) });
      }
      o = stop;
    }
  };
  walk(0, buf.length);
  return out;
}

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
