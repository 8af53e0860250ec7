// Tip tracking tab: the catheter tip as the bi-plane images see it (tendril.TipTracking on
// /imaging/tracking), and the per-plane segmentation editor (/api/v1/imaging/segmentation, roadmaps).
// The switch subscribes /imaging/tracking, off by default: while it is subscribed the server segments
// both planes at every frame (8–10 ms a 512² frame in a sanitized build), so the console does not ask
// for it unless the operator does. Changes to the parameters need the imaged robot's lease; the server
// applies them at the plane's next frame, and the editor shows "applied" once the GET says so.
import {TimePlot} from './plot.js';

export const TRACKING_TOPIC = '/imaging/tracking';
const PLANES = ['ap', 'lateral'];
const PLANE_LABEL = {ap: 'AP', lateral: 'Lateral'};
// The editor's fields, in the order of the form: [key, label, kind, step]. roi.* are nested.
const FIELDS = [
  ['threshold', 'threshold', 'int', 1],
  ['background_subtraction', 'background subtraction', 'bool'],
  ['background_weight', 'background weight', 'num', 0.05],
  ['morphology_px', 'opening (px)', 'int', 1],
  ['canny_low', 'Canny low', 'num', 5],
  ['canny_high', 'Canny high', 'num', 5],
  ['min_blob_px', 'smallest region (px)', 'int', 10],
  ['downsample', 'downsample', 'int', 1],
  ['spline_knot_spacing_px', 'knot spacing (px)', 'num', 1],
  ['vessel_threshold', 'vessel threshold', 'int', 1],
  ['entry', 'entry edge', 'edge'],
  ['roi.x', 'ROI x', 'int', 1],
  ['roi.y', 'ROI y', 'int', 1],
  ['roi.width', 'ROI width (0: to the edge)', 'int', 1],
  ['roi.height', 'ROI height (0: to the edge)', 'int', 1],
];
const EDGES = ['bottom', 'top', 'left', 'right'];
const APPLY_POLLS = 40;  // GETs, 250 ms apart, after a change until the plane applies it (one frame)

const testid = (key) => `seg-${key.replace(/[._]/g, '-')}`;
const getKey = (obj, key) => key.split('.').reduce((o, k) => (o == null ? undefined : o[k]), obj);
const fmt = (v, d = 1) => (Number.isFinite(v) ? v.toFixed(d) : '—');

export class TrackingPanel {
  // root: the tab panel; api: Api; connection(): the FoxgloveConnection (or null); view(): the
  // CatheterView (or null); status(text, kind): the page's command status line.
  constructor(root, {api, connection, view, status}) {
    this.root = root;
    this.api = api;
    this.connection = connection;
    this.view = view;
    this.status = status;
    this.on = false;
    this.last = null;
    this.parameters = {};  // plane -> the server's parameters (the GET)
    this.$ = (id) => root.querySelector(`[data-testid="${id}"]`);
    this.switch = this.$('tracking-switch');
    this.plotPlane = this.$('tracking-plot-plane');
    this.editPlane = this.$('seg-plane');
    this.buildForm();
    this.plot = new TimePlot(this.$('tip-tracking-plot'), {
      windowS: 10, unit: 'px', minSpan: 4,
      series: [
        {label: 'segmented', color: '#e3b341', format: (v) => fmt(v)},
        {label: 'EKF', color: '#ff6ad5', dash: [5, 3], format: (v) => fmt(v)},
      ],
    });
    this.plot.setMessage('Tracking is off: switch it on to plot the segmented tip against the EKF.');
    this.switch.addEventListener('click', () => this.setOn(!this.on));
    this.plotPlane.addEventListener('change', () => this.plot.clear());
    this.editPlane.addEventListener('change', () => this.fillForm());
    this.$('seg-apply-button').addEventListener('click', () => this.apply());
    this.$('roadmap-button').addEventListener('click', () => this.takeRoadmap());
    this.showPlanes(null);
  }

