// The variable-diameter continuum robot's panel (robot kind mbcr_vd, Abah 2022, ch. 2): a live plot of the
// robot's diameter and of its backbones' actuation forces, the reference circle's start and stop, and the
// choice between a variable diameter (gradient projection lowers the forces) and a fixed one (the
// the dissertation's baseline). The values are the robot's operating_state "mbcr" fields as the /{robot}/actuation
// topic carries them (20 Hz, over the console's WebSocket); while that stream is silent (no WebSocket,
// a proxy that drops it) the panel reads GET operating_state every 100 ms instead.
import {TimePlot} from './plot.js';

const POLL_MS = 100;
const STREAM_SILENT_MS = 500;  // no topic message for this long: poll REST
// One colour per segment; its four backbones share it (backbones 3 and 4 mirror 1 and 2).
const SEGMENT_COLORS = ['#4ea1ff', '#f0883e', '#3fb950'];

function el(tag, attrs = {}, text = '') {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text) e.textContent = text;
  return e;
}

export class MbcrPanel {
  // container: the tab panel; api: the console's Api; status(text, kind): the console's status line.
  constructor(container, api, {status}) {
    this.container = container;
    this.api = api;
    this.status = status;
    this.robot = null;
    this.timer = null;
    this.t0 = performance.now();
    this.commandable = true;
    this.build();
  }

  build() {
    const c = this.container;
    c.replaceChildren();
    const readouts = el('div', {class: 'mbcr-readouts', 'data-testid': 'mbcr-readouts', role: 'status'});
    this.values = {};
    for (const [key, label] of [['diameter', 'outer diameter'], ['radius', 'inner radius a'], ['force', '‖τ‖'],
      ['rms', 'RMS ‖τ‖ this run'], ['margin', 'interference margin'], ['limits', 'limits'], ['motion', 'motion'],
      ['last', 'last circles (RMS)']]) {
      const item = el('div', {class: 'config-item'});
      item.append(el('span', {class: 'readout-label'}, label));
      const v = el('span', {class: 'config-value', 'data-testid': `mbcr-${key}`}, '—');
      item.append(v);
      this.values[key] = v;
      readouts.append(item);
    }
    const controls = el('div', {class: 'mbcr-controls', role: 'group', 'aria-label': 'Reference circle'});
    const choice = el('fieldset', {class: 'mbcr-choice'});
    choice.append(el('legend', {}, 'diameter'));
    for (const value of ['variable', 'fixed']) {
      const label = el('label');
      const input = el('input', {type: 'radio', name: 'mbcr-diameter', value, 'data-testid': `mbcr-diameter-${value}`});
      if (value === 'variable') input.checked = true;
      label.append(input, ` ${value}`);
      choice.append(label);
    }
    this.start = el('button', {type: 'button', class: 'btn btn-go', 'data-testid': 'mbcr-start',
      'aria-label': 'Run the reference circle of Abah 2022 (switches to task mode)'}, 'Run circle');
    this.stop = el('button', {type: 'button', class: 'btn', 'data-testid': 'mbcr-stop'}, 'Stop');
    controls.append(choice, this.start, this.stop);
    const plots = el('div', {class: 'mbcr-plots'});
    const diameterBox = el('div', {class: 'plot-box'});
    const diameterCanvas = el('canvas', {'data-testid': 'mbcr-diameter-plot', role: 'img',
      'aria-label': 'Diameter over time (mm)'});
    diameterBox.append(diameterCanvas);
    const forceBox = el('div', {class: 'plot-box'});
    const forceCanvas = el('canvas', {'data-testid': 'mbcr-force-plot', role: 'img',
      'aria-label': 'Backbone actuation forces over time (N)'});
    forceBox.append(forceCanvas);
    plots.append(el('h3', {}, 'Diameter joint a (mm)'), diameterBox, el('h3', {}, 'Actuation forces (N)'), forceBox);
    c.append(el('h3', {}, 'Variable diameter'), readouts, controls, plots);

    const fmt = (d) => (v) => v.toFixed(d);
    this.diameterPlot = new TimePlot(diameterCanvas, {
      // a, the diameter joint, against its limits (as the dissertation's Fig. 2.12); the outer diameter is a
      // readout (it follows a, and on one axis with it would flatten a's history).
      series: [{label: 'a', color: '#4ea1ff', format: fmt(2)},
        {label: 'upper limit (joint, interference)', color: '#f85149', dash: true, format: fmt(1)},
        {label: 'a_min', color: '#8b98a8', dash: true}],
      windowS: 30, minSpan: 1,
    });
    const forceSeries = [{label: '‖τ‖', color: '#e6edf3', format: fmt(0)}];
    for (let i = 0; i < 12; ++i) {
      const segment = Math.floor(i / 4);
      forceSeries.push({label: i % 4 === 0 ? `segment ${segment + 1}` : undefined, color: SEGMENT_COLORS[segment], width: 1});
    }
    this.forcePlot = new TimePlot(forceCanvas, {series: forceSeries, windowS: 30, minSpan: 10});

    this.start.addEventListener('click', () => this.run());
    this.stop.addEventListener('click', () => this.halt());
  }

