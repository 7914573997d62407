// interact.js - the mouse on the 3D view:
//   click (press and release without moving) on the cloth or the ground: drops a rock there;
//   click on a rock: selects it for the chart (again: unselects);
//   press and drag on the cloth: grabs the nearest vertex and moves it with the mouse through the
//     stream's grab/release messages (no HTTP round trip per move);
//   shift + drag a kinematic rock: moves it (PATCH /v1/rocks/{id}, newest position wins);
//   anything else: the camera's own drag (orbit, pan, zoom).
import * as THREE from 'three';

const CLICK_PIXELS = 4;

export class Interaction {
  /**
   * @param {import('./view.js').View} view
   * @param {{dropRock(point: number[]), selectRock(id), grab(vertex, target), release(),
   *   moveRock(id, position), groundZ(): number|null}} actions
   */
  constructor(view, element, actions) {
    this.view = view;
    this.actions = actions;
    this.ray = new THREE.Raycaster();
    this.ndc = new THREE.Vector2();
    this.press = null;
    // Capture phase on the container: runs before the camera controls' own listener on the canvas,
    // so a drag that grabs the cloth or a rock can switch them off first.
    element.addEventListener('pointerdown', (e) => this.down(e), { capture: true });
    window.addEventListener('pointermove', (e) => this.move(e));
    window.addEventListener('pointerup', (e) => this.up(e));
    window.addEventListener('pointercancel', (e) => this.up(e));
  }

  aim(e) {
    const r = this.view.renderer.domElement.getBoundingClientRect();
    this.ndc.set(((e.clientX - r.left) / r.width) * 2 - 1, -((e.clientY - r.top) / r.height) * 2 + 1);
    this.ray.setFromCamera(this.ndc, this.view.camera);
    return this.ray.ray;
  }

  /** What is under the mouse: {kind: 'rock'|'cloth'|'ground', point, id?, vertex?} or null. */
  pick(e) {
    this.aim(e);
    const v = this.view;
    const targets = [...v.rocks.values()].map((r) => r.mesh);
    if (v.cloth?.hasFrame) targets.push(v.cloth.mesh);
    const hits = this.ray.intersectObjects(targets, false);
    for (const h of hits) {
      if (h.object.userData.rockId !== undefined) return { kind: 'rock', id: h.object.userData.rockId, point: h.point, object: h.object };
      if (h.face) {
        const pos = v.cloth.position;
        let best = -1, bestD = Infinity;
        for (const k of [h.face.a, h.face.b, h.face.c]) {
          const d = h.point.distanceToSquared(new THREE.Vector3().fromBufferAttribute(pos, k));
          if (d < bestD) { bestD = d; best = k; }
        }
        return { kind: 'cloth', vertex: best, point: h.point };
      }
    }
    const z = this.actions.groundZ();
    if (z !== null) {
      const p = new THREE.Vector3();
      if (this.ray.ray.intersectPlane(new THREE.Plane(new THREE.Vector3(0, 0, 1), -z), p)) return { kind: 'ground', point: p };
    }
    return null;
  }

  down(e) {
    if (e.button !== 0) return;
    const hit = this.pick(e);
    this.press = { x: e.clientX, y: e.clientY, hit, dragging: false, shift: e.shiftKey, ray: this.ray.ray.clone() };
    const takes = hit && ((hit.kind === 'cloth' && !e.shiftKey) ||
      (hit.kind === 'rock' && e.shiftKey && this.view.rockInfo.get(hit.id)?.kinematic));
    if (takes) {
      this.view.controls.enabled = false;
      this.press.owned = true;
      // The drag moves in the plane through the grabbed point that faces the camera.
      const normal = new THREE.Vector3();
      this.view.camera.getWorldDirection(normal);
      const anchor = hit.kind === 'rock' ? hit.object.position.clone() : hit.point.clone();
      this.press.plane = new THREE.Plane().setFromNormalAndCoplanarPoint(normal, anchor);
      this.press.offset = hit.kind === 'rock' ? anchor.clone().sub(hit.point) : new THREE.Vector3();
    }
  }

  move(e) {
    const p = this.press;
    if (!p) return;
    if (!p.dragging && Math.hypot(e.clientX - p.x, e.clientY - p.y) > CLICK_PIXELS) p.dragging = true;
    if (!p.dragging || !p.owned) return;
    const ray = this.aim(e);
    const target = new THREE.Vector3();
    if (!ray.intersectPlane(p.plane, target)) return;
    if (p.hit.kind === 'cloth') this.actions.grab(p.hit.vertex, target.toArray());
    else this.actions.moveRock(p.hit.id, target.add(p.offset).toArray());
  }

  up(e) {
    const p = this.press;
    if (!p) return;
    this.press = null;
    if (p.owned) this.view.controls.enabled = true;
    if (p.dragging) {
      if (p.owned && p.hit.kind === 'cloth') this.actions.release();
      return;
    }
    if (e.type === 'pointercancel' || !p.hit) return;
    if (p.hit.kind === 'rock') this.actions.selectRock(p.hit.id);
    else this.actions.dropRock(p.hit.point.toArray(), p.ray.direction.toArray());
  }
}
