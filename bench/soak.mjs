#!/usr/bin/env node
// The long soak (tests/server/soak.mjs): for a set time, wrk reads the API, 64 stream clients
// (some slow, some never reading) watch, valid changes and hostile requests arrive, while the sim
// runs; then a paused phase checks that the state hash holds. Loopback only; it stops by itself.
//   bench/soak.mjs [seconds, default 300] [--saturate] [--clients N] [-- clothd flags]
// Prints requests per second, errors, frames delivered and skipped, peak RSS and the real-time
// factor; exits 1 if a problem was found. Needs a build (scripts/build.sh) and wrk.
import { dirname, join, resolve } from 'node:path';
import { fileURLToPath } from 'node:url';
import { existsSync } from 'node:fs';

const root = resolve(dirname(fileURLToPath(import.meta.url)), '..');
const args = process.argv.slice(2);
const dash = args.indexOf('--');
const flags = dash >= 0 ? args.splice(dash).slice(1) : [];
const seconds = Number(args.find((a) => /^\d+$/.test(a)) ?? 300);
const ci = args.indexOf('--clients');
const clients = ci >= 0 ? Number(args[ci + 1]) : 64;
process.env.CLOTHD_BIN ??= join(root, 'build', 'server', 'clothd');
process.env.CLOTHD_SOURCE ??= root;
if (!existsSync(process.env.CLOTHD_BIN)) {
  console.error(`soak: no ${process.env.CLOTHD_BIN}; run scripts/build.sh first`);
  process.exit(2);
}
const { soak, summary } = await import(join(root, 'tests', 'server', 'soak.mjs'));
const r = await soak({
  seconds, pausedSeconds: Math.max(8, Math.round(seconds / 10)), clients,
  wrkDelayMs: args.includes('--saturate') ? 0 : 8, flags, log: (m) => console.error(m),
});
console.log(`soak: ${seconds} s running + ${r.pausedSeconds} s paused, ${clients} stream clients, wrk ${args.includes('--saturate') ? 'saturating' : 'paced (8 ms per request per connection)'}`);
console.log(summary(r));
process.exit(r.errors.length ? 1 : 0);