  buildForm() {
    const form = this.$('seg-form');
    for (const [key, label, kind, step] of FIELDS) {
      const row = document.createElement('div');
      row.className = 'seg-row';
      const id = `seg-field-${key.replace('.', '-')}`;
      const lab = document.createElement('label');
      lab.htmlFor = id;
      lab.textContent = label;
      let input;
      if (kind === 'edge') {
        input = document.createElement('select');
        for (const e of EDGES) input.append(new Option(e, e));
      } else {
        input = document.createElement('input');
        input.type = kind === 'bool' ? 'checkbox' : 'number';
        if (step) input.step = String(step);
      }
      input.id = id;
      input.setAttribute('data-testid', testid(key));
      input.dataset.key = key;
      input.dataset.kind = kind;
      input.setAttribute('aria-label', `Segmentation ${label}`);
      row.append(lab, input);
      form.append(row);
    }
  }

  // The tab was opened: the parameters as the server has them.
  async refresh() {
    try {
      const answer = await this.api.get('/imaging/segmentation');
      this.parameters = answer.planes || {};
      this.fillForm();
      return answer;
    } catch (err) {
      this.setSegStatus(`Segmentation parameters unavailable: ${err.message}`, 'error');
      return null;
    }
  }

  fillForm() {
    const plane = this.parameters[this.editPlane.value];
    if (!plane) return;
    for (const input of this.root.querySelectorAll('[data-key]')) {
      const v = getKey(plane.parameters, input.dataset.key);
      if (input.dataset.kind === 'bool') input.checked = !!v;
      else input.value = v ?? '';
    }
    const r = plane.roadmap || {};
    const taken = Number.isFinite(r.taken_unix_s) ? new Date(r.taken_unix_s * 1000).toLocaleTimeString() : '—';
    this.$('roadmap-info').textContent =
      `roadmaps: ${r.count ?? '—'}, last at ${taken}${r.pending ? ' (pending: taken at the next tracked frame)' : ''}`;
    this.setSegStatus(plane.roadmap_from === 'source_frame' && !r.count
        ? `${PLANE_LABEL[this.editPlane.value]} is fed by a source: pull the catheter out of the field and take a roadmap`
      : plane.applied ? `${PLANE_LABEL[this.editPlane.value]}: parameters applied` : 'pending: applied at the plane\'s next tracked frame',
    plane.applied ? 'ok' : 'pending');
  }

  setSegStatus(text, kind) {
    const el = this.$('seg-status');
    el.textContent = text;
    el.dataset.kind = kind;
  }

  // Only the fields the operator changed go out (a partial PUT), so two editors do not undo each other.
  changes() {
    const plane = this.parameters[this.editPlane.value];
    const out = {};
    for (const input of this.root.querySelectorAll('[data-key]')) {
      const key = input.dataset.key;
      const kind = input.dataset.kind;
      const value = kind === 'bool' ? input.checked : kind === 'edge' ? input.value : input.value.trim() === '' ? NaN : Number(input.value);
      if (plane && getKey(plane.parameters, key) === value) continue;
      if (key.startsWith('roi.')) {
        out.roi = out.roi || {};
        out.roi[key.slice(4)] = value;
      } else {
        out[key] = value;
      }
    }
    return out;
  }

  async apply() {
    const planeName = this.editPlane.value;
    const body = this.changes();
    if (Object.keys(body).length === 0) {
      this.setSegStatus('nothing changed', 'ok');
      return;
    }
    // A number field left empty or not a number is refused here with the same words as the server's.
    for (const [k, v] of Object.entries(body)) {
      if (typeof v === 'number' && !Number.isFinite(v)) {
        this.setSegStatus(`${k}: expected a number`, 'error');
        return;
      }
    }
    // Said before the request goes out, so nothing reads the previous "applied" as this change's.
    this.setSegStatus('sending…', 'pending');
    try {
      await this.api.request('PUT', `/imaging/segmentation/${planeName}`, body);
    } catch (err) {
      const field = err.details?.field ? ` (${err.details.field})` : '';
      this.setSegStatus(`refused${field}: ${err.message}`, 'error');
      this.status?.(`Segmentation change refused: ${err.message}`, 'error');
      this.root.querySelector(`[data-key="${err.details?.field}"]`)?.focus();
      return;
    }
    this.setSegStatus('sent; pending: applied at the plane\'s next tracked frame', 'pending');
    for (let i = 0; i < APPLY_POLLS; i++) {
      const answer = await this.refresh();
      if (answer?.planes?.[planeName]?.applied) return;
      await new Promise((r) => setTimeout(r, 250));
    }
    if (!this.on) this.setSegStatus('pending: the plane applies it at its next tracked frame (tracking is off)', 'pending');
  }

