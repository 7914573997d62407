// implicit.test.mjs - integrator implicit_euler through the API (kernels/MODEL.md, "The implicit
// solver"): its parameters in the schema and checked like every other (422 naming the parameter,
// nothing changed), the switch taken with a rock in the scene and a rock added under it (the rock
// then rests on the cloth, above the cloth's pinned height less its sag), and /v1/sim's solver
// report after a step: substeps solved, Newton and CG iterations, residual.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { start, stop, call, ok, PROBLEM } from './harness.mjs';

test('implicit_euler: schema, checks, rocks and the solver report', async () => {
  const d = await start(['--paused', '--nx', '24', '--ny', '24', '--auto-drop-interval', '0']);
  try {
    const schema = await ok(d, 'GET', '/v1/params/schema');
    const row = (name) => schema.params.find((p) => p.name === name);
    assert.ok(row('integrator').choices.includes('implicit_euler'));
    for (const name of ['implicit_substeps', 'solver_iterations', 'solver_tolerance', 'cg_iterations']) assert.ok(row(name), name);

    const before = await ok(d, 'GET', '/v1/params');
    // (NaN: JSON.stringify writes null; a bare NaN is malformed JSON, 400, server/errors.test.mjs)
    for (const [name, value] of [['solver_iterations', 0], ['solver_iterations', -3], ['solver_iterations', 'many'],
      ['solver_iterations', NaN], ['solver_iterations', 1e6], ['solver_iterations', 2.5], ['solver_tolerance', 0],
      ['solver_tolerance', NaN], ['solver_tolerance', '1e-3'], ['cg_iterations', 0], ['implicit_substeps', 0]]) {
      const r = await call(d, 'PATCH', '/v1/params', { [name]: value });
      assert.equal(r.status, 422, `${name} ${value}: ${r.status} ${r.text}`);
      assert.equal(r.type, PROBLEM);
      assert.equal(r.json.param, name);
    }
    assert.deepEqual(await ok(d, 'GET', '/v1/params'), before);

    // It runs, and /v1/sim says what the solver did.
    const set = await ok(d, 'PATCH', '/v1/params', { integrator: 'implicit_euler' });
    assert.equal(set.params.integrator, 'implicit_euler');
    const sim0 = await ok(d, 'GET', '/v1/sim');
    assert.equal(sim0.substeps, set.params.implicit_substeps);
    await ok(d, 'POST', '/v1/sim/step', { frames: 3 });
    const sim = await ok(d, 'GET', '/v1/sim');
    assert.ok(sim.solver.substeps >= sim0.substeps, JSON.stringify(sim.solver));
    assert.ok(sim.solver.newton >= 1 && sim.solver.iterations >= 1, JSON.stringify(sim.solver));
    assert.ok(sim.solver.residual >= 0 && sim.solver.residual < 1, JSON.stringify(sim.solver));

    // A rock dropped under it lands on the cloth (1 m up, edges pinned) and stays on it: after two
    // seconds it is above the ground and below where it was let go.
    const rock = await ok(d, 'POST', '/v1/rocks', { position: [0, 0, 1.5], radius: 0.1, density: 2500 });
    await ok(d, 'POST', '/v1/sim/step', { frames: 120 });
    const held = await ok(d, 'GET', `/v1/rocks/${rock.id}`);
    assert.ok(held.position[2] > 0.1 && held.position[2] < 1.5, JSON.stringify(held));
    // and back to velocity Verlet with the rock in contact, and again to implicit_euler: finite
    await ok(d, 'PATCH', '/v1/params', { integrator: 'velocity_verlet' });
    await ok(d, 'POST', '/v1/sim/step', { frames: 5 });
    await ok(d, 'PATCH', '/v1/params', { integrator: 'implicit_euler' });
    await ok(d, 'POST', '/v1/sim/step', { frames: 5 });
    const again = await ok(d, 'GET', `/v1/rocks/${rock.id}`);
    assert.ok(again.position.every(Number.isFinite) && again.position[2] > 0.1, JSON.stringify(again));
  } finally {
    await stop(d);
  }
});
