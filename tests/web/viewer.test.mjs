// viewer.test.mjs - unit tests of the viewer's pure modules (no browser): the schema-to-panel
// mapping against a schema written here, the render topology against hand-counted grids, the
// normals against a flat and a folded cloth, and the colour maps' ends.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { controlsFromSchema, valueForControl, controlLabel } from '../../web/src/schema.js';
import { triangleIndices, springIndices, springEnds, vertexNormals } from '../../web/src/topology.js';
import { lut, speedRgb, heatRgb, applyLut } from '../../web/src/colors.js';

const SCHEMA = {
  params: [
    { name: 'nx', type: 'int', unit: '-', default: 64, min: 2, max: 4096, choices: null, kind: 'scene', help: 'Vertices along x' },
    { name: 'orientation', type: 'enum', unit: '-', default: 'horizontal', min: null, max: null, choices: ['horizontal', 'vertical'], kind: 'scene', help: 'h or v' },
    { name: 'gravity', type: 'vec3', unit: 'm/s^2', default: [0, 0, -9.81], min: -1000, max: 1000, choices: null, kind: 'live', help: 'g' },
    { name: 'k_structural', type: 'float', unit: 'N/m', default: 400, min: 0, max: 1e9, choices: null, kind: 'live', help: 'k' },
    { name: 'mu', type: 'float', unit: '-', default: 0.5, min: 0, max: 100, choices: null, kind: 'live', help: 'friction' },
    { name: 'substeps', type: 'int', unit: '-', default: 30, min: 1, max: 100000, choices: null, kind: 'live', help: 'n' },
    { name: 'ground', type: 'bool', unit: '-', default: true, min: null, max: null, choices: null, kind: 'live', help: 'on' },
    { name: 'brand_new', type: 'float', unit: 'J', default: 1, min: 0, max: 10, choices: null, kind: 'live', help: 'a parameter added later' },
    { name: 'port', type: 'int', unit: '-', default: 8080, min: 0, max: 65535, choices: null, kind: 'startup', help: 'p' },
    { name: 'web_root', type: 'string', unit: '-', default: 'web', min: null, max: null, choices: null, kind: 'startup', help: 'w' },
  ],
};

test('every scene and live parameter gets a control, startup settings none', () => {
  const c = controlsFromSchema(SCHEMA);
  assert.deepEqual(c.scene.map((x) => x.name), ['nx', 'orientation']);
  assert.deepEqual(c.live.map((x) => x.name), ['gravity', 'k_structural', 'mu', 'substeps', 'ground', 'brand_new']);
  const by = Object.fromEntries([...c.scene, ...c.live].map((x) => [x.name, x]));
  assert.equal(by.nx.widget, 'number');           // 2 .. 4096: wider than a slider
  assert.equal(by.nx.step, 1);
  assert.equal(by.orientation.widget, 'select');
  assert.deepEqual(by.orientation.choices, ['horizontal', 'vertical']);
  assert.equal(by.gravity.widget, 'vector');
  assert.equal(by.k_structural.widget, 'number'); // 0 .. 1e9 N/m
  assert.equal(by.mu.widget, 'slider');           // 0 .. 100
  assert.equal(by.substeps.widget, 'number');
  assert.equal(by.ground.widget, 'checkbox');
  assert.equal(by.brand_new.widget, 'slider');    // a new parameter needs no viewer change
  assert.equal(by.brand_new.label, 'brand_new (J)');
  assert.equal(by.brand_new.help, 'a parameter added later');
  assert.equal(by.k_structural.label, 'k_structural (N/m)');
  assert.equal(by.mu.label, 'mu');                // no unit
  assert.deepEqual(by.gravity.default, [0, 0, -9.81]);
});

test('steps: whole numbers for ints, none for floats (a typed value keeps its digits)', () => {
  const c = controlsFromSchema(SCHEMA);
  const by = Object.fromEntries([...c.scene, ...c.live].map((x) => [x.name, x]));
  assert.equal(by.nx.step, 1);
  assert.equal(by.substeps.step, 1);
  assert.equal(by.mu.step, null);
  assert.equal(by.k_structural.step, null);
  assert.equal(controlLabel({ name: 'drag', unit: '1/s' }), 'drag (1/s)');
});

test('values the panel refuses before asking the server', () => {
  const c = controlsFromSchema(SCHEMA);
  const by = Object.fromEntries([...c.scene, ...c.live].map((x) => [x.name, x]));
  assert.deepEqual(valueForControl(by.mu, '0.25'), { value: 0.25 });
  assert.match(valueForControl(by.mu, 'abc').error, /finite/);
  assert.match(valueForControl(by.mu, Infinity).error, /finite/);
  assert.match(valueForControl(by.substeps, 2.5).error, /whole/);
  assert.deepEqual(valueForControl(by.gravity, [0, '1', -2]), { value: [0, 1, -2] });
  assert.match(valueForControl(by.gravity, [0, NaN, 1]).error, /three finite/);
  assert.match(valueForControl(by.orientation, 'diagonal').error, /horizontal, vertical/);
  assert.match(valueForControl(by.ground, 'yes').error, /true or false/);
  // Range checks are the server's: an out-of-range number goes to it (and its 422 is shown).
  assert.deepEqual(valueForControl(by.mu, 1e6), { value: 1e6 });
});

