// install.test.mjs - what docker/Dockerfile's build stage and the systemd unit rely on, run here:
// scripts/install.sh PREFIX from this build, then the installed clothd-serve (the image's
// entrypoint, the unit's ExecStart) started as they start it. Test daemons listen on 127.0.0.1,
// or on 0.0.0.0 only with a token.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { accessSync, constants, existsSync, readFileSync, statSync, writeFileSync } from 'node:fs';
import { join } from 'node:path';
import {
  BUILD, SOURCE, get, install, refused, run, serve, serveEnv, site, stop, tempDir, tokenFile,
} from './support.mjs';

const TOKEN = 'deploy-t0ken-0123456789abcdef';
const VIEW = 'deploy-view-0123456789abcdef';

test('scripts/install.sh puts clothd, clothd-serve, clothctl and the viewer in PREFIX, and the packages that run it', async () => {
  const prefix = install();
  for (const f of ['bin/clothd', 'bin/clothd-serve', 'bin/clothctl']) accessSync(join(prefix, f), constants.X_OK);
  assert.equal(readFileSync(join(prefix, 'share/clothd/web/index.html'), 'utf8'),
    readFileSync(join(BUILD, 'web/index.html'), 'utf8'));
  assert.ok(existsSync(join(prefix, 'share/clothd/web/vendor/three.module.js')), 'the viewer comes with its npm packages');
  // The runtime package list: what the image's runtime stage installs. Each is a Debian package
  // installed here, and the daemon's own libraries are among them.
  const packages = readFileSync(join(prefix, 'share/clothd/runtime-packages'), 'utf8').trim().split('\n');
  for (const want of [/^libmicrohttpd/, /^libjansson/, /^libwebsockets/, /^libmeshoptimizer/]) {
    assert.ok(packages.some((p) => want.test(p)), `${want} in ${packages.join(' ')}`);
  }
  const { stdout } = await run('dpkg-query', ['-W', '-f', '${Package} ${Status}\n', ...packages]);
  for (const line of stdout.trim().split('\n')) assert.match(line, /install ok installed$/);
  const version = (await run(join(prefix, 'bin/clothd'), ['--version'])).stdout;
  assert.match(version, /^clothd \d+\.\d+\.\d+/);
});

test('clothd-serve without a token: 127.0.0.1 only, and it says so; the viewer from PREFIX; the state file saved on SIGTERM and resumed', async () => {
  const prefix = install();
  const where = site();
  const env = serveEnv(where);
  const d = await serve(prefix, env, ['--paused']);
  assert.equal(d.listen, '127.0.0.1');
  assert.match(d.log, /no token .*listening on 127\.0\.0\.1 only/);
  const port = new URL(d.url).port;
  assert.match(d.log, new RegExp(`viewer: http://127\\.0\\.0\\.1:${port}/`), 'the viewer line');
  const health = await get(d, '/v1/health');
  assert.equal(health.status, 200);
  assert.equal(health.json.status, 'ok');
  assert.equal(health.json.backend, 'cpu');
  const page = await get(d, '/');
  assert.equal(page.status, 200);
  assert.equal(page.text, readFileSync(join(prefix, 'share/clothd/web/index.html'), 'utf8'));
  const hash = (await get(d, '/v1/sim')).json.state_hash;
  assert.match(hash, /^[0-9a-f]{16}$/);
  assert.deepEqual(await stop(d), { code: 0, signal: null });
  assert.ok(statSync(where.stateFile).size > 0, 'state.bin written');
  const again = await serve(prefix, env, ['--paused']);
  assert.match(again.log, new RegExp(`resumed from ${where.stateFile} at step \\d+, state hash ${hash}`));
  assert.equal((await get(again, '/v1/sim')).json.state_hash, hash);
  await stop(again);
});

