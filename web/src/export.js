// export.js - the cloth as files, with three.js's own exporters (examples/jsm/exporters): one
// frame as PLY (binary little-endian: positions and the triangles of the torn topology) or as
// glTF binary (.glb: the cloth with its normals, and the rocks as spheres), and a run of frames
// as one .glb with animation: the cloth mesh holds one morph target per frame and an
// AnimationClip whose weights track turns each frame's target fully on at that frame's sim time
// (what GLTFExporter writes for per-vertex animation). The positions are clothd's own (metres,
// z up); the glTF files put the cloth under a node turned -90 degrees about x, so glTF's y-up
// viewers show it upright while the accessors keep clothd's coordinates as they are.
import * as THREE from 'three';
import { GLTFExporter } from 'three/addons/exporters/GLTFExporter.js';
import { PLYExporter } from 'three/addons/exporters/PLYExporter.js';
import { vertexNormals } from './topology.js';

/** The most frames one animated export holds (each is 12 bytes per vertex, twice: target and accessor). */
export const MAX_ANIMATION_FRAMES = 600;
/** The most bytes of morph targets one animated export holds (a large cloth gets fewer frames). */
export const MAX_ANIMATION_BYTES = 128 * 1024 * 1024;

/** The most frames an animated export of a cloth of `nVertices` holds. */
export function animationCap(nVertices) {
  return Math.max(2, Math.min(MAX_ANIMATION_FRAMES, Math.floor(MAX_ANIMATION_BYTES / (12 * nVertices))));
}

/**
 * Which frames an animated export of `count` consecutive frames takes: every `stride`-th from
 * the first, at most animationCap(nVertices) of them (all of them when they fit).
 */
export function animationStride(count, nVertices) {
  return count <= 1 ? 1 : Math.max(1, Math.ceil((count - 1) / (animationCap(nVertices) - 1)));
}

function clothGeometry(positions, index, normals) {
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.BufferAttribute(Float32Array.from(positions), 3));
  g.setIndex(new THREE.BufferAttribute(Uint32Array.from(index), 1));
  if (normals) {
    const n = new Float32Array(positions.length);
    vertexNormals(positions, index, n);
    g.setAttribute('normal', new THREE.BufferAttribute(n, 3));
  }
  return g;
}

const clothMaterial = () => new THREE.MeshStandardMaterial({ color: 0xc8553d, side: THREE.DoubleSide, roughness: 0.8 });

/** The node every glTF export hangs its meshes on: clothd's z up turned into glTF's y up. */
function zUpRoot() {
  const root = new THREE.Group();
  root.name = 'clothd';
  root.rotation.x = -Math.PI / 2;
  return root;
}

function glb(root, animations = []) {
  return new GLTFExporter().parseAsync(root, { binary: true, animations });
}

/**
 * One frame as PLY (binary little-endian): `element vertex n` with x y z, `element face` of the
 * intact triangles.
 * @param {Float32Array} positions 3 per vertex @param {Uint32Array} index 3 per triangle
 * @returns {ArrayBuffer}
 */
export function framePly(positions, index) {
  const mesh = new THREE.Mesh(clothGeometry(positions, index, false));
  return new PLYExporter().parse(mesh, null, { binary: true, littleEndian: true });
}

/**
 * One frame as glTF binary: the mesh `cloth` (positions, normals, the intact triangles) and a
 * sphere `rock-<id>` per rock.
 * @param {Float32Array} positions @param {Uint32Array} index
 * @param {{id: number, position: number[], radius: number, orientation: number[]}[]} rocks
 * @returns {Promise<ArrayBuffer>}
 */
export function frameGlb(positions, index, rocks = []) {
  const root = zUpRoot();
  const cloth = new THREE.Mesh(clothGeometry(positions, index, true), clothMaterial());
  cloth.name = 'cloth';
  root.add(cloth);
  const sphere = new THREE.SphereGeometry(1, 24, 12), stone = new THREE.MeshStandardMaterial({ color: 0xd9a441 });
  for (const r of rocks) {
    const m = new THREE.Mesh(sphere, stone);
    m.name = `rock-${r.id}`;
    m.position.fromArray(r.position);
    m.quaternion.fromArray(r.orientation);
    m.scale.setScalar(r.radius);
    root.add(m);
  }
  return glb(root);
}

/**
 * Frames as one animated glTF binary: the mesh `cloth` has the first frame's positions, one
 * morph target per frame (named `frame-<ordinal>`), and the clip `clothd` a weights track whose
 * key k, at times[k] - times[0] seconds, is frame k's target at 1 and every other at 0.
 * @param {Float32Array[]} frames positions, 3 per vertex each @param {number[]} times sim seconds
 * @param {Uint32Array} index the triangles (one topology for the whole run)
 * @param {string[]} [names] the morph targets' names
 * @returns {Promise<ArrayBuffer>}
 */
export function animationGlb(frames, times, index, names) {
  const count = frames.length;
  if (count < 1) throw new Error('no frames to export');
  const geometry = clothGeometry(frames[0], index, true);
  geometry.morphAttributes.position = frames.map((p) => new THREE.BufferAttribute(p, 3));
  const root = zUpRoot();
  const cloth = new THREE.Mesh(geometry, clothMaterial());
  cloth.name = 'cloth';
  cloth.updateMorphTargets();
  const targetNames = names ?? frames.map((_, k) => `frame-${k}`);
  cloth.morphTargetDictionary = Object.fromEntries(targetNames.map((name, k) => [name, k]));
  root.add(cloth);
  const t0 = times[0];
  const keyTimes = new Float32Array(count), weights = new Float32Array(count * count);
  for (let k = 0; k < count; k++) {
    keyTimes[k] = times[k] - t0;
    weights[k * count + k] = 1;
  }
  // A clip of one key: glTF wants an animation to last; the one frame is shown from 0 on.
  const track = new THREE.NumberKeyframeTrack('cloth.morphTargetInfluences', keyTimes, weights);
  const clip = new THREE.AnimationClip('clothd', -1, [track]);
  return glb(root, [clip]);
}

/** Hands bytes to the browser as a download (a Blob URL, revoked a while later). */
export function download(bytes, name, type = 'application/octet-stream') {
  const a = document.createElement('a');
  a.href = URL.createObjectURL(new Blob([bytes], { type }));
  a.download = name;
  document.body.appendChild(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(a.href), 30000);
}
