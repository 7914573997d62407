// panel.js - the lil-gui control panel. The parameter and scene folders are generated from
// GET /v1/params/schema (schema.js): units, ranges and help come from the table. An edit PATCHes
// at once; a refused value shows the server's problem+json detail next to its control, and the
// control snaps back to the value the server holds.
import GUI from 'lil-gui';
import { controlsFromSchema, valueForControl } from './schema.js';

export class Panel {
  /**
   * @param {HTMLElement} container
   * @param {{patchParams, putScene, refreshParams, actions: object, view: object}} hooks
   *   patchParams(obj) and putScene(obj) answer the server's body or throw a ClothdError (clients/js);
   *   refreshParams() reads the live parameters again (a preset sets some);
   *   actions: {playPause, step, reset, clearRocks, download, upload, screenshot, webm}; view: the View folder's
   *   object (mode, camera, encoding, drop radius and density), with onChange(name, value).
   */
  constructor(container, schema, hooks) {
    this.hooks = hooks;
    this.gui = new GUI({ container, title: 'clothd', width: 320 });
    this.controls = controlsFromSchema(schema);
    this.params = {};         // what the server holds (live)
    this.sceneValues = {};    // what the server holds (scene)
    this.sceneEdit = {};      // the scene panel's values, applied by its button
    this.byName = new Map();  // name -> {control, ctrls: [lil-gui controllers], folder}

    const sim = this.gui.addFolder('Simulation');
    const a = hooks.actions;
    this.simState = { play: () => a.playPause(), step: () => a.step(), reset: () => a.reset(),
      clear: () => a.clearRocks(), download: () => a.download(), upload: () => a.upload(),
      screenshot: () => a.screenshot(), webm: () => a.webm() };
    this.playButton = sim.add(this.simState, 'play').name('Pause');
    sim.add(this.simState, 'step').name('Step one frame');
    sim.add(this.simState, 'reset').name('Reset');
    sim.add(this.simState, 'clear').name('Remove all rocks');
    sim.add(this.simState, 'download').name('Download snapshot');
    sim.add(this.simState, 'upload').name('Upload snapshot…');
    this.screenshotButton = sim.add(this.simState, 'screenshot').name('Screenshot (PNG)');
    this.webmButton = sim.add(this.simState, 'webm').name('Record WebM');

    const v = hooks.view;
    const viewFolder = this.gui.addFolder('View');
    viewFolder.add(v.values, 'mode', { 'lit surface': 'surface', 'springs and points (speed)': 'springs', 'strain heat map': 'strain', 'stretch (blue - white - red)': 'stretch' })
      .name('cloth').onChange((x) => v.onChange('mode', x));
    viewFolder.add(v.values, 'camera', { 'orbit (3D)': 'orbit', '2D orthographic': '2d' }).name('camera')
      .onChange((x) => v.onChange('camera', x));
    viewFolder.add(v.values, 'preset', ['fit', 'top', 'front', 'side']).name('camera preset')
      .onChange((x) => v.onChange('preset', x));
    viewFolder.add(v.values, 'encoding', ['delta', 'q16', 'meshopt', 'f32']).name('frame encoding')
      .onChange((x) => v.onChange('encoding', x));
    viewFolder.add(v.values, 'dropRadius', 0.01, 1, 0.01).name('drop radius (m)');
    viewFolder.add(v.values, 'dropDensity', 10, 10000, 10).name('drop density (kg/m^3)');
    viewFolder.add(v.values, 'stretchRange', 0.5, 50, 0.5).name('stretch range (%)')
      .onChange((x) => v.onChange('stretchRange', x));
    viewFolder.add(v.values, 'shadows').name('shadows of the rocks').onChange((x) => v.onChange('shadows', x));
    viewFolder.add(v.values, 'probe').name('vertex probe (hover)');
    viewFolder.add(v.values, 'chart').name('energy chart').onChange((x) => v.onChange('chart', x));

    const scene = this.gui.addFolder('Scene (rebuilds the cloth)');
    for (const c of this.controls.scene) this.addControl(scene, this.sceneEdit, c, null);
    this.sceneButton = scene.add({ apply: () => this.applyScene() }, 'apply').name('Apply scene');
    // the daemon's named scenes that show self_collision (PUT /v1/scene {"preset"}, MODEL.md)
    this.presetState = { preset: 'towel-on-line', load: () => this.loadPreset() };
    scene.add(this.presetState, 'preset', ['towel-on-line', 'cloth-over-stone', 'sheet-crumple']).name('preset');
    this.presetButton = scene.add(this.presetState, 'load').name('Load preset');
    scene.close();

    const live = this.gui.addFolder('Parameters');
    for (const c of this.controls.live) this.addControl(live, this.params, c, (value) => this.patch(c, value));
  }

