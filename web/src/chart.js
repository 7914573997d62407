// chart.js - a live uPlot chart of the energies of GET /v1/sim (kinetic, spring, gravity, total;
// J) over simulated time, and the speed of the selected rock (m/s, right axis).
import uPlot from 'uplot';

const WINDOW = 240; // points kept (a minute at 4 samples a second)

export class EnergyChart {
  constructor(container) {
    this.container = container;
    this.data = [[], [], [], [], [], []];
    const line = (label, stroke, scale = 'J') => ({ label, stroke, width: 1.5, scale, points: { show: false }, value: (u, v) => (v == null ? '-' : v.toPrecision(4)) });
    this.plot = new uPlot({
      width: container.clientWidth || 420, height: 170,
      legend: { live: false },
      cursor: { show: false },
      scales: { x: { time: false }, J: { auto: true }, 'm/s': { auto: true } },
      axes: [
        { stroke: '#aab', grid: { stroke: '#2c313c' }, label: 'sim time (s)', labelSize: 14, size: 30 },
        { stroke: '#aab', grid: { stroke: '#2c313c' }, scale: 'J', label: 'J', labelSize: 14, size: 50 },
        { stroke: '#e5c07b', grid: { show: false }, scale: 'm/s', side: 1, label: 'rock m/s', labelSize: 14, size: 45 },
      ],
      series: [
        { label: 't' },
        line('kinetic', '#e06c75'), line('spring', '#61afef'), line('gravity', '#98c379'),
        line('total', '#dcdfe4'), line('rock speed', '#e5c07b', 'm/s'),
      ],
    }, this.data, container);
    new ResizeObserver(() => this.plot.setSize({ width: container.clientWidth || 420, height: 170 })).observe(container);
  }

  /** One sample: the sim's time and energies, and the selected rock's speed (or null). */
  push(simTime, energy, rockSpeed) {
    const last = this.data[0].length ? this.data[0][this.data[0].length - 1] : -Infinity;
    if (simTime < last) this.clear(); // a reset or a new scene: start over
    else if (simTime === last) return;
    const values = [simTime, energy.kinetic, energy.spring, energy.gravity, energy.total, rockSpeed];
    values.forEach((x, k) => this.data[k].push(x));
    if (this.data[0].length > WINDOW) for (const d of this.data) d.splice(0, d.length - WINDOW);
    if (this.container.offsetParent !== null) this.plot.setData(this.data);
  }

  clear() {
    for (const d of this.data) d.length = 0;
    this.plot.setData(this.data);
  }
}
