// view.js - the three.js scene: the cloth (lit surface, springs and points coloured by speed, a
// strain heat map from the stream's scalar, or its stretch computed here from the positions), the
// rocks (marked spheres; kinematic ones in wireframe), the ground, an orbit camera and a 2D
// orthographic one. It draws only when something changed (a frame, the camera),
// and a frame is written into the GPU buffers in place: the stream decodes straight into the
// position attribute's array.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { triangleIndices, springIndices, vertexNormals, stretchField } from './topology.js';
import { lut, applyLut, speedRgb, heatRgb, stretchRgb, applyStretch } from './colors.js';

export const MODES = { surface: 'none', springs: 'speed', strain: 'strain', stretch: 'none' }; // mode -> scalar it needs
const SPEED_LUT = lut(speedRgb), HEAT_LUT = lut(heatRgb), STRETCH_LUT = lut((t) => stretchRgb(2 * t - 1));
/** The modes that colour the surface per vertex. */
const COLOURED = new Set(['strain', 'stretch']);

/** The rock sphere, with a beach-ball marking (alternate octants) so its spin shows. */
function rockGeometry() {
  const g = new THREE.SphereGeometry(1, 32, 16);
  const p = g.attributes.position;
  const rgb = new Float32Array(3 * p.count);
  const a = new THREE.Color(0xd9a441), b = new THREE.Color(0x3b4b8c);
  for (let k = 0; k < p.count; k++) {
    const c = p.getX(k) * p.getY(k) * p.getZ(k) >= 0 ? a : b;
    rgb.set([c.r, c.g, c.b], 3 * k);
  }
  g.setAttribute('color', new THREE.BufferAttribute(rgb, 3));
  return g;
}

/**
 * The cloth's two-sided surface, lit per vertex (a hemisphere sky and one sun, as the rocks' lights)
 * with the normals of each frame: per-fragment lighting of 32 000 small triangles costs a software
 * renderer a third of its frame rate (headless Chromium: 21 -> 29 frames/s for a bare 128 x 128
 * cloth), and per-vertex lighting looks the same at this density. vertexColors: the strain map's
 * colours instead of the cloth's own.
 */
function clothMaterial(vertexColors) {
  return new THREE.ShaderMaterial({
    side: THREE.DoubleSide,
    defines: vertexColors ? { USE_STRAIN: 1 } : {},
    uniforms: { base: { value: new THREE.Color(0xc8553d) }, sun: { value: new THREE.Vector3(4, -2, 3).normalize() } },
    vertexShader: `
      uniform vec3 base;
      uniform vec3 sun;
      varying vec3 vFront;
      varying vec3 vBack;
      #ifdef USE_STRAIN
      attribute vec3 color;
      #endif
      vec3 lit(vec3 n, vec3 c) {
        vec3 sky = mix(vec3(0.12, 0.11, 0.1), vec3(0.38, 0.42, 0.5), 0.5 + 0.5 * n.z);
        return c * (sky + 1.1 * max(dot(n, sun), 0.0));
      }
      void main() {
        #ifdef USE_STRAIN
        vec3 c = color;
        #else
        vec3 c = base;
        #endif
        vFront = lit(normal, c);
        vBack = lit(-normal, c);
        gl_Position = projectionMatrix * modelViewMatrix * vec4(position, 1.0);
      }`,
    fragmentShader: `
      varying vec3 vFront;
      varying vec3 vBack;
      void main() {
        gl_FragColor = vec4(gl_FrontFacing ? vFront : vBack, 1.0);
        #include <colorspace_fragment>
      }`,
  });
}

/** Whether WebGL runs on the CPU (SwiftShader, llvmpipe): no GPU, every pixel costs. */
function isSoftwareWebGL() {
  const gl = document.createElement('canvas').getContext('webgl2');
  if (!gl) return true;
  const info = gl.getExtension('WEBGL_debug_renderer_info');
  const name = info ? gl.getParameter(info.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER);
  gl.getExtension('WEBGL_lose_context')?.loseContext();
  return /swiftshader|llvmpipe|software/i.test(String(name));
}

