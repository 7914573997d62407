// wsclient.mjs - a stream client for the tests (the npm `ws` package): keeps every message, texts
// parsed and frames decoded with proto/frame.mjs (a decoder per client, which keeps the newest
// delta keyframe; a frame that does not decode is kept in c.badFrames), and waits for the one a
// test expects.
import { join } from 'node:path';
import WebSocket from 'ws';
import { MeshoptDecoder } from 'meshoptimizer';
import { ZSTDDecoder } from 'zstddec';
import { start, ok } from './harness.mjs';

const { createDecoder } = await import(join(process.env.CLOTHD_SOURCE, 'proto', 'frame.mjs'));
await MeshoptDecoder.ready;
const zstd = new ZSTDDecoder();
await zstd.init();

// A client that keeps every message: texts parsed, frames decoded.
// options.headers: extra request headers (Origin, Host); the connection fails when refused.
export function connect(d, { path = '/stream', protocol = 'clothd.v1', headers } = {}) {
  return new Promise((resolve, reject) => {
    const ws = new WebSocket(`ws://127.0.0.1:${d.streamPort}${path}`, protocol, { headers });
    const c = { ws, texts: [], frames: [], badFrames: [], closed: false, waiters: [] };
    const decoder = createDecoder({ meshopt: MeshoptDecoder, zstd });
    ws.on('message', (data, binary) => {
      if (!binary) c.texts.push(JSON.parse(data.toString()));
      else {
        try {
          c.frames.push(decoder.decode(data));
        } catch (e) {
          c.badFrames.push(e.message);
        }
      }
      for (const w of c.waiters.splice(0)) w();
    });
    ws.on('close', () => {
      c.closed = true;
      for (const w of c.waiters.splice(0)) w();
    });
    ws.on('open', () => resolve(c));
    ws.on('error', reject);
  });
}

// Waits for a message matching pred, among those from index `from` on (by default all, the ones
// already there first).
export async function next(c, kind, pred = () => true, timeout = 15000, from = 0) {
  const list = kind === 'frame' ? c.frames : c.texts;
  let seen = from;
  const t0 = Date.now();
  for (;;) {
    for (; seen < list.length; seen++) if (pred(list[seen])) return list[seen];
    if (c.closed) throw new Error('the stream closed');
    if (Date.now() - t0 > timeout) throw new Error(`no ${kind} matching ${pred} in time`);
    await new Promise((r) => {
      c.waiters.push(r);
      setTimeout(r, 200);
    });
  }
}

// start() (options too), and the stream's port.
export async function daemon(flags, options) {
  const d = await start(flags, options);
  d.streamPort = (await ok(d, 'GET', '/v1/health')).stream.port;
  return d;
}