test('clothd-serve with a token secret: listens on 0.0.0.0, and every route but health and the viewer needs the token', async () => {
  const prefix = install();
  const where = site();
  tokenFile(join(where.secrets, 'clothd_token'), TOKEN);
  tokenFile(join(where.secrets, 'clothd_view_token'), VIEW);
  const d = await serve(prefix, serveEnv(where));
  assert.equal(d.listen, '0.0.0.0');
  assert.doesNotMatch(d.log, /no token/);
  assert.equal((await get(d, '/v1/health')).status, 200);
  assert.equal((await get(d, '/')).status, 200);
  assert.equal((await get(d, '/v1/sim')).status, 401);
  assert.equal((await get(d, '/metrics')).status, 401);
  assert.equal((await get(d, '/v1/sim', TOKEN)).status, 200);
  assert.equal((await get(d, '/metrics', VIEW)).status, 200, 'the view token reads the metrics (ServiceMonitor)');
  assert.deepEqual(await stop(d), { code: 0, signal: null });
});

test('clothd-serve under systemd: the token from $CREDENTIALS_DIRECTORY, the state in $STATE_DIRECTORY', async () => {
  const prefix = install();
  const where = site();
  const creds = tempDir('creds');
  tokenFile(join(creds, 'token'), TOKEN);
  const env = serveEnv(where, { CREDENTIALS_DIRECTORY: creds, STATE_DIRECTORY: where.state });
  delete env.CLOTHD_STATE_FILE;
  const d = await serve(prefix, env);
  assert.equal(d.listen, '0.0.0.0');
  assert.equal((await get(d, '/v1/sim')).status, 401);
  assert.equal((await get(d, '/v1/sim', TOKEN)).status, 200);
  assert.deepEqual(await stop(d), { code: 0, signal: null });
  assert.ok(existsSync(join(where.state, 'state.bin')));
});

test('clothd-serve refuses: a named token file that is missing, 0.0.0.0 without a token, a state directory that is not there', async () => {
  const prefix = install();
  const where = site();
  let r = await refused(prefix, serveEnv(where, { CLOTHD_TOKEN_FILE: join(where.secrets, 'missing') }));
  assert.notEqual(r.code, 0);
  assert.match(r.log, /missing: No such file/);
  r = await refused(prefix, serveEnv(where, { CLOTHD_LISTEN: '0.0.0.0' }));
  assert.notEqual(r.code, 0);
  assert.match(r.log, /refusing to listen on 0\.0\.0\.0 without a token/);
  r = await refused(prefix, serveEnv(where, { CLOTHD_STATE_FILE: join(where.dir, 'nowhere/state.bin') }));
  assert.notEqual(r.code, 0);
  assert.match(r.log, /state directory .*nowhere does not exist or is not writable/);
});

// systemd-analyze reads unit files offline: verify (an unknown key, a bad value, an unknown system
// call group, a missing executable: lines it prints, at status 0 for most) and the security
// analyzer, whose overall exposure stays at most the figure of operating.md, "systemd".
test('the systemd units verify (systemd-analyze) against the installed clothd-serve, exposure at most 1.6', async (t) => {
  const analyze = await run('sh', ['-c', 'command -v systemd-analyze']).then((r) => r.stdout.trim(), () => '');
  if (!analyze) {
    t.skip('systemd-analyze not installed');
    return;
  }
  const prefix = install();
  const dir = tempDir('unit');
  const copies = [['clothd.service', 'clothd.service'], ['clothd@.service', 'clothd@0.service']].map(([file, name]) => {
    const unit = readFileSync(join(SOURCE, 'docker/systemd', file), 'utf8');
    assert.match(unit, /^ExecStart=\/opt\/clothd\/bin\/clothd-serve$/m);
    writeFileSync(join(dir, name), unit.replaceAll('/opt/clothd/', `${prefix}/`));
    return join(dir, name);
  });
  const r = await run(analyze, ['verify', ...copies]).then((x) => ({ code: 0, ...x }), (e) => e);
  assert.equal(r.code, 0, r.stderr);
  assert.doesNotMatch(r.stderr, /Unknown|ignoring|not executable|Invalid/i, r.stderr);
  for (const copy of copies) {
    const s = await run(analyze, ['security', '--offline=yes', '--no-pager', copy]);
    const level = Number(/Overall exposure level for \S+: ([\d.]+)/.exec(s.stdout)?.[1]);
    assert.ok(level <= 1.6, `${copy}: exposure ${level}\n${s.stdout}`);
  }
});