export class View {
  constructor(container) {
    this.container = container;
    this.software = isSoftwareWebGL();
    // Multisampling doubles a software renderer's cost (SwiftShader, a browser without a GPU).
    this.renderer = new THREE.WebGLRenderer({ antialias: !this.software, powerPreference: 'high-performance' });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    // The background follows the page's theme (prefers-color-scheme, as style.css).
    this.lightTheme = matchMedia('(prefers-color-scheme: light)');
    const background = () => {
      this.background = this.lightTheme.matches ? 0xe9ecf1 : 0x1b1f27;
      this.renderer.setClearColor(this.background);
      this.dirty = true;
    };
    background();
    this.lightTheme.addEventListener('change', background);
    container.appendChild(this.renderer.domElement);

    this.scene = new THREE.Scene();
    this.scene.add(new THREE.HemisphereLight(0xdfe8ff, 0x302820, 1.4));
    // The sun, from (4, -2, 3) as the cloth shader's; with shadows on it casts the rocks' shadows
    // on the cloth (three.js shadow map; frameScene fits its camera to the cloth).
    this.sun = new THREE.DirectionalLight(0xffffff, 2.0);
    this.sun.position.set(4, -2, 3);
    this.sun.shadow.mapSize.set(1024, 1024);
    this.sun.shadow.bias = -0.0005;
    this.sun.shadow.normalBias = 0.01;
    this.scene.add(this.sun, this.sun.target);
    this.renderer.shadowMap.type = THREE.PCFShadowMap;
    this.shadows = false;

    THREE.Object3D.DEFAULT_UP.set(0, 0, 1); // z up, as the simulation
    this.perspective = new THREE.PerspectiveCamera(45, 1, 0.01, 500);
    this.perspective.up.set(0, 0, 1);
    this.ortho = new THREE.OrthographicCamera(-1, 1, 1, -1, -100, 100);
    this.ortho.up.set(0, 0, 1);
    this.orbit = new OrbitControls(this.perspective, this.renderer.domElement);
    this.pan2d = new OrbitControls(this.ortho, this.renderer.domElement);
    this.pan2d.enableRotate = false;
    this.pan2d.screenSpacePanning = true;
    for (const c of [this.orbit, this.pan2d]) c.addEventListener('change', () => (this.dirty = true));
    this.camera2d = false;
    this.setCamera2d(false);

    // Ground: a grid 5 cloth sizes wide (frameScene scales it) at ground_z while `ground` is on.
    // Lines, not a filled plane: filling the screen with a plane halves the frame rate of a
    // software renderer (measured in headless Chromium: 48 -> 22 frames/s).
    this.ground = new THREE.GridHelper(1, 20, 0x7d8a74, 0x4d5548);
    this.ground.rotation.x = Math.PI / 2;
    this.scene.add(this.ground);

    // Cloth: one position and one colour attribute shared by the surface, the lines and the points.
    this.surfaceMaterial = clothMaterial(false);
    this.strainMaterial = clothMaterial(true);
    // With shadows on, three.js's own Lambert materials (per-fragment, shadow-receiving) instead,
    // their colour raised 1.7 times to the brightness of the per-vertex shader under the same
    // lights (three.js's Lambert takes 1/pi of the sun's light).
    this.shadowSurfaceMaterial = new THREE.MeshLambertMaterial({ color: new THREE.Color(0xc8553d).multiplyScalar(1.7), side: THREE.DoubleSide });
    this.shadowStrainMaterial = new THREE.MeshLambertMaterial({ color: new THREE.Color(1.7, 1.7, 1.7), vertexColors: true, side: THREE.DoubleSide });
    this.cloth = null;
    this.mode = 'surface';
    this.stretchRange = 0.05; // the stretch colouring's full blue / red, as a relative extension

    this.rockGeometry = rockGeometry();
    this.rockMaterial = new THREE.MeshLambertMaterial({ vertexColors: true });
    this.kinematicMaterial = new THREE.MeshBasicMaterial({ vertexColors: true, wireframe: true });
    this.selectMaterial = new THREE.MeshBasicMaterial({ color: 0xffee55, side: THREE.BackSide });
    this.rocks = new Map(); // id -> {mesh, seen}
    this.rockInfo = new Map(); // id -> {kinematic} from the hello and the events
    this.selected = null;

    this.dirty = true;
    this.drawn = 0;
    this.resize();
    new ResizeObserver(() => this.resize()).observe(container);
  }

  resize() {
    const w = Math.max(1, this.container.clientWidth), h = Math.max(1, this.container.clientHeight);
    this.renderer.setSize(w, h, false);
    this.renderer.domElement.style.width = '100%';
    this.renderer.domElement.style.height = '100%';
    this.perspective.aspect = w / h;
    this.perspective.updateProjectionMatrix();
    this.fitOrtho();
    this.dirty = true;
  }

  get camera() { return this.camera2d ? this.ortho : this.perspective; }
  get controls() { return this.camera2d ? this.pan2d : this.orbit; }

  setCamera2d(on) {
    this.camera2d = on;
    this.orbit.enabled = !on;
    this.pan2d.enabled = on;
    this.dirty = true;
  }