  diameterChoice() {
    return this.container.querySelector('input[name="mbcr-diameter"]:checked')?.value || 'variable';
  }

  setRobot(robot) {
    const changed = this.robot?.name !== robot?.name;
    this.robot = robot;
    if (changed) {
      this.lastStream = undefined;
      this.diameterPlot.clear();
      this.forcePlot.clear();
    }
    clearInterval(this.timer);
    this.timer = robot ? setInterval(() => this.poll(), POLL_MS) : null;
  }

  setCommandable(yes) {
    this.commandable = yes;
    this.start.disabled = !yes;
    this.stop.disabled = !yes;
  }

  path(leaf) { return `/robots/${encodeURIComponent(this.robot.name)}/${leaf}`; }

  async run() {
    if (!this.robot) return;
    const diameter = this.diameterChoice();
    try {
      const state = await this.api.operatingState(this.robot.name);
      if (state.state !== 'ENABLED') throw new Error('enable the robot first');
      if (state.mode !== 'task') await this.api.setMode(this.robot.name, 'task');
      // The mode switch reaches the control thread within a tick or two; the command checks the mode.
      for (let i = 0; i < 20 && (await this.api.operatingState(this.robot.name)).mode !== 'task'; ++i) {
        await new Promise((r) => setTimeout(r, 50));
      }
      const answer = await this.api.post(this.path('trajectory'), {action: 'start', name: 'seed_circle', diameter});
      this.status(`Circle, ${diameter} diameter: ${answer.approach_s.toFixed(1)} s to its start, then ` +
        `${(answer.duration_s - answer.approach_s).toFixed(0)} s around`, 'ok');
    } catch (err) {
      this.status(`Circle not started: ${err.message}`, 'error');
    }
  }

  async halt() {
    if (!this.robot) return;
    try {
      await this.api.post(this.path('trajectory'), {action: 'stop'});
      this.status('Circle stopped', 'ok');
    } catch (err) {
      this.status(`Stop refused: ${err.message}`, 'error');
    }
  }

  // A /{robot}/actuation message (the robot's whole operating state).
  onMessage(msg) {
    if (!this.robot || !msg?.mbcr) return;
    this.lastStream = performance.now();
    this.container.dataset.source = 'stream';
    this.show(msg.mbcr);
  }

  async poll() {
    if (!this.robot || this.polling) return;
    if (performance.now() - (this.lastStream ?? -Infinity) < STREAM_SILENT_MS) return;
    this.container.dataset.source = 'rest';
    this.polling = true;
    try {
      const state = await this.api.operatingState(this.robot.name);
      this.show(state.mbcr);
    } catch {
      // the console's connection indicator reports an unreachable server
    } finally {
      this.polling = false;
    }
  }

  show(m) {
    if (!m || !m.actuation) return;
    const a = m.actuation;
    const t = (performance.now() - this.t0) / 1000;
    this.diameterPlot.push(0, t, a.inner_radius_mm);
    this.diameterPlot.push(1, t, a.inner_radius_limits_mm[1]);
    this.diameterPlot.push(2, t, a.inner_radius_limits_mm[0]);
    this.forcePlot.push(0, t, a.force_norm_n);
    a.backbone_forces_n.forEach((f, i) => this.forcePlot.push(i + 1, t, f));
    const v = this.values;
    v.diameter.textContent = `${a.diameter_mm.toFixed(1)} mm`;
    v.radius.textContent = `${a.inner_radius_mm.toFixed(2)} mm (${a.inner_radius_limits_mm[0].toFixed(1)}–${a.inner_radius_limits_mm[1].toFixed(1)})`;
    v.force.textContent = `${a.force_norm_n.toFixed(1)} N`;
    v.rms.textContent = a.rms_force_n === null ? '—' : `${a.rms_force_n.toFixed(1)} N`;
    v.margin.textContent = a.interference_margin === null ? 'straight' : `${a.interference_margin.toFixed(1)} mm`;
    v.limits.textContent = a.limits_active.length ? a.limits_active.join(', ').replace(/_/g, ' ') : 'none';
    v.motion.textContent = m.trajectory ? `${m.trajectory.phase} (${m.trajectory.diameter})` : `${m.motion} (${m.diameter})`;
    const c = a.circle;
    const r = (x) => (x === null ? '—' : `${x.toFixed(1)} N`);
    v.last.textContent = `variable ${r(c.last_rms_variable_n)}, fixed ${r(c.last_rms_fixed_n)}`;
    this.container.dataset.samples = String(c.samples);
  }
}