test('the topology of an intact grid: 2 triangles per quad, structural and shear lines', () => {
  const nx = 4, ny = 3, n = nx * ny;
  const tri = triangleIndices(nx, ny, new Set());
  assert.equal(tri.length, 3 * 2 * (nx - 1) * (ny - 1));
  // The first quad, split on its +x+y diagonal: (0, 1, 5) and (0, 5, 4).
  assert.deepEqual(Array.from(tri.slice(0, 6)), [0, 1, 5, 0, 5, 4]);
  const lines = springIndices(nx, ny, new Set());
  // Structural (nx-1) ny + nx (ny-1), shear 2 (nx-1)(ny-1): 9 + 8 + 12 = 29 springs.
  assert.equal(lines.length, 2 * 29);
  assert.deepEqual(springEnds(3 * n + 1, nx, ny), [1, 4]);   // shear -x+y from (1, 0) to (0, 1)
  assert.equal(springEnds(3 * n + 0, nx, ny), null);          // (0, 0) has no -x neighbour
  assert.equal(springEnds(4 * n + 2, nx, ny), null);          // bend +2x from (2, 0) leaves the grid
  assert.deepEqual(springEnds(5 * n + 1, nx, ny), [1, 9]);   // bend +2y
});

test('a torn spring removes exactly the triangles and the line that use it', () => {
  const nx = 4, ny = 3, n = nx * ny;
  const full = triangleIndices(nx, ny, new Set()).length / 3;
  // The structural +x spring 5-6 is an edge of quad (1,0)'s B and of quad (1,1)'s A.
  const torn = new Set([0 * n + 5]);
  const tri = triangleIndices(nx, ny, torn);
  assert.equal(tri.length / 3, full - 2);
  for (let t = 0; t < tri.length; t += 3) {
    const v = [tri[t], tri[t + 1], tri[t + 2]];
    assert.ok(!(v.includes(5) && v.includes(6)), `triangle ${v} still uses the torn edge 5-6`);
  }
  assert.equal(springIndices(nx, ny, torn).length, 2 * 28);
  // The diagonal 0-5 (shear +x+y of vertex 0) takes both triangles of the first quad.
  assert.equal(triangleIndices(nx, ny, new Set([2 * n + 0])).length / 3, full - 2);
  // The other diagonal (shear -x+y) is no triangle's edge: the surface stays whole.
  assert.equal(triangleIndices(nx, ny, new Set([3 * n + 1])).length / 3, full);
  // A lent array is reused.
  const into = new Uint32Array(100);
  assert.equal(triangleIndices(nx, ny, torn, into).buffer, into.buffer);
});

test('normals of a flat cloth are its plane\'s, of a folded one each side\'s', () => {
  const nx = 3, ny = 3;
  const p = new Float32Array(3 * nx * ny);
  for (let j = 0; j < ny; j++) for (let i = 0; i < nx; i++) p.set([i, j, 1], 3 * (j * nx + i));
  const index = triangleIndices(nx, ny, new Set());
  const nrm = new Float32Array(p.length);
  vertexNormals(p, index, nrm);
  const normalOf = (v) => Array.from(nrm.slice(3 * v, 3 * v + 3)).map((x) => Math.round(x * 1e6) / 1e6 + 0);
  for (let v = 0; v < nx * ny; v++) assert.deepEqual(normalOf(v), [0, 0, 1]);
  // A right-angle fold: the column i = 2 moves from (2, j, 1) up to (1, j, 2), so the quads of
  // i = 1 stand in the plane x = 1. Column 0 belongs to flat triangles only (+z); column 2 to
  // the standing ones only: (0, 0, 1) x (0, 1, 1) = (-1, 0, 0).
  for (let j = 0; j < ny; j++) p.set([1, j, 2], 3 * (j * nx + 2));
  vertexNormals(p, index, nrm);
  for (let j = 0; j < ny; j++) {
    assert.deepEqual(normalOf(j * nx), [0, 0, 1]);
    assert.deepEqual(normalOf(j * nx + 2), [-1, 0, 0]);
  }
  // A vertex of no triangle gets +z, not NaN.
  const lone = new Float32Array(3);
  vertexNormals(new Float32Array(3), new Uint32Array(0), lone);
  assert.deepEqual(Array.from(lone), [0, 0, 1]);
});

test('colour maps: blue when slow, red when fast; the heat map from dark blue to red', () => {
  const speed = lut(speedRgb), heat = lut(heatRgb);
  const at = (t, s) => Array.from(t.slice(3 * s, 3 * s + 3));
  const [r0, , b0] = at(speed, 0), [r1, , b1] = at(speed, 255);
  assert.ok(b0 > 200 && r0 < 60, 'slow is blue');
  assert.ok(r1 > 200 && b1 < 60, 'fast is red');
  assert.deepEqual(at(heat, 0), [20, 40, 140]);
  assert.deepEqual(at(heat, 255), [220, 30, 20]);
  const rgb = new Uint8Array(6);
  applyLut(speed, Uint8Array.of(0, 255), rgb, 2);
  assert.deepEqual(Array.from(rgb), [...at(speed, 0), ...at(speed, 255)]);
});