  /** Places both cameras to see the whole cloth of a scene (GET /v1/scene). */
  frameScene(scene) {
    this.sceneInfo = scene;
    const s = Math.max(scene.size_x, scene.size_y);
    const vertical = scene.orientation === 'vertical';
    const c = new THREE.Vector3(0, 0, vertical ? scene.height : scene.height * 0.6);
    this.orbit.target.copy(c);
    this.perspective.position.set(c.x + 0.9 * s, c.y - 1.5 * s, c.z + (vertical ? 0.3 : 0.9) * s);
    this.orbit.update();
    // 2D: look at the cloth's plane (along +y for a curtain in xz, down -z for a horizontal one).
    this.pan2d.target.copy(c);
    if (vertical) this.ortho.position.set(c.x, c.y - 10, c.z);
    else this.ortho.position.set(c.x, c.y - 1e-3, c.z + 10);
    this.orthoSpan = 0.65 * s;
    this.ground.scale.setScalar(5 * s);
    // The sun's shadow camera: a box around the cloth and what falls on it.
    this.sun.target.position.copy(c);
    this.sun.position.copy(c).addScaledVector(new THREE.Vector3(4, -2, 3).normalize(), 3 * s);
    Object.assign(this.sun.shadow.camera, { left: -s, right: s, top: s, bottom: -s, near: 0.01, far: 6 * s });
    this.sun.shadow.camera.updateProjectionMatrix();
    this.ortho.zoom = 1;
    this.pan2d.update();
    this.fitOrtho();
    this.dirty = true;
  }

  fitOrtho() {
    const span = this.orthoSpan ?? 1.3;
    const aspect = this.perspective.aspect;
    Object.assign(this.ortho, { left: -span * aspect, right: span * aspect, top: span, bottom: -span });
    this.ortho.updateProjectionMatrix();
  }

  /** Builds the cloth of nx x ny vertices with the torn springs (a Set of ids) left out. */
  buildCloth(nx, ny, torn) {
    this.disposeCloth();
    const n = nx * ny;
    const geometry = new THREE.BufferGeometry();
    const position = new THREE.BufferAttribute(new Float32Array(3 * n), 3).setUsage(THREE.DynamicDrawUsage);
    const color = new THREE.BufferAttribute(new Uint8Array(3 * n).fill(160), 3, true).setUsage(THREE.DynamicDrawUsage);
    geometry.setAttribute('position', position);
    const normal = new THREE.BufferAttribute(new Float32Array(3 * n), 3).setUsage(THREE.DynamicDrawUsage);
    geometry.setAttribute('normal', normal);
    geometry.setAttribute('color', color);
    geometry.boundingSphere = new THREE.Sphere();
    const lines = new THREE.BufferGeometry();
    lines.setAttribute('position', position);
    lines.setAttribute('color', color);
    lines.boundingSphere = geometry.boundingSphere;
    const mesh = new THREE.Mesh(geometry, this.surfaceMaterial);
    const springs = new THREE.LineSegments(lines, new THREE.LineBasicMaterial({ vertexColors: true, transparent: true, opacity: 0.7 }));
    const points = new THREE.Points(lines, new THREE.PointsMaterial({ vertexColors: true, size: 4, sizeAttenuation: false }));
    for (const o of [mesh, springs, points]) o.frustumCulled = false;
    this.scene.add(mesh, springs, points);
    this.cloth = { nx, ny, n, geometry, lines, mesh, springs, points, position, normal, color, scalar: new Uint8Array(n),
      stretch: new Float32Array(n), torn: new Set(), hasFrame: false };
    this.setTorn(torn);
    this.setMode(this.mode);
  }

  disposeCloth() {
    if (!this.cloth) return;
    const { mesh, springs, points, geometry, lines } = this.cloth;
    this.scene.remove(mesh, springs, points);
    geometry.dispose(); lines.dispose();
    springs.material.dispose(); points.material.dispose();
    this.cloth = null;
  }

  /** Rebuilds the indices after springs tore (or a reset mended them). */
  setTorn(torn) {
    const c = this.cloth;
    if (!c) return;
    c.torn = torn;
    c.index = triangleIndices(c.nx, c.ny, torn).slice();
    c.geometry.setIndex(new THREE.BufferAttribute(c.index, 1));
    c.lines.setIndex(new THREE.BufferAttribute(springIndices(c.nx, c.ny, torn), 1));
    this.dirty = true;
  }

