// implicit.test.mjs - integrator implicit_euler through the API (kernels/MODEL.md, "The implicit
// solver"): its parameters in the schema and checked like every other (422 naming the parameter,
// nothing changed), the switch refused while a rock is in the scene (rocks are not coupled yet),
// and /v1/sim's solver report after a step: substeps solved, Newton and CG iterations, residual.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { start, stop, call, ok, PROBLEM } from './harness.mjs';

test('implicit_euler: schema, checks, the rock refusal and the solver report', async () => {
  const d = await start(['--paused', '--nx', '24', '--ny', '24', '--auto-drop-interval', '0']);
  try {
    const schema = await ok(d, 'GET', '/v1/params/schema');
    const row = (name) => schema.params.find((p) => p.name === name);
    assert.ok(row('integrator').choices.includes('implicit_euler'));
    for (const name of ['implicit_substeps', 'solver_iterations', 'solver_tolerance', 'cg_iterations']) assert.ok(row(name), name);

    const before = await ok(d, 'GET', '/v1/params');
    for (const [name, value] of [['solver_iterations', 0], ['solver_iterations', -3], ['solver_iterations', 'many'],
      ['solver_iterations', 1e6], ['solver_tolerance', 0], ['cg_iterations', 0], ['implicit_substeps', 0]]) {
      const r = await call(d, 'PATCH', '/v1/params', { [name]: value });
      assert.ok(r.status === 422 || r.status === 400, `${name} ${value}: ${r.status}`);
      assert.equal(r.type, PROBLEM);
      assert.equal(r.json.param, name);
    }
    assert.deepEqual(await ok(d, 'GET', '/v1/params'), before);

    // A rock in the scene: the switch is refused and changes nothing.
    await ok(d, 'POST', '/v1/rocks', { position: [0, 0, 1.5], radius: 0.1 });
    const refused = await call(d, 'PATCH', '/v1/params', { integrator: 'implicit_euler' });
    assert.equal(refused.status, 422, refused.text);
    assert.equal(refused.json.param, 'integrator');
    assert.equal((await ok(d, 'GET', '/v1/params')).integrator, 'velocity_verlet');

    // Without rocks it runs, and /v1/sim says what the solver did.
    await ok(d, 'POST', '/v1/sim/reset');
    const set = await ok(d, 'PATCH', '/v1/params', { integrator: 'implicit_euler' });
    assert.equal(set.params.integrator, 'implicit_euler');
    const sim0 = await ok(d, 'GET', '/v1/sim');
    assert.equal(sim0.substeps, set.params.implicit_substeps);
    await ok(d, 'POST', '/v1/sim/step', { frames: 3 });
    const sim = await ok(d, 'GET', '/v1/sim');
    assert.ok(sim.solver.substeps >= sim0.substeps, JSON.stringify(sim.solver));
    assert.ok(sim.solver.newton >= 1 && sim.solver.iterations >= 1, JSON.stringify(sim.solver));
    assert.ok(sim.solver.residual >= 0 && sim.solver.residual < 1, JSON.stringify(sim.solver));
    // and a rock is now refused, naming the reason
    const rock = await call(d, 'POST', '/v1/rocks', { position: [0, 0, 1.5], radius: 0.1 });
    assert.equal(rock.status, 422, rock.text);
    assert.match(rock.json.detail, /implicit_euler/);
  } finally {
    await stop(d);
  }
});
