// presets.test.mjs - PUT /v1/scene {"preset"}: the named scenes that show self_collision (kernels/
// MODEL.md, "Scene presets") set their scene fields, live parameters, pins and rocks; fields given
// beside the preset override its own; an unknown name is 422 and changes nothing; the spec's list
// of names is the daemon's.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { start, stop, call, ok, pause, hash, SPEC, PROBLEM } from './harness.mjs';

test('presets set scene, parameters, pins and rocks; bad names change nothing', async () => {
  const d = await start();
  try {
    await pause(d);
    const towel = await ok(d, 'PUT', '/v1/scene', { preset: 'towel-on-line' });
    assert.equal(towel.preset, 'towel-on-line');
    assert.equal(towel.nx, 32);
    const params = await ok(d, 'GET', '/v1/params');
    assert.equal(params.self_collision, true);
    assert.equal(params.integrator, 'implicit_euler');
    assert.deepEqual(params.wind, [0, 3, 0]);
    // the line: the middle row pinned, 32 vertices (unpinning a vertex of the edge changes nothing)
    const pins = await ok(d, 'PUT', '/v1/pins', { vertices: [0], pinned: false });
    assert.equal(pins.pinned, 32);
    assert.equal((await ok(d, 'GET', '/v1/rocks')).rocks.length, 0);
    // it runs, with self_collision on: the pinned line stays up while the halves fall
    await ok(d, 'POST', '/v1/sim/step', { frames: 5 });
    const state = await ok(d, 'GET', '/v1/cloth/state');
    const z = (v) => state.positions[v][2];
    assert.ok(Math.abs(z(16 * 32 + 5) - 1.2) < 1e-6, 'a pinned vertex of the line stays at 1.2 m');
    assert.ok(z(5) < 1.2 - 0.01, 'the edge of a half falls');

    const stone = await ok(d, 'PUT', '/v1/scene', { preset: 'cloth-over-stone' });
    assert.equal(stone.height, 0.9);
    const rocks = (await ok(d, 'GET', '/v1/rocks')).rocks;
    assert.equal(rocks.length, 1);
    assert.equal(rocks[0].radius, 0.25);
    assert.equal(rocks[0].kinematic, true);

    // fields beside the preset override its own
    const crumple = await ok(d, 'PUT', '/v1/scene', { preset: 'sheet-crumple', nx: 20 });
    assert.equal(crumple.nx, 20);
    assert.equal(crumple.ny, 32);
    assert.equal((await ok(d, 'GET', '/v1/rocks')).rocks[0].radius, 0.15);

    // an unknown preset or a wrong type: a problem, nothing changed
    const scene = await ok(d, 'GET', '/v1/scene'), h = await hash(d);
    const unknown = await call(d, 'PUT', '/v1/scene', { preset: 'flag-in-wind' });
    assert.equal(unknown.status, 422);
    assert.equal(unknown.type, PROBLEM);
    assert.equal(unknown.json.param, 'preset');
    const wrong = await call(d, 'PUT', '/v1/scene', { preset: 5 });
    assert.equal(wrong.status, 400);
    assert.deepEqual(await ok(d, 'GET', '/v1/scene'), scene);
    assert.equal(await hash(d), h);
    // the names the daemon knows are the spec's
    const names = unknown.json.detail.replace(/^preset must be one of /, '').split(', ');
    const input = SPEC.components.schemas.SceneInput.allOf.find((s) => s.properties?.preset);
    assert.deepEqual(input.properties.preset.enum, names);
  } finally {
    await stop(d);
  }
});