  addControl(folder, obj, c, onCommit) {
    obj[c.name] = structuredClone(c.default);
    const entry = { control: c, ctrls: [], folder };
    if (c.widget === 'vector') {
      const sub = folder.addFolder(c.label);
      const vec = [0, 1, 2].map((k) => ({ get v() { return obj[c.name][k]; }, set v(x) { obj[c.name][k] = x; } }));
      ['x', 'y', 'z'].forEach((axis, k) => {
        const ctrl = sub.add(vec[k], 'v').name(axis);
        if (onCommit) ctrl.onFinishChange(() => onCommit(obj[c.name].slice()));
        entry.ctrls.push(ctrl);
      });
      sub.domElement.title = c.help;
      sub.domElement.dataset.param = c.name;
      entry.messageHost = sub.domElement.querySelector('.lil-title') ?? sub.domElement;
      sub.close();
    } else {
      let ctrl;
      if (c.widget === 'select') ctrl = folder.add(obj, c.name, c.choices);
      else if (c.widget === 'slider') ctrl = folder.add(obj, c.name, c.min, c.max, c.step ?? undefined);
      else ctrl = folder.add(obj, c.name);
      if (c.widget === 'number' && c.step) ctrl.step(c.step);
      ctrl.name(c.label);
      ctrl.domElement.title = c.help;
      ctrl.domElement.dataset.param = c.name;
      if (onCommit) ctrl.onFinishChange((value) => onCommit(value));
      entry.ctrls.push(ctrl);
      entry.messageHost = ctrl.domElement;
    }
    this.byName.set(c.name, entry);
  }

  /** Shows (or clears, with null) a message under a control. */
  showMessage(name, text) {
    const entry = this.byName.get(name);
    const host = entry?.messageHost ?? this.gui.domElement;
    let el = host.querySelector(':scope > .refused');
    if (!text) { el?.remove(); return; }
    if (!el) {
      el = document.createElement('div');
      el.className = 'refused';
      host.appendChild(el);
    }
    el.textContent = text;
  }

  async patch(c, raw) {
    const checked = valueForControl(c, raw);
    if (checked.error) {
      this.showMessage(c.name, `${c.name}: ${checked.error}`);
      this.setParams({ [c.name]: this.serverParams?.[c.name] ?? c.default });
      return;
    }
    try {
      const res = await this.hooks.patchParams({ [c.name]: checked.value });
      this.showMessage(c.name, null);
      this.setParams(res.params);
    } catch (e) {
      this.showMessage(e.param && this.byName.has(e.param) ? e.param : c.name, `refused: ${e.message}`);
      this.setParams(this.serverParams ?? {}); // snap back
    }
  }

  /** Loads the chosen preset: its scene, and the live parameters it set. */
  async loadPreset() {
    try {
      const res = await this.hooks.putScene({ preset: this.presetState.preset });
      this.setScene(res);
      await this.hooks.refreshParams?.();
      this.presetButton.name('Load preset');
    } catch (e) {
      this.presetButton.name(`Load preset - refused: ${e.message}`);
    }
  }

  async applyScene() {
    for (const c of this.controls.scene) this.showMessage(c.name, null);
    try {
      const res = await this.hooks.putScene({ ...this.sceneEdit });
      this.setScene(res);
    } catch (e) {
      const name = e.param && this.byName.has(e.param) ? e.param : null;
      if (name) this.showMessage(name, `refused: ${e.message}`);
      this.sceneButton.name(name ? 'Apply scene' : `Apply scene - refused: ${e.message}`);
      this.setScene(this.serverScene ?? {});
    }
  }

  /**
   * The server's live parameters (GET /v1/params, an answer, an event, the hello). A control
   * being typed into keeps what is typed: its edit, when committed, goes to the server as usual.
   */
  setParams(params) {
    this.serverParams = { ...(this.serverParams ?? {}), ...structuredClone(params) };
    for (const [name, value] of Object.entries(params)) {
      if (!(name in this.params)) continue;
      if (this.isEditing(name)) continue;
      this.params[name] = structuredClone(value);
      for (const ctrl of this.byName.get(name).ctrls) ctrl.updateDisplay();
    }
  }

  /** Whether a control of this name has the keyboard focus (is being typed into). */
  isEditing(name) {
    return this.byName.get(name).ctrls.some((ctrl) => ctrl.domElement.contains(document.activeElement));
  }

  /** The server's scene (GET /v1/scene, an event, the hello). */
  setScene(scene) {
    this.serverScene = { ...(this.serverScene ?? {}), ...scene };
    this.sceneButton.name('Apply scene');
    for (const c of this.controls.scene) {
      if (!(c.name in scene) || this.isEditing(c.name)) continue;
      this.sceneEdit[c.name] = scene[c.name];
      for (const ctrl of this.byName.get(c.name).ctrls) ctrl.updateDisplay();
    }
  }

  setWebm(recording) {
    this.webmButton.name(recording ? 'Stop WebM (download)' : 'Record WebM');
  }

  setRunning(running) {
    this.playButton.name(running ? 'Pause' : 'Play');
  }
}