  setMode(mode) {
    this.mode = mode;
    const c = this.cloth;
    if (!c) return;
    c.mesh.visible = mode !== 'springs';
    c.mesh.material = this.shadows
      ? (COLOURED.has(mode) ? this.shadowStrainMaterial : this.shadowSurfaceMaterial)
      : (COLOURED.has(mode) ? this.strainMaterial : this.surfaceMaterial);
    c.mesh.receiveShadow = this.shadows;
    c.springs.visible = c.points.visible = mode === 'springs';
    if (mode === 'stretch' && c.hasFrame) this.colourStretch();
    this.dirty = true;
  }

  /** The stretch colouring's range: a relative extension of +range is full red, -range full blue. */
  setStretchRange(range) {
    if (!(range > 0)) return;
    this.stretchRange = range;
    if (this.mode === 'stretch' && this.cloth?.hasFrame) this.colourStretch();
    this.dirty = true;
  }

  /**
   * Colours the cloth by its stretch: each vertex's mean relative extension of its intact
   * structural springs against the grid spacing (topology.js structuralStrain, the probe's
   * function), from the positions shown.
   */
  colourStretch() {
    const c = this.cloth, sc = this.sceneInfo;
    if (!c || !sc || sc.nx !== c.nx || sc.ny !== c.ny) return;
    stretchField(c.position.array, c.nx, c.ny, sc.size_x / (c.nx - 1), sc.size_y / (c.ny - 1), c.stretch, c.torn);
    applyStretch(STRETCH_LUT, c.stretch, this.stretchRange, c.color.array, c.n);
    c.color.needsUpdate = true;
  }

  /** The arrays the next frame may decode into (PROTOCOL.md frames, proto/frame.mjs). */
  frameTargets() {
    return this.cloth ? { positions: this.cloth.position.array, scalar: this.cloth.scalar } : {};
  }

