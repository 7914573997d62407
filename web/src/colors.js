// colors.js - colour maps from the frame's per-vertex scalar (0 .. 255) to RGB bytes, as lookup
// tables of 256 entries. No three.js: node's tests import it as it is.

const lerp = (a, b, t) => a + (b - a) * t;

/** Speed (seed 004): blue when slow through violet to red when fast. */
export function speedRgb(t) {
  return [Math.round(lerp(40, 235, t)), Math.round(lerp(90, 40, t)), Math.round(lerp(235, 40, t))];
}

/** Strain: a heat map, dark blue (unstrained) - cyan - yellow - red (0.25 and more). */
const HEAT = [[20, 40, 140], [0, 170, 220], [250, 220, 40], [220, 30, 20]];
export function heatRgb(t) {
  const x = Math.min(Math.max(t, 0), 1) * (HEAT.length - 1);
  const k = Math.min(Math.floor(x), HEAT.length - 2), f = x - k;
  return [0, 1, 2].map((c) => Math.round(lerp(HEAT[k][c], HEAT[k + 1][c], f)));
}

/** 256 RGB entries of a map over t = s / 255. */
export function lut(map) {
  const out = new Uint8Array(256 * 3);
  for (let s = 0; s < 256; s++) out.set(map(s / 255), 3 * s);
  return out;
}

/** Fills rgb (3 bytes per vertex) from scalar (1 byte per vertex) through a lut. */
export function applyLut(table, scalar, rgb, n) {
  for (let v = 0; v < n; v++) {
    const s = 3 * scalar[v];
    rgb[3 * v] = table[s]; rgb[3 * v + 1] = table[s + 1]; rgb[3 * v + 2] = table[s + 2];
  }
}

/**
 * Stretch, diverging: t = -1 blue (compressed by the panel's range or more), 0 white (at rest),
 * 1 red (stretched by the range or more).
 */
const BLUE = [40, 90, 220], WHITE = [240, 240, 240], RED = [215, 35, 30];
export function stretchRgb(t) {
  const x = Math.min(Math.max(t, -1), 1), to = x < 0 ? BLUE : RED, f = Math.abs(x);
  return [0, 1, 2].map((c) => Math.round(lerp(WHITE[c], to[c], f)));
}

/**
 * Fills rgb (3 bytes per vertex) from signed strains through a lut of stretchRgb over 256 steps
 * of -range .. range.
 */
export function applyStretch(table, strain, range, rgb, n) {
  const k = 127.5 / range;
  for (let v = 0; v < n; v++) {
    const s = 3 * Math.min(255, Math.max(0, Math.round(127.5 + k * strain[v])));
    rgb[3 * v] = table[s]; rgb[3 * v + 1] = table[s + 1]; rgb[3 * v + 2] = table[s + 2];
  }
}
