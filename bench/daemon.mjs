// daemon.mjs - starts build/server/clothd (or $CLOTHD_BIN) for the benchmark scripts on free
// ports with the CPU backend, and finds its stream: { proc, url, ws }.
import { spawn } from 'node:child_process';
import { dirname, join } from 'node:path';
import { fileURLToPath } from 'node:url';

const root = join(dirname(fileURLToPath(import.meta.url)), '..');

export async function daemon(flags) {
  const proc = spawn(process.env.CLOTHD_BIN ?? join(root, 'build/server/clothd'),
    ['--port', '0', '--stream-port', '0', '--backend', 'cpu', '--web-root', '/nonexistent', ...flags],
    { stdio: ['ignore', 'ignore', 'pipe'] });
  // A benchmark that throws or exits early does not leave its daemon running (and loading the
  // machine that the next benchmark measures on).
  process.on('exit', () => proc.kill('SIGTERM'));
  let log = '';
  const url = await new Promise((resolve, reject) => {
    proc.stderr.on('data', (c) => {
      log += c;
      const m = /listening on (http:\/\/[0-9.]+:\d+)/.exec(log);
      if (m) resolve(m[1]);
    });
    proc.on('exit', () => reject(new Error(log)));
  });
  const health = await (await fetch(`${url}/v1/health`)).json();
  return { proc, url, ws: `ws://127.0.0.1:${health.stream.port}/stream` };
}