  /** Shows one decoded frame; false when it does not fit the cloth (a new scene is on its way). */
  showFrame(f) {
    const c = this.cloth;
    if (!c || f.nVertices !== c.n) return false;
    if (f.positions.buffer !== c.position.array.buffer) c.position.array.set(f.positions);
    c.position.needsUpdate = true;
    if (this.mode === 'stretch') this.colourStretch();
    else if (f.scalar && this.mode !== 'surface') {
      applyLut(this.mode === 'strain' ? HEAT_LUT : SPEED_LUT, f.scalar, c.color.array, c.n);
      c.color.needsUpdate = true;
    }
    if (c.mesh.visible) {
      vertexNormals(c.position.array, c.index, c.normal.array);
      c.normal.needsUpdate = true;
    }
    const [x0, y0, z0] = f.bboxMin, [x1, y1, z1] = f.bboxMax;
    c.geometry.boundingSphere.center.set((x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2);
    c.geometry.boundingSphere.radius = Math.hypot(x1 - x0, y1 - y0, z1 - z0) / 2 + 1e-6;
    c.hasFrame = true;
    this.lastStep = f.step;
    this.showRocks(f.rocks);
    this.dirty = true;
    return true;
  }

  /** The shortest distance from point p to the cloth's vertices and to the rocks' surfaces. */
  clearance(p) {
    let best = Infinity;
    const c = this.cloth;
    if (c?.hasFrame) {
      const a = c.position.array;
      for (let v = 0; v < c.n; v++) {
        const d = Math.hypot(a[3 * v] - p[0], a[3 * v + 1] - p[1], a[3 * v + 2] - p[2]);
        if (d < best) best = d;
      }
    }
    for (const r of this.rocks.values()) {
      const d = r.mesh.position.distanceTo({ x: p[0], y: p[1], z: p[2] }) - r.radius;
      if (d < best) best = d;
    }
    return best;
  }

  showRocks(rocks) {
    for (const r of this.rocks.values()) r.seen = false;
    for (const r of rocks) {
      let entry = this.rocks.get(r.id);
      const kinematic = !!this.rockInfo.get(r.id)?.kinematic;
      if (!entry) {
        const mesh = new THREE.Mesh(this.rockGeometry, this.rockMaterial);
        mesh.castShadow = true;
        mesh.userData.rockId = r.id;
        entry = { mesh, outline: null };
        this.rocks.set(r.id, entry);
        this.scene.add(mesh);
      }
      const m = entry.mesh;
      m.material = kinematic ? this.kinematicMaterial : this.rockMaterial;
      m.position.fromArray(r.position);
      m.quaternion.fromArray(r.orientation);
      m.scale.setScalar(r.radius);
      entry.seen = true;
      entry.radius = r.radius;
      this.markSelected(entry, r.id === this.selected);
    }
    for (const [id, r] of this.rocks) {
      if (r.seen) continue;
      this.scene.remove(r.mesh);
      this.rocks.delete(id);
    }
  }

  markSelected(entry, on) {
    if (on && !entry.outline) {
      entry.outline = new THREE.Mesh(this.rockGeometry, this.selectMaterial);
      entry.outline.scale.setScalar(1.12);
      entry.mesh.add(entry.outline);
    } else if (!on && entry.outline) {
      entry.mesh.remove(entry.outline);
      entry.outline = null;
    }
  }

  select(id) {
    this.selected = id;
    for (const [rid, r] of this.rocks) this.markSelected(r, rid === id);
    this.dirty = true;
  }

  /** Shadows of the rocks on the cloth (the sun's shadow map), on or off. */
  setShadows(on) {
    this.shadows = !!on;
    this.renderer.shadowMap.enabled = this.shadows;
    this.sun.castShadow = this.shadows;
    for (const m of [this.rockMaterial, this.kinematicMaterial, this.shadowSurfaceMaterial, this.shadowStrainMaterial]) m.needsUpdate = true;
    this.setMode(this.mode);
    this.dirty = true;
  }

  setGround(on, z) {
    this.ground.visible = !!on;
    this.ground.position.z = z ?? 0;
    this.dirty = true;
  }

  /**
   * Camera presets: `fit` (as frameScene places it), `top` (straight down), `front` (along +y),
   * `side` (along -x), each at the fit's distance from the cloth's centre. Switches to the orbit
   * camera.
   */
  preset(name) {
    if (!this.sceneInfo) return;
    this.frameScene(this.sceneInfo);
    if (name !== 'fit') {
      const t = this.orbit.target, d = this.perspective.position.distanceTo(t);
      const dir = { top: [0, -1e-3, 1], front: [0, -1, 0], side: [1, 0, 0] }[name];
      if (!dir) return;
      this.perspective.position.set(t.x + d * dir[0], t.y + d * dir[1], t.z + d * dir[2]);
      this.orbit.update();
    }
    this.setCamera2d(false);
  }

  /** The orbit camera as [x, y, z of the eye, x, y, z of the target]. */
  cameraState() {
    return [...this.perspective.position.toArray(), ...this.orbit.target.toArray()];
  }

  setCameraState(s) {
    if (!Array.isArray(s) || s.length !== 6 || !s.every(Number.isFinite)) return false;
    this.perspective.position.fromArray(s, 0);
    this.orbit.target.fromArray(s, 3);
    this.orbit.update();
    this.dirty = true;
    return true;
  }

  /**
   * A PNG of the view: drawn and read in the same task, so the drawing buffer is still there
   * without preserveDrawingBuffer (which costs a software renderer a copy every frame).
   */
  screenshot() {
    const canvas = this.render();
    return new Promise((resolve, reject) => canvas.toBlob((b) => (b ? resolve(b) : reject(new Error('the canvas gave no PNG'))), 'image/png'));
  }

  /**
   * The cloth vertex nearest to a page point (clientX, clientY) on screen, within `radius` pixels,
   * or -1.
   */
  vertexAt(x, y, radius = 24) {
    const c = this.cloth;
    if (!c?.hasFrame) return -1;
    const r = this.renderer.domElement.getBoundingClientRect();
    const m = new THREE.Matrix4().multiplyMatrices(this.camera.projectionMatrix, this.camera.matrixWorldInverse);
    const e = m.elements, a = c.position.array;
    let best = -1, bestD = radius * radius;
    for (let v = 0; v < c.n; v++) {
      const px = a[3 * v], py = a[3 * v + 1], pz = a[3 * v + 2];
      const w = e[3] * px + e[7] * py + e[11] * pz + e[15];
      if (w <= 0) continue;
      const sx = r.left + ((e[0] * px + e[4] * py + e[8] * pz + e[12]) / w + 1) / 2 * r.width;
      const sy = r.top + (1 - (e[1] * px + e[5] * py + e[9] * pz + e[13]) / w) / 2 * r.height;
      const d = (sx - x) ** 2 + (sy - y) ** 2;
      if (d < bestD) { bestD = d; best = v; }
    }
    return best;
  }

  /** Draws now; answers the canvas, whose drawing lasts until this task ends. */
  render() {
    this.renderer.render(this.scene, this.camera);
    return this.renderer.domElement;
  }

  /** Draws if anything changed; answers whether it drew. */
  draw() {
    if (!this.dirty) return false;
    this.dirty = false;
    this.renderer.render(this.scene, this.camera);
    this.drawn++;
    return true;
  }
}
