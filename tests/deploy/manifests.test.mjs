// manifests.test.mjs - docker/ checked offline (no Docker engine, no cluster): the Dockerfile,
// compose.yaml, the systemd unit and the Kubernetes manifests parse, and every value the daemon
// depends on - ports, probe and scrape paths, the state directory, where the token is read, the
// GPU, the settings they name - matches what the code says. The expected values come from the
// code, never from this file: the running daemon's GET /v1/params/schema (defaults) and
// /v1/health (the stream's path), `clothd routes`, and `clothd-serve --explain` (scripts/serve.sh).
import { test, before } from 'node:test';
import assert from 'node:assert/strict';
import { existsSync, mkdirSync, readFileSync, readdirSync, statSync, copyFileSync, writeFileSync } from 'node:fs';
import { dirname, join } from 'node:path';
import YAML from 'yaml';
import { start, stop, call } from '../server/harness.mjs';
import { CLOTHD, SOURCE, cleanEnv, run, tempDir } from './support.mjs';

const docker = (f) => join(SOURCE, 'docker', f);
const read = (f) => readFileSync(f, 'utf8');

// What the code says.
const code = {};
before(async () => {
  const d = await start(['--paused']);
  try {
    const schema = (await call(d, 'GET', '/v1/params/schema')).json.params;
    code.settings = Object.fromEntries(schema.map((p) => [p.name, p]));
    code.health = (await call(d, 'GET', '/v1/health')).json;
  } finally {
    await stop(d);
  }
  code.port = code.settings.port.default;
  code.streamPort = code.settings.stream_port.default;
  code.routes = (await run(CLOTHD, ['routes'])).stdout.trim().split('\n');
  code.serve = await explain({});
  // The exit status of a start with a bad setting (one no restart can mend).
  code.badSettingsExit = await run(CLOTHD, ['--port', 'nope']).then(() => 0, (e) => e.code);
  // The state file's size is capped by max_state_mb; a stop must leave time to write the largest
  // one on a slow disk (32 MiB/s).
  code.minGrace = Math.max(30, Math.ceil(code.settings.max_state_mb.default / 32));
});

// clothd-serve --explain (from the source tree) in an environment of its own.
async function explain(env) {
  const { stdout } = await run(join(SOURCE, 'scripts/serve.sh'), ['--explain'], { env: cleanEnv(env) });
  const vars = Object.fromEntries(stdout.split('\n').filter((l) => /^CLOTHD_\w+=/.test(l)).map((l) => {
    const i = l.indexOf('=');
    return [l.slice(0, i), l.slice(i + 1)];
  }));
  const tokenPaths = /^# token looked for in: (.*)$/m.exec(stdout)[1].split(' ');
  const viewTokenPaths = /^# view token looked for in: (.*)$/m.exec(stdout)[1].split(' ');
  return { vars, tokenPaths, viewTokenPaths };
}

function routeExists(method, path) {
  assert.ok(code.routes.includes(`${method} ${path}`), `clothd routes has no ${method} ${path}`);
}

// A CLOTHD_* variable a file sets must name a setting, with a value the setting takes.
function checkSettingVar(name, value) {
  const m = /^CLOTHD_([A-Z_]+)$/.exec(name);
  if (!m) return;
  const s = code.settings[m[1].toLowerCase()];
  assert.ok(s, `${name} names no clothd setting`);
  if (s.choices && !/\$/.test(String(value))) assert.ok(s.choices.includes(value), `${name}=${value}: not one of ${s.choices}`);
}

const seconds = (v) => {
  const m = /^(\d+)(s|m)?$/.exec(String(v));
  assert.ok(m, `a duration: ${v}`);
  return Number(m[1]) * (m[2] === 'm' ? 60 : 1);
};

// ---- Dockerfile ----

