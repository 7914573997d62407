// export_mcap.test.mjs - the viewer's "Recording as MCAP" button (web/src/recordings.js through
// clients/js recording-export.js, @mcap/core and @foxglove/schemas as the page's own ES modules)
// in headless Chromium: a recording the real clothd made (a rock falling) is opened from a file,
// the button downloads a .mcap, and @mcap/core's reader here reads it back: the magic, one
// foxglove.SceneUpdate message per frame, and the cloth's points of chosen frames equal to the
// file's frames as proto/frame.mjs decodes them.
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { McapStreamReader } from '@mcap/core';
import { ZSTDDecoder } from 'zstddec';
import { stop } from '../server/harness.mjs';
import { missing, launch, openViewer, artifact, exportableRecording, exportFromPlayer } from './browser.mjs';
import { readRecording } from '../../proto/recording.mjs';
import { createDecoder } from '../../proto/frame.mjs';

const why = missing();
const opts = { skip: why ?? false };
let daemon, browser, page, bytes, path;

before(async () => {
  if (why) return;
  ({ daemon, bytes, path } = await exportableRecording('web-mcap'));
  browser = await launch();
  page = await openViewer(browser.context, daemon.url + '/');
});

after(async () => {
  await browser?.close();
  if (daemon) await stop(daemon);
});

test('the button downloads the recording as MCAP that @mcap/core reads back, a message a frame', opts, async () => {
  const out = artifact('web-mcap.mcap');
  assert.equal(await exportFromPlayer(page, path, '#export-mcap', 'web-mcap.mcap', 'MCAP'), 'web-mcap.mcap');
  const mcap = new Uint8Array(readFileSync(out));
  assert.deepEqual([...mcap.subarray(0, 8)], [0x89, 0x4d, 0x43, 0x41, 0x50, 0x30, 0x0d, 0x0a], 'MCAP magic');

  const reader = new McapStreamReader();
  reader.append(mcap);
  // Schemas and channels come again in the summary section: by id.
  const messages = [], schemas = new Map(), channels = new Map();
  for (let rec; (rec = reader.nextRecord()); ) {
    if (rec.type === 'Message') messages.push(rec);
    else if (rec.type === 'Schema') schemas.set(rec.id, rec);
    else if (rec.type === 'Channel') channels.set(rec.id, rec);
  }
  assert.ok(reader.done(), 'the reader reached the footer');
  assert.deepEqual([...schemas.values()].map((s) => [s.name, s.encoding]), [['foxglove.SceneUpdate', 'jsonschema']]);
  assert.equal(channels.size, 1);
  assert.equal(JSON.parse(new TextDecoder().decode([...schemas.values()][0].data)).title, 'foxglove.SceneUpdate');
  const r = readRecording(bytes);
  assert.equal(messages.length, r.frames.length);

  const zstd = new ZSTDDecoder();
  await zstd.init();
  const decoder = createDecoder({ zstd });
  const frames = r.frames.map((_, k) => Float32Array.from(decoder.decode(r.frame(k)).positions));
  for (const k of [0, 7, r.frames.length - 1]) {
    const m = JSON.parse(new TextDecoder().decode(messages[k].data));
    const cloth = m.entities.find((e) => e.id === 'cloth');
    const pts = Float32Array.from(cloth.triangles[0].points.flatMap((p) => [p.x, p.y, p.z]));
    assert.deepEqual(pts, frames[k], `frame ${k}`);
    assert.ok(m.entities.some((e) => e.id.startsWith('rock-') && e.spheres.length === 1), `the rock in frame ${k}`);
  }
  assert.deepEqual(page.errors, []);
});
