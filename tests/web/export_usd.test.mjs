// export_usd.test.mjs - the viewer's "Recording as USD" button (web/src/recordings.js through
// clients/js recording-export.js) in headless Chromium: a recording the real clothd made (a rock
// falling, delta frames) is opened from a file, the button downloads a .usda, and TinyUSDZ reads
// it: the stage's frame rate and span, and the points at chosen times equal to the file's frames
// as proto/frame.mjs decodes them here.
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync, writeFileSync } from 'node:fs';
import { ZSTDDecoder } from 'zstddec';
import { start, stop, ok, call, until } from '../server/harness.mjs';
import { WEB_ROOT, missing, launch, openViewer, artifact } from './browser.mjs';
import { tinyusdz, parseUsd, samples } from '../clients/usd.mjs';
import { readRecording } from '../../proto/recording.mjs';
import { createDecoder } from '../../proto/frame.mjs';

const why = missing();
const opts = { skip: why ?? false };
let daemon, browser, page, bytes, path;

before(async () => {
  if (why) return;
  daemon = await start(['--nx', '10', '--ny', '8', '--auto-drop-interval', '0', '--paused'], { webRoot: WEB_ROOT });
  await call(daemon, 'POST', '/v1/rocks', { position: [0, 0, 1.5], radius: 0.12 });
  await ok(daemon, 'POST', '/v1/recordings', { seconds: 0.25, id: 'web-usd' });
  await ok(daemon, 'POST', '/v1/sim/step', { frames: 15 });
  await until('the recording done', async () => (await ok(daemon, 'GET', '/v1/recordings')).recordings.some((r) => r.id === 'web-usd' && r.state === 'done'));
  const res = await fetch(`${daemon.url}/v1/recordings/web-usd`);
  bytes = new Uint8Array(await res.arrayBuffer());
  path = artifact('web-usd.clr');
  writeFileSync(path, bytes);
  browser = await launch();
  page = await openViewer(browser.context, daemon.url + '/');
});

after(async () => {
  await browser?.close();
  if (daemon) await stop(daemon);
});

test('the button downloads the recording as USD that TinyUSDZ reads, its points the frames', opts, async () => {
  await page.setInputFiles('#rec-file', path);
  await until('the recording open', () => page.evaluate(() => !document.getElementById('rec-player').hidden));
  const [dl] = await Promise.all([page.waitForEvent('download'), page.click('#export-usd')]);
  assert.equal(dl.suggestedFilename(), 'web-usd.usda');
  const out = artifact('web-usd.usda');
  await dl.saveAs(out);
  await until('the bar says so', () => page.evaluate(() => /exported \d+ frames as USD/.test(document.getElementById('rec-message').textContent)));

  const r = readRecording(bytes);
  const zstd = new ZSTDDecoder();
  await zstd.init();
  const decoder = createDecoder({ zstd });
  const frames = r.frames.map((_, k) => Float32Array.from(decoder.decode(r.frame(k)).positions));
  const { stage, text } = parseUsd(await tinyusdz(), new Uint8Array(readFileSync(out)));
  const rate = r.info.frame_rate;
  assert.match(text, new RegExp(`timeCodesPerSecond = ${rate}\\b`));
  assert.match(text, /endTimeCode = 15\b/);
  assert.deepEqual(Float32Array.from(stage.getMesh(0).points), frames[0]);
  const points = samples(text, 'points');
  assert.equal(points.size, r.frames.length);
  for (const k of [0, 5, r.frames.length - 1]) {
    const tc = Math.round((r.frames[k].simTime - r.frames[0].simTime) * rate);
    assert.deepEqual(Float32Array.from(points.get(tc)), frames[k], `frame ${k}`);
  }
  assert.ok(samples(text, 'xformOp:translate').size === r.frames.length, 'the rock at every frame');
});
