// support.mjs - what the JavaScript client's tests share: one paused clothd without automatic
// drops for a test file, and a client of it.
import { after, before } from 'node:test';
import { start, stop } from '../server/harness.mjs';
import { Client } from '../../clients/js/src/index.js';

/** Starts the file's daemon before its tests; resolves with its client. */
export function pausedDaemon() {
  const shared = { daemon: null };
  let ready;
  const client = new Promise((resolve) => { ready = resolve; });
  before(async () => {
    shared.daemon = await start(['--auto-drop-interval', '0', '--paused']);
    ready(new Client({ base: shared.daemon.url }));
  });
  after(async () => {
    if (shared.daemon) await stop(shared.daemon);
  });
  return client;
}
