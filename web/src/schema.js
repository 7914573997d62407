// schema.js - turns GET /v1/params/schema into control descriptions for the panel, so that a new
// parameter of the table appears in the viewer with no change here. No DOM, no three.js: node's
// tests import it as it is.
//
// A control: {name, kind: 'live'|'scene', widget, label, unit, help, default, min, max, step (1
// for ints, else null), choices}. widget is
//   'checkbox' for bool, 'select' for enum (choices), 'vector' for vec3 (three numbers),
//   'slider' for an int or float whose range is bounded and not wider than SLIDER_SPAN,
//   'number' for the rest (a box: a slider over 0 .. 1e9 N/m could not set 400).
// `startup` settings and strings are left out: they cannot change while clothd runs.

export const SLIDER_SPAN = 1000;

/** Label shown in the panel: the name, with its unit unless it has none. */
export function controlLabel(p) {
  return p.unit && p.unit !== '-' ? `${p.name} (${p.unit})` : p.name;
}

/**
 * @param {{params: object[]}} schema GET /v1/params/schema
 * @returns {{live: object[], scene: object[]}} in the schema's order
 */
export function controlsFromSchema(schema) {
  const out = { live: [], scene: [] };
  for (const p of schema.params ?? []) {
    if (p.kind !== 'live' && p.kind !== 'scene') continue;
    let widget;
    if (p.type === 'bool') widget = 'checkbox';
    else if (p.type === 'enum') widget = 'select';
    else if (p.type === 'vec3') widget = 'vector';
    else if (p.type === 'int' || p.type === 'float') {
      const bounded = Number.isFinite(p.min) && Number.isFinite(p.max);
      widget = bounded && p.max - p.min <= SLIDER_SPAN ? 'slider' : 'number';
    } else continue; // strings: none are live
    const c = {
      name: p.name, kind: p.kind, widget, label: controlLabel(p), unit: p.unit, help: p.help ?? '',
      default: p.default, min: p.min ?? null, max: p.max ?? null, choices: p.choices ?? null, step: null,
    };
    // Whole numbers only for ints; a float keeps every digit typed (an explicit step would make
    // lil-gui round what is typed to it: 0.0001 on a step of 0.001 would become 0).
    if (p.type === 'int') c.step = 1;
    out[p.kind].push(c);
  }
  return out;
}

/**
 * The value to send for a control, or an error string when the panel already knows it is wrong
 * (not a number); range checks are the server's, whose problem+json the panel shows.
 */
export function valueForControl(c, value) {
  if (c.widget === 'checkbox') return typeof value === 'boolean' ? { value } : { error: 'not true or false' };
  if (c.widget === 'select') return c.choices.includes(value) ? { value } : { error: `not one of ${c.choices.join(', ')}` };
  const num = (x) => (typeof x === 'number' ? x : Number(x));
  if (c.widget === 'vector') {
    const v = Array.isArray(value) && value.length === 3 ? value.map(num) : null;
    return v && v.every(Number.isFinite) ? { value: v } : { error: 'needs three finite numbers' };
  }
  const x = num(value);
  if (!Number.isFinite(x)) return { error: 'not a finite number' };
  if (c.step === 1 && !Number.isInteger(x)) return { error: 'not a whole number' };
  return { value: x };
}