  async takeRoadmap() {
    const planeName = this.editPlane.value;
    const before = this.parameters[planeName]?.roadmap?.count ?? 0;
    try {
      await this.api.post(`/imaging/roadmap/${planeName}`, {});
    } catch (err) {
      this.setSegStatus(`roadmap refused: ${err.message}`, 'error');
      this.status?.(`Take roadmap refused: ${err.message}`, 'error');
      return;
    }
    this.setSegStatus(`${PLANE_LABEL[planeName]}: roadmap asked for`, 'pending');
    for (let i = 0; i < APPLY_POLLS; i++) {
      const answer = await this.refresh();
      const r = answer?.planes?.[planeName]?.roadmap;
      if (r && r.count > before && !r.pending) {
        this.setSegStatus(`${PLANE_LABEL[planeName]}: new roadmap taken`, 'ok');
        return;
      }
      await new Promise((res) => setTimeout(res, 250));
    }
  }

  setOn(on) {
    this.on = on;
    this.switch.setAttribute('aria-checked', String(on));
    this.switch.querySelector('.switch-state').textContent = on ? 'on' : 'off';
    const conn = this.connection();
    if (on) conn?.addTopic(TRACKING_TOPIC);
    else conn?.removeTopic(TRACKING_TOPIC);
    this.plot.clear();
    this.plot.setMessage(on ? 'Waiting for the first tracked frames…' : 'Tracking is off: switch it on to plot the segmented tip against the EKF.');
    if (!on) {
      this.last = null;
      this.showPlanes(null);
      this.view()?.setTrackedTip(null);
    }
  }

  // A tendril.TipTracking message.
  onMessage(msg) {
    if (!this.on || !msg || typeof msg !== 'object') return;
    this.last = msg;
    this.showPlanes(msg);
    // One plane and one image coordinate at a time, so that the axis spans the two estimates' difference.
    const [planeName, axis] = this.plotPlane.value.split(':');
    const p = msg.planes?.[planeName];
    if (p) {
      const t = performance.now() / 1000;
      this.plot.setMessage(null);
      if (p.tip_px) this.plot.push(0, t, p.tip_px[Number(axis)]);
      if (p.filtered_px) this.plot.push(1, t, p.filtered_px[Number(axis)]);
    }
    this.view()?.setTrackedTip(Array.isArray(msg.tip_mm) ? msg.tip_mm : null);
  }

  showPlanes(msg) {
    for (const plane of PLANES) {
      const el = this.$(`tracking-${plane}-status`);
      const p = msg?.planes?.[plane];
      if (!msg) {
        el.textContent = '—';
        el.dataset.found = '';
      } else if (p?.found) {
        el.textContent = `found (quality ${fmt(p.quality, 2)})`;
        el.dataset.found = 'true';
      } else {
        el.textContent = p?.reason || 'nothing found';
        el.dataset.found = 'false';
      }
    }
    const d = msg?.disagreement_mm;
    const bound = Number.isFinite(msg?.disagreement_bound_mm) ? msg.disagreement_bound_mm : 3;
    const dis = this.$('tracking-disagreement');
    dis.textContent = Number.isFinite(d) ? `${d.toFixed(2)} mm (bound ${fmt(bound)} mm)` : '—';
    dis.dataset.level = !Number.isFinite(d) ? '' : d > bound ? 'alarm' : 'ok';
    dis.setAttribute('aria-label', Number.isFinite(d)
      ? `Imaged tip to model tip: ${d.toFixed(2)} mm${d > bound ? ', beyond the bound' : ''}` : 'Imaged tip to model tip: no value');
    const tip = msg?.tip_mm;
    this.$('tracking-tip').textContent = Array.isArray(tip) ? `[${tip.map((v) => v.toFixed(1)).join(', ')}] mm` : '—';
  }
}
