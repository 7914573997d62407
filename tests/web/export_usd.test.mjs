// export_usd.test.mjs - the viewer's "Recording as USD" button (web/src/recordings.js through
// clients/js recording-export.js) in headless Chromium: a recording the real clothd made (a rock
// falling, delta frames) is opened from a file, the button downloads a .usda, and TinyUSDZ reads
// it: the stage's frame rate and span, and the points at chosen times equal to the file's frames
// as proto/frame.mjs decodes them here.
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { ZSTDDecoder } from 'zstddec';
import { stop } from '../server/harness.mjs';
import { missing, launch, openViewer, artifact, exportableRecording, exportFromPlayer } from './browser.mjs';
import { tinyusdz, parseUsd, samples } from '../clients/usd.mjs';
import { readRecording } from '../../proto/recording.mjs';
import { createDecoder } from '../../proto/frame.mjs';

const why = missing();
const opts = { skip: why ?? false };
let daemon, browser, page, bytes, path;

before(async () => {
  if (why) return;
  ({ daemon, bytes, path } = await exportableRecording('web-usd'));
  browser = await launch();
  page = await openViewer(browser.context, daemon.url + '/');
});

after(async () => {
  await browser?.close();
  if (daemon) await stop(daemon);
});

test('the button downloads the recording as USD that TinyUSDZ reads, its points the frames', opts, async () => {
  const out = artifact('web-usd.usda');
  assert.equal(await exportFromPlayer(page, path, '#export-usd', 'web-usd.usda', 'USD'), 'web-usd.usda');

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