// Instructions with continuations joined, comments dropped; ARGs before the first FROM resolved.
function dockerfile() {
  const lines = read(docker('Dockerfile')).split('\n').filter((l) => !/^\s*#/.test(l));
  const text = lines.join('\n').replace(/\\\n/g, ' ');
  const ins = text.split('\n').map((l) => l.trim()).filter(Boolean).map((l) => {
    const i = l.search(/\s/);
    return { op: l.slice(0, i).toUpperCase(), arg: l.slice(i + 1).trim() };
  });
  const args = {};
  for (const x of ins) {
    if (x.op === 'FROM') break;
    if (x.op === 'ARG') {
      const [k, v = ''] = x.arg.split('=');
      args[k] = v.replace(/^"|"$/g, '');
    }
  }
  const subst = (s) => s.replace(/\$\{(\w+)\}/g, (_, k) => args[k] ?? `\${${k}}`);
  const stages = [];
  for (const x of ins) {
    if (x.op === 'FROM') stages.push({ from: subst(x.arg), ins: [] });
    else if (stages.length) stages.at(-1).ins.push(x);
  }
  return { ins, stages };
}

test('Dockerfile: built on the CUDA devel image, run on the matching base image, of the CUDA release this project builds with', async () => {
  const { stages } = dockerfile();
  assert.ok(stages.length >= 2);
  const image = (s) => /^nvidia\/cuda:(\d+\.\d+\.\d+)-(devel|base|runtime)-(ubuntu[\d.]+)(?:\s+AS\s+(\w+))?$/i.exec(s.from);
  const build = image(stages[0]);
  const runtime = image(stages.at(-1));
  assert.ok(build && runtime, `FROM lines: ${stages.map((s) => s.from).join(' | ')}`);
  assert.equal(build[2], 'devel');
  assert.equal(runtime[2], 'base', 'the smallest CUDA image: clothd needs no CUDA library of its own');
  assert.equal(runtime[1], build[1], 'the same CUDA version');
  assert.equal(runtime[3], build[3], 'the same Ubuntu');
  // The image compiles with the CUDA release the code is compiled and tested with here.
  const nvcc = ['/usr/local/cuda/bin/nvcc', 'nvcc'];
  const out = await run(nvcc[0], ['--version']).catch(() => run(nvcc[1], ['--version'])).catch(() => null);
  if (out) {
    const release = /release (\d+\.\d+)/.exec(out.stdout)[1];
    assert.equal(build[1].split('.').slice(0, 2).join('.'), release, 'the image CUDA release = nvcc here');
  }
  // What lets it run on the base image (no libcudart, no cuBLAS): the binary built here loads no
  // CUDA library but the driver's libcuda, which cudart_static opens at run time.
  const ldd = await run('ldd', [CLOTHD]).catch(() => null);
  if (ldd) assert.doesNotMatch(ldd.stdout, /libcu(?!da\.so)|libnv/, `clothd links a CUDA library dynamically:\n${ldd.stdout}`);
  // The runtime stage takes the installed tree from the build stage.
  const copy = stages.at(-1).ins.find((x) => x.op === 'COPY');
  assert.match(copy.arg, new RegExp(`--from=${build[4]}\\s+/opt/clothd\\s+/opt/clothd`));
});

test('Dockerfile: its build runs the repository scripts that the tests run here', () => {
  const { stages } = dockerfile();
  const runs = stages[0].ins.filter((x) => x.op === 'RUN').map((x) => x.arg).join(' && ');
  const called = [...runs.matchAll(/scripts\/([\w.-]+)/g)].map((m) => m[1]);
  assert.deepEqual(called, ['setup.sh', 'build.sh', 'install.sh']);
  // setup.sh and build.sh are what scripts/test.sh (README's test command, .ci/run) runs first;
  // install.sh is run into a temporary prefix by install.test.mjs, and so is the entrypoint.
  const testSh = read(join(SOURCE, 'scripts/test.sh'));
  assert.match(testSh, /scripts\/setup\.sh/);
  assert.match(testSh, /scripts\/build\.sh/);
  const installTest = read(join(SOURCE, 'tests/deploy/install.test.mjs'));
  assert.match(installTest, /scripts\/install\.sh PREFIX/);
  assert.match(installTest, /clothd-serve/);
  // The build context leaves out build trees, node_modules and local tokens.
  const ignore = read(join(SOURCE, '.dockerignore')).split('\n').map((l) => l.trim());
  for (const p of ['build', 'node_modules', 'web/node_modules', 'docker/token', 'docker/k8s/token', 'docker/k8s/view_token']) {
    assert.ok(ignore.includes(p), `.dockerignore lacks ${p}`);
  }
});

test('Dockerfile: a non-root user, the daemon ports, a health check on /livez, the state volume, clothd-serve', () => {
  const rt = dockerfile().stages.at(-1).ins;
  const one = (op) => {
    const xs = rt.filter((x) => x.op === op);
    assert.equal(xs.length, 1, `one ${op} in the runtime stage`);
    return xs[0].arg;
  };
  const user = one('USER').split(':')[0];
  assert.ok(user !== 'root' && user !== '0', `USER ${user}`);
  const exposed = one('EXPOSE').split(/\s+/).map(Number);
  assert.ok(exposed.includes(code.port) && exposed.includes(code.streamPort), `EXPOSE ${exposed}`);
  const health = one('HEALTHCHECK');
  routeExists('GET', '/livez');
  assert.match(health, /CMD .*127\.0\.0\.1:\$\{CLOTHD_PORT:-(\d+)\}\/livez/);
  assert.equal(Number(/CLOTHD_PORT:-(\d+)/.exec(health)[1]), code.port);
  assert.equal(one('VOLUME'), dirname(code.serve.vars.CLOTHD_STATE_FILE));
  assert.deepEqual(JSON.parse(one('ENTRYPOINT')), ['/opt/clothd/bin/clothd-serve']);
  // The runtime packages come from the list install.sh writes.
  assert.match(rt.filter((x) => x.op === 'RUN').map((x) => x.arg).join(' '), /\/opt\/clothd\/share\/clothd\/runtime-packages/);
  // The default token path of clothd-serve is where Docker puts a secret named clothd_token.
  assert.ok(code.serve.tokenPaths.includes('/run/secrets/clothd_token'));
});

test('Dockerfile: OCI labels on the image - title, description, source, licenses, and the version clothd reports', async () => {
  const rt = dockerfile().stages.at(-1).ins;
  const args = Object.fromEntries(rt.filter((x) => x.op === 'ARG').map((x) => {
    const m = /^(\w+)(?:=(.*))?$/.exec(x.arg);
    return [m[1], (m[2] ?? '').replace(/^"(.*)"$/, '$1')];
  }));
  const labels = {};
  for (const x of rt.filter((i) => i.op === 'LABEL')) {
    for (const m of x.arg.matchAll(/([\w.-]+)="([^"]*)"/g)) labels[m[1]] = m[2];
  }
  const oci = (k) => labels[`org.opencontainers.image.${k}`];
  for (const k of ['title', 'description', 'source', 'licenses', 'version', 'revision']) assert.notEqual(oci(k), undefined, `label ${k}`);
  assert.equal(oci('title'), 'clothd');
  assert.ok(oci('description').length > 10);
  // ${ARG}s of the stage, each declared there; the version's default is what clothd --version says.
  for (const k of ['version', 'source', 'revision', 'licenses']) {
    const m = /^\$\{(\w+)\}$/.exec(oci(k));
    assert.ok(m && m[1] in args, `${k} from an ARG of the runtime stage`);
  }
  const version = /^clothd (\S+)/.exec((await run(CLOTHD, ['--version'])).stdout)[1];
  assert.equal(args[/\w+/.exec(oci('version').slice(2))[0]], version);
});

// ---- compose ----

test('compose.yaml: one NVIDIA GPU, the ports, the state volume, the token secret, restart when clothd exits non-zero, a health check on /livez', () => {
  const c = YAML.parse(read(docker('compose.yaml')));
  const [name, svc] = Object.entries(c.services)[0];
  assert.equal(Object.keys(c.services).length, 1, 'one service');
  assert.equal(svc.build.dockerfile, 'docker/Dockerfile');
  assert.ok(existsSync(join(dirname(docker('compose.yaml')), svc.build.context, svc.build.dockerfile)));
  const devices = svc.deploy.resources.reservations.devices;
  assert.equal(devices.length, 1);
  assert.equal(devices[0].driver, 'nvidia');
  assert.equal(devices[0].count, 1);
  assert.ok(devices[0].capabilities.includes('gpu'));
  const published = svc.ports.map((p) => Number(String(p).split(':').at(-1)));
  assert.ok(published.includes(code.port) && published.includes(code.streamPort), `ports ${svc.ports}`);
  const stateDir = dirname(code.serve.vars.CLOTHD_STATE_FILE);
  const stateMount = svc.volumes.map((v) => v.split(':')).find(([, target]) => target === stateDir);
  assert.ok(stateMount, `a volume at ${stateDir}`);
  assert.ok(stateMount[0] in c.volumes, 'a named volume');
  // Compose mounts secret X at /run/secrets/X: clothd-serve must look there.
  assert.ok(svc.secrets.some((s) => code.serve.tokenPaths.includes(`/run/secrets/${s.source ?? s}`)), `${svc.secrets}`);
  for (const s of svc.secrets) assert.ok(c.secrets[s.source ?? s].file, `secret ${s} from a file`);
  assert.equal(svc.restart, 'on-failure', `${name} restarts on a non-zero exit only`);
  // Its health check is the image's: GET /livez on the HTTP port.
  routeExists('GET', '/livez');
  assert.match(svc.healthcheck.test.join(' '), new RegExp(`127\\.0\\.0\\.1:${code.port}/livez`));
  assert.ok(seconds(svc.stop_grace_period) >= code.minGrace, `stop_grace_period >= ${code.minGrace}s`);
  for (const [k, v] of Object.entries(svc.environment ?? {})) checkSettingVar(k, v);
});

// ---- systemd ----

function unitFile(path) {
  const sections = {};
  let cur = null;
  for (const raw of read(path).split('\n')) {
    const l = raw.trim();
    if (!l || l.startsWith('#') || l.startsWith(';')) continue;
    const sec = /^\[(\w+)\]$/.exec(l);
    if (sec) {
      cur = sections[sec[1]] = {};
      continue;
    }
    const i = l.indexOf('=');
    assert.ok(cur && i > 0, `unit line: ${l}`);
    (cur[l.slice(0, i)] ??= []).push(l.slice(i + 1));
  }
  return sections;
}

test('systemd unit: what the container runs, a state directory, restart on failure but not on bad settings, hardening, a user of its own', async () => {
  const u = unitFile(docker('systemd/clothd.service')).Service;
  const one = (k) => {
    assert.equal(u[k]?.length, 1, `one ${k}=`);
    return u[k][0];
  };
  assert.equal(one('ExecStart'), '/opt/clothd/bin/clothd-serve', 'the image\'s entrypoint');
  assert.equal(one('Restart'), 'on-failure');
  assert.equal(code.badSettingsExit, 2);
  assert.equal(one('RestartPreventExitStatus'), String(code.badSettingsExit), 'bad settings are not restarted');
  assert.ok(seconds(one('TimeoutStopSec')) >= code.minGrace);
  assert.equal(one('NoNewPrivileges'), 'yes');
  assert.match(one('ProtectSystem'), /^(strict|full)$/);
  assert.ok(u.DynamicUser?.[0] === 'yes' || (u.User && !['root', '0'].includes(u.User[0])), 'a user of its own');
  assert.equal(u.PrivateDevices, undefined, 'PrivateDevices would hide the GPU');
  assert.equal(one('DevicePolicy'), 'closed');
  assert.deepEqual(u.DeviceAllow, ['char-nvidia* rw'], 'the NVIDIA driver\'s devices, and no others');
  // A filtered system call fails with EPERM rather than killing the daemon, and setpriority (the
  // HTTP threads' http_nice) stays allowed after ~@resources.
  assert.equal(one('SystemCallErrorNumber'), 'EPERM');
  assert.deepEqual(u.SystemCallFilter, ['@system-service', '~@privileged @resources', 'setpriority']);
  // systemd sets STATE_DIRECTORY and CREDENTIALS_DIRECTORY; clothd-serve keeps the state and reads
  // the token where the unit says.
  const stateDir = `/var/lib/${one('StateDirectory')}`;
  const creds = '/run/credentials/clothd.service';
  const s = await explain({ STATE_DIRECTORY: stateDir, CREDENTIALS_DIRECTORY: creds });
  assert.equal(s.vars.CLOTHD_STATE_FILE, `${stateDir}/state.bin`);
  const id = one('LoadCredential').split(':')[0];
  assert.equal(s.tokenPaths[0], `${creds}/${id}`);
  for (const e of u.Environment ?? []) checkSettingVar(...e.replace(/^"|"$/g, '').split('='));
  // Type=notify with a watchdog: clothd sends READY=1 and WATCHDOG=1 itself (tests/server/systemd.test.mjs).
  assert.equal(one('Type'), 'notify');
  assert.equal(one('NotifyAccess'), 'main');
  assert.ok(seconds(one('WatchdogSec')) >= 2, 'WatchdogSec: WATCHDOG=1 comes at least every second');
});

test('systemd template clothd@N: one GPU each (CUDA_VISIBLE_DEVICES=N), its own ports (/etc/clothd/N.env) and state directory, as clothd.service otherwise', async () => {
  const base = unitFile(docker('systemd/clothd.service')).Service;
  const u = unitFile(docker('systemd/clothd@.service')).Service;
  assert.deepEqual(u.Environment, ['CUDA_VISIBLE_DEVICES=%i']);
  assert.deepEqual(u.EnvironmentFile, ['/etc/clothd/%i.env'], 'required: a missing file stops the start');
  assert.deepEqual(u.StateDirectory, ['clothd/%i']);
  // systemd sets STATE_DIRECTORY=/var/lib/clothd/N: each instance's state file is its own.
  const s = await explain({ STATE_DIRECTORY: '/var/lib/clothd/1', CREDENTIALS_DIRECTORY: '/run/credentials/clothd@1.service' });
  assert.equal(s.vars.CLOTHD_STATE_FILE, '/var/lib/clothd/1/state.bin');
  for (const k of new Set([...Object.keys(base), ...Object.keys(u)])) {
    if (['Environment', 'EnvironmentFile', 'StateDirectory'].includes(k)) continue;
    assert.deepEqual(u[k], base[k], `${k}= as in clothd.service`);
  }
  // The port settings an N.env names are clothd's.
  checkSettingVar('CLOTHD_PORT', '8090');
  checkSettingVar('CLOTHD_STREAM_PORT', '8091');
});

// ---- Kubernetes ----

function k8sDocs() {
  const dir = docker('k8s');
  const docs = [];
  for (const f of readdirSync(dir).filter((x) => x.endsWith('.yaml') && x !== 'kustomization.yaml')) {
    for (const d of YAML.parseAllDocuments(read(join(dir, f)))) {
      assert.deepEqual(d.errors, [], f);
      docs.push({ file: f, ...d.toJS() });
    }
  }
  return docs;
}
const byKind = (docs, kind) => docs.filter((d) => d.kind === kind);

test('Kubernetes: a StatefulSet of clothd pods, one GPU and many scenes each, a volume each for the state file, probes on /livez and /readyz, a grace period longer than a save', () => {
  const docs = k8sDocs();
  const [sts] = byKind(docs, 'StatefulSet');
  assert.ok(sts, 'a StatefulSet');
  const pod = sts.spec.template.spec;
  assert.equal(pod.containers.length, 1);
  const c = pod.containers[0];
  const ports = Object.fromEntries(c.ports.map((p) => [p.name, p.containerPort]));
  assert.equal(ports.http, code.port);
  assert.equal(ports.stream, code.streamPort);
  assert.equal(code.health.stream.path, '/stream');
  assert.equal(String(c.resources.limits['nvidia.com/gpu']), '1');
  // Many scenes share the pod's GPU: max_scenes is set, above one and within the setting's range.
  const maxScenes = Number(c.env.find((e) => e.name === 'CLOTHD_MAX_SCENES')?.value);
  assert.ok(maxScenes > 1 && maxScenes <= code.settings.max_scenes.max, `CLOTHD_MAX_SCENES ${maxScenes}`);
  routeExists('GET', '/livez');
  routeExists('GET', '/readyz');
  const paths = { readinessProbe: '/readyz', livenessProbe: '/livez', startupProbe: '/livez' };
  for (const probe of Object.keys(paths)) {
    assert.equal(c[probe].httpGet.path, paths[probe], probe);
    const port = c[probe].httpGet.port;
    assert.equal(typeof port === 'string' ? ports[port] : port, code.port, `${probe} port`);
  }
  assert.ok(pod.terminationGracePeriodSeconds >= code.minGrace, `terminationGracePeriodSeconds >= ${code.minGrace}`);
  // The state file on a volume of each pod's own (a volume claim template), where clothd-serve keeps it.
  const stateDir = dirname(code.serve.vars.CLOTHD_STATE_FILE);
  const stateMount = c.volumeMounts.find((m) => m.mountPath === stateDir);
  assert.ok(stateMount, `a mount at ${stateDir}`);
  assert.ok(sts.spec.volumeClaimTemplates.some((t) => t.metadata.name === stateMount.name), 'the state volume is per pod');
  // The tokens from a Secret, mounted where clothd-serve looks for them.
  const tokens = c.volumeMounts.filter((m) => m.name !== stateMount.name);
  const vol = pod.volumes.find((v) => v.name === tokens[0].name).secret;
  const files = vol.items.map((i) => join(tokens[0].mountPath, i.path));
  assert.ok(files.includes(code.serve.tokenPaths.at(-1)), `${files} holds ${code.serve.tokenPaths.at(-1)}`);
  assert.ok(files.includes(code.serve.viewTokenPaths.at(-1)));
  const kust = YAML.parse(read(docker('k8s/kustomization.yaml')));
  const gen = kust.secretGenerator.find((g) => g.name === vol.secretName);
  assert.ok(gen, `the Secret ${vol.secretName} is generated`);
  for (const i of vol.items) assert.ok(gen.files.includes(i.key), `the Secret has ${i.key}`);
  assert.equal(kust.generatorOptions.disableNameSuffixHash, true, 'the Secret keeps its name (the ServiceMonitor names it)');
  // Not root; the pod's volume group lets it write its state.
  assert.equal(pod.securityContext.runAsNonRoot, true);
  assert.ok(pod.securityContext.runAsUser > 0);
  assert.equal(pod.securityContext.fsGroup, pod.securityContext.runAsGroup);
  assert.equal(c.securityContext.allowPrivilegeEscalation, false);
  assert.deepEqual(c.securityContext.capabilities.drop, ['ALL']);
  assert.equal(c.securityContext.readOnlyRootFilesystem, true);
  assert.equal(pod.automountServiceAccountToken, false);
  for (const e of c.env) checkSettingVar(e.name, e.value);
  for (const f of kust.resources) assert.ok(existsSync(docker(`k8s/${f}`)), f);
});

test('Kubernetes: a headless Service gives each pod a stable name the API answers to; metrics are scraped with the view token', () => {
  const docs = k8sDocs();
  const [sts] = byKind(docs, 'StatefulSet');
  const svc = byKind(docs, 'Service').find((s) => s.spec.clusterIP === 'None');
  assert.ok(svc, 'a headless Service');
  // /readyz turns 503 when a pod is full: its name stays, for the scenes it holds.
  assert.equal(svc.spec.publishNotReadyAddresses, true);
  assert.equal(sts.spec.serviceName, svc.metadata.name);
  const labels = sts.spec.template.metadata.labels;
  for (const [k, v] of Object.entries(svc.spec.selector)) assert.equal(labels[k], v);
  for (const [k, v] of Object.entries(sts.spec.selector.matchLabels)) assert.equal(labels[k], v);
  const c = sts.spec.template.spec.containers[0];
  const containerPorts = Object.fromEntries(c.ports.map((p) => [p.name, p.containerPort]));
  for (const p of svc.spec.ports) assert.equal(p.port, containerPorts[p.targetPort], p.name);
  // clothd-N.<service>.<namespace>.svc: the Host clothd must answer to (allowed_hosts).
  const hosts = c.env.find((e) => e.name === 'CLOTHD_ALLOWED_HOSTS').value.split(',');
  assert.ok(hosts.includes(`$(POD_NAME).${svc.metadata.name}.$(POD_NAMESPACE).svc`), hosts.join(','));
  assert.deepEqual(c.env.find((e) => e.name === 'POD_NAME').valueFrom.fieldRef, { fieldPath: 'metadata.name' });
  assert.deepEqual(c.env.find((e) => e.name === 'POD_NAMESPACE').valueFrom.fieldRef, { fieldPath: 'metadata.namespace' });
  // The ServiceMonitor: /metrics on the http port, with the view token (metrics need a token
  // when one is set).
  const [mon] = byKind(docs, 'ServiceMonitor');
  routeExists('GET', '/metrics');
  for (const [k, v] of Object.entries(mon.spec.selector.matchLabels)) assert.equal(svc.metadata.labels[k], v);
  const ep = mon.spec.endpoints[0];
  assert.equal(ep.path, '/metrics');
  assert.equal(svc.spec.ports.find((p) => p.name === ep.port).port, code.port);
  const vol = sts.spec.template.spec.volumes.find((v) => v.secret).secret;
  assert.equal(ep.authorization.credentials.name, vol.secretName);
  const viewFile = vol.items.find((i) => i.key === ep.authorization.credentials.key).path;
  assert.ok(code.serve.viewTokenPaths.at(-1).endsWith(`/${viewFile}`), 'Prometheus uses the view token');
});

test('Kubernetes: a Service per pod and an HTTPRoute give scene S on pod P a stable URL, /pods/P/..., prefix cut off', () => {
  const docs = k8sDocs();
  const [sts] = byKind(docs, 'StatefulSet');
  const c = sts.spec.template.spec.containers[0];
  const containerPorts = Object.fromEntries(c.ports.map((p) => [p.name, p.containerPort]));
  const pods = Array.from({ length: sts.spec.replicas }, (_, i) => `${sts.metadata.name}-${i}`);
  // One Service per pod, selecting that pod alone by the label the StatefulSet controller sets,
  // its ports the container's, the names of full pods published.
  const perPod = byKind(docs, 'Service').filter((s) => s.spec.selector?.['statefulset.kubernetes.io/pod-name']);
  assert.deepEqual(perPod.map((s) => s.metadata.name).sort(), pods, 'a Service per replica, named as its pod');
  const services = {};
  for (const s of perPod) {
    assert.equal(s.file, 'pod-services.yaml');
    assert.deepEqual(Object.keys(s.spec.selector), ['statefulset.kubernetes.io/pod-name']);
    assert.equal(s.spec.selector['statefulset.kubernetes.io/pod-name'], s.metadata.name);
    assert.equal(s.spec.publishNotReadyAddresses, true, s.metadata.name);
    assert.notEqual(s.spec.clusterIP, 'None');
    for (const p of s.spec.ports) assert.equal(p.port, containerPorts[p.targetPort], `${s.metadata.name} ${p.name}`);
    services[s.metadata.name] = Object.fromEntries(s.spec.ports.map((p) => [p.port, containerPorts[p.targetPort]]));
  }
  const kust = YAML.parse(read(docker('k8s/kustomization.yaml')));
  assert.ok(kust.resources.includes('pod-services.yaml'));
  // The ServiceMonitor scrapes each pod once, through the headless Service alone.
  const [mon] = byKind(docs, 'ServiceMonitor');
  const matches = (s) => Object.entries(mon.spec.selector.matchLabels).every(([k, v]) => s.metadata.labels?.[k] === v);
  assert.deepEqual(byKind(docs, 'Service').filter(matches).map((s) => s.spec.clusterIP), ['None']);
  // The HTTPRoute: /pods/P to P's http port with the prefix replaced by /, /pods/P/stream to its
  // stream port as /stream (the stream's path, GET /v1/health); every rule names a per-pod Service.
  const [route] = byKind(docs, 'HTTPRoute');
  assert.ok(route, 'an HTTPRoute');
  assert.equal(route.apiVersion, 'gateway.networking.k8s.io/v1');
  const seen = new Set();
  for (const rule of route.spec.rules) {
    assert.equal(rule.matches.length, 1);
    const { path } = rule.matches[0];
    assert.equal(path.type, 'PathPrefix');
    const m = /^\/pods\/([a-z0-9-]+)(\/stream)?$/.exec(path.value);
    assert.ok(m, path.value);
    const [, pod, stream] = m;
    assert.ok(pods.includes(pod), `${path.value}: ${pod} is no pod`);
    assert.equal(rule.backendRefs.length, 1);
    const ref = rule.backendRefs[0];
    assert.equal(ref.name, pod, `${path.value} goes to ${pod}'s Service`);
    assert.ok(services[pod][ref.port], `${pod} has port ${ref.port}`);
    const rewrite = rule.filters.find((f) => f.type === 'URLRewrite').urlRewrite.path;
    assert.equal(rewrite.type, 'ReplacePrefixMatch');
    if (stream) {
      assert.equal(services[pod][ref.port], code.streamPort);
      assert.equal(rewrite.replacePrefixMatch, code.health.stream.path);
    } else {
      assert.equal(services[pod][ref.port], code.port);
      assert.equal(rewrite.replacePrefixMatch, '/');
    }
    seen.add(`${pod}${stream ?? ''}`);
  }
  for (const pod of pods) for (const k of [pod, `${pod}/stream`]) assert.ok(seen.has(k), `a rule for /pods/${k}`);
  routeExists('GET', '/v1/scenes/{scene}/sim');
  // The gateway passes the client's Host on: clothd must answer to it.
  const hosts = c.env.find((e) => e.name === 'CLOTHD_ALLOWED_HOSTS').value.split(',');
  for (const h of route.spec.hostnames) assert.ok(hosts.includes(h), `${h} is in CLOTHD_ALLOWED_HOSTS`);
});

test('Kubernetes: kubectl kustomize builds the manifests (where kubectl is installed)', async (t) => {
  const kubectl = await run('sh', ['-c', 'command -v kubectl']).then((r) => r.stdout.trim(), () => '');
  if (!kubectl) {
    t.skip('kubectl not installed');
    return;
  }
  const dir = join(tempDir('k8s'), 'k8s');
  mkdirSync(dir);
  for (const f of readdirSync(docker('k8s'))) if (statSync(docker(`k8s/${f}`)).isFile()) copyFileSync(docker(`k8s/${f}`), join(dir, f));
  writeFileSync(join(dir, 'token'), 'control-t0ken-0123456789abcdef\n');
  writeFileSync(join(dir, 'view_token'), 'view-t0ken-0123456789abcdef\n');
  const { stdout } = await run(kubectl, ['kustomize', dir]);
  const kinds = YAML.parseAllDocuments(stdout).map((d) => d.toJS().kind).sort();
  const [stsIn] = byKind(k8sDocs(), 'StatefulSet');
  // the Secret, the headless Service, a Service per pod, the StatefulSet
  assert.deepEqual(kinds, ['Secret', ...Array(1 + stsIn.spec.replicas).fill('Service'), 'StatefulSet']);
  const sts = YAML.parseAllDocuments(stdout).map((d) => d.toJS()).find((d) => d.kind === 'StatefulSet');
  assert.match(sts.spec.template.spec.containers[0].image, /clothd:/);
});

