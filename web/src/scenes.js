// scenes.js - the scene picker: the daemon's scenes (GET /v1/scenes, every two seconds), the one
// shown, a new one made from the shown scene's settings (POST /v1/scenes), and a delete
// (DELETE /v1/scenes/{id}); the overview page is a link away. What to show is main.js's: the
// picker asks it through hooks.show(id), which sets the URL's #scene=.
const REFRESH_MS = 2000;

export class ScenePicker {
  /**
   * @param {HTMLElement} root the picker's element (index.html's #scenes)
   * @param {import('clothd/client').Client} api
   * @param {{current: () => string, show: (id: string) => void,
   *   settings: () => {scene?: object, params?: object}, problem: (text: string) => void}} hooks
   */
  constructor(root, api, hooks) {
    this.root = root;
    this.api = api;
    this.hooks = hooks;
    this.list = [];
    this.select = root.querySelector('#scene-select');
    this.idInput = root.querySelector('#scene-new-id');
    this.select.onchange = () => hooks.show(this.select.value);
    root.querySelector('#scene-new').onclick = () => this.create();
    root.querySelector('#scene-delete').onclick = () => this.remove();
    this.refresh();
    this.timer = setInterval(() => this.refresh(), REFRESH_MS);
  }

  /** Re-reads the list of scenes; a server without scenes hides the picker. */
  async refresh() {
    try {
      const { scenes } = await this.api.scenes();
      this.list = scenes;
      this.root.hidden = false;
      this.render();
    } catch (e) {
      if (e.status === 404) this.root.hidden = true;
    }
  }

  /** @private */
  render() {
    const current = this.hooks.current();
    const ids = this.list.map((s) => s.id);
    if (!ids.includes(current)) ids.push(current); // shown, though gone or not listed yet
    const label = (id) => {
      const s = this.list.find((x) => x.id === id);
      return s ? `${id} (${s.state}, ${s.n_vertices} vertices)` : `${id} (not on this clothd)`;
    };
    // Redrawn when an id or a label changes (the list arriving after the first draw changes the
    // labels of the same ids).
    const labels = ids.map(label), want = JSON.stringify([ids, labels]);
    if (this.select.dataset.ids !== want) {
      this.select.replaceChildren(...ids.map((id, k) => {
        const o = document.createElement('option');
        o.value = id;
        o.textContent = labels[k];
        return o;
      }));
      this.select.dataset.ids = want;
    }
    this.select.value = current;
  }

  /** The scene shown changed (the URL, back/forward). */
  setCurrent() {
    this.render();
  }

  /** A new scene from the shown one's scene fields and live parameters, then shows it. */
  async create() {
    const id = this.idInput.value.trim();
    const spec = { ...this.hooks.settings() };
    if (id) spec.id = id;
    try {
      const made = await this.api.createScene(spec);
      this.idInput.value = '';
      await this.refresh();
      this.hooks.show(made.id);
    } catch (e) {
      this.hooks.problem(`new scene refused: ${e.message}`);
    }
  }

  /** Deletes the shown scene (after asking), then shows the first one left. */
  async remove() {
    const id = this.hooks.current();
    if (!window.confirm(`Delete scene ${id}? Its cloth, rocks and journal go.`)) return;
    try {
      await this.api.deleteScene(id);
    } catch (e) {
      return this.hooks.problem(`delete refused: ${e.message}`);
    }
    await this.refresh();
    const next = this.list.find((s) => s.id !== id);
    if (next) this.hooks.show(next.id);
  }
}
