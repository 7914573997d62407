// topology.js - which triangles and lines of the cloth are drawn, from the grid size and the torn
// springs (PROTOCOL.md, "hello"). No three.js here: node's tests import it as it is.
//
// Spring ids are type * n + v, v = j nx + i the spring's lower-index end. Types: 0 structural +x,
// 1 structural +y, 2 shear +x+y, 3 shear -x+y, 4 bend +2x, 5 bend +2y.
//
// Each grid quad (i, j) .. (i+1, j+1) is split on its +x+y diagonal into two triangles:
//   A = (v00, v10, v11), edges structural +x of v00, structural +y of v10, shear +x+y of v00;
//   B = (v00, v11, v01), edges shear +x+y of v00, structural +x of v01, structural +y of v00.
// A triangle is drawn while its three springs are intact.

export const SPRING_TYPES = 6;
export const STRUCT_X = 0, STRUCT_Y = 1, SHEAR_PP = 2, SHEAR_MP = 3, BEND_X = 4, BEND_Y = 5;

/** The springs' two ends, or null where the grid has no such spring. */
export function springEnds(id, nx, ny) {
  const n = nx * ny;
  const type = Math.floor(id / n), v = id - type * n;
  const i = v % nx, j = Math.floor(v / nx);
  const d = [[1, 0], [0, 1], [1, 1], [-1, 1], [2, 0], [0, 2]][type];
  if (!d) return null;
  const i2 = i + d[0], j2 = j + d[1];
  if (i2 < 0 || i2 >= nx || j2 >= ny) return null;
  return [v, j2 * nx + i2];
}

/**
 * Triangle indices of the intact cloth.
 * @param {number} nx @param {number} ny @param {Set<number>} torn spring ids
 * @param {Uint32Array} [into] reused when large enough
 * @returns {Uint32Array} 3 indices per triangle (a subarray of `into` when given)
 */
export function triangleIndices(nx, ny, torn, into) {
  const n = nx * ny;
  const out = into && into.length >= 6 * (nx - 1) * (ny - 1) ? into : new Uint32Array(6 * (nx - 1) * (ny - 1));
  const intact = (type, v) => torn.size === 0 || !torn.has(type * n + v);
  let k = 0;
  for (let j = 0; j + 1 < ny; j++) {
    for (let i = 0; i + 1 < nx; i++) {
      const v00 = j * nx + i, v10 = v00 + 1, v01 = v00 + nx, v11 = v01 + 1;
      const diagonal = intact(SHEAR_PP, v00);
      if (diagonal && intact(STRUCT_X, v00) && intact(STRUCT_Y, v10)) {
        out[k++] = v00; out[k++] = v10; out[k++] = v11;
      }
      if (diagonal && intact(STRUCT_X, v01) && intact(STRUCT_Y, v00)) {
        out[k++] = v00; out[k++] = v11; out[k++] = v01;
      }
    }
  }
  return out.subarray(0, k);
}

/**
 * Line-segment indices of the intact structural and shear springs (bend springs are not drawn:
 * they would cover the others).
 */
export function springIndices(nx, ny, torn) {
  const n = nx * ny;
  const out = [];
  for (let type = STRUCT_X; type <= SHEAR_MP; type++) {
    for (let v = 0; v < n; v++) {
      const id = type * n + v;
      if (torn.has(id)) continue;
      const ends = springEnds(id, nx, ny);
      if (ends) out.push(ends[0], ends[1]);
    }
  }
  return Uint32Array.from(out);
}

/**
 * Per-vertex normals of an indexed triangle list, each the normalised sum of its triangles'
 * area-weighted normals (what three's computeVertexNormals gives, in one tight loop over typed
 * arrays: a 128 x 128 cloth takes a fraction of the time).
 * @param {Float32Array} p positions, 3 per vertex @param {Uint32Array} index 3 per triangle
 * @param {Float32Array} out normals, 3 per vertex (overwritten); a vertex of no triangle gets +z
 */
export function vertexNormals(p, index, out) {
  out.fill(0);
  for (let t = 0; t < index.length; t += 3) {
    const a = 3 * index[t], b = 3 * index[t + 1], c = 3 * index[t + 2];
    const ux = p[b] - p[a], uy = p[b + 1] - p[a + 1], uz = p[b + 2] - p[a + 2];
    const vx = p[c] - p[a], vy = p[c + 1] - p[a + 1], vz = p[c + 2] - p[a + 2];
    const nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
    out[a] += nx; out[a + 1] += ny; out[a + 2] += nz;
    out[b] += nx; out[b + 1] += ny; out[b + 2] += nz;
    out[c] += nx; out[c + 1] += ny; out[c + 2] += nz;
  }
  for (let k = 0; k < out.length; k += 3) {
    const len = Math.sqrt(out[k] * out[k] + out[k + 1] * out[k + 1] + out[k + 2] * out[k + 2]);
    if (len > 0) { out[k] /= len; out[k + 1] /= len; out[k + 2] /= len; } else out[k + 2] = 1;
  }
}

/**
 * Vertex v's structural springs' relative extensions (|d| - L0) / L0, L0 the grid spacing (hx
 * along i, hy along j), those in `torn` (spring ids) left out: with `mean` false the largest of
 * them and 0 (PROTOCOL.md's `strain` scalar; the vertex probe), with `mean` true their mean,
 * signed (below 0 compressed; the stretch colouring). 0 for a vertex with none.
 * @param {Float32Array|number[]} p positions, 3 per vertex
 */
export function structuralStrain(p, nx, ny, hx, hy, v, mean = false, torn = null) {
  const n = nx * ny, i = v % nx, j = (v - i) / nx;
  let sum = 0, count = 0, max = 0;
  for (let s = 0; s < 4; s++) {
    // +x, -x, +y, -y: the neighbour, and the spring's id (its lower-index end's)
    const w = s === 0 ? (i + 1 < nx ? v + 1 : -1) : s === 1 ? (i > 0 ? v - 1 : -1)
      : s === 2 ? (j + 1 < ny ? v + nx : -1) : (j > 0 ? v - nx : -1);
    if (w < 0) continue;
    if (torn?.size && torn.has((s < 2 ? STRUCT_X : STRUCT_Y) * n + Math.min(v, w))) continue;
    const l0 = s < 2 ? hx : hy;
    const e = (Math.hypot(p[3 * w] - p[3 * v], p[3 * w + 1] - p[3 * v + 1], p[3 * w + 2] - p[3 * v + 2]) - l0) / l0;
    sum += e; count++;
    if (e > max) max = e;
  }
  return mean ? (count ? sum / count : 0) : max;
}

/**
 * structuralStrain's mean for every vertex into out (one float each).
 * @param {Float32Array} p @param {Float32Array} out @param {Set<number>} [torn]
 */
export function stretchField(p, nx, ny, hx, hy, out, torn = null) {
  for (let v = 0; v < nx * ny; v++) out[v] = structuralStrain(p, nx, ny, hx, hy, v, true, torn);
  return out;
}
