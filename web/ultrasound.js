// Panel of the ultrasound arm (a serial arm with an "ultrasound" section in GET /robots; Heunis et al. 2021):
// - sweep controls (plan, preview, pre-position, start, pause, abort: POST /robots/{r}/sweep) with the
//   phase, the via-point reached, the progress and the acquisition gate from /{robot}/sweep;
// - the live SIMULATED B-mode image (/{robot}/ultrasound/image, foxglove.CompressedImage in JSON, PNG)
//   with the artery boundary the ellipse EKF fitted (/{robot}/ultrasound/annotations,
//   foxglove.ImageAnnotations) drawn over it, matched by time stamp;
// - the contact force plot: the normal force against the 0.8 N target (/{robot}/force, every sample);
// - the 3D scene of Fig. 7 of Heunis et al. 2021 (/{robot}/reconstruction, foxglove.SceneUpdate in the frame
//   "tissue") in a tissue-stabilised view: the 3D view's fixed frame becomes "tissue" through /tf, so
//   the limb stands still on screen while it moves in the world, and the arm and probe move about it.
import {el, group, fmt, describe, robotCommand} from './panel_kit.js';
import {TimePlot} from './plot.js';
import {CalibrationPanel} from './us_calibration.js';
import {operatorWords} from './words.js';

const ENTITY_PREFIX = 'ultrasound-panel/';
const TISSUE_FRAME = 'tissue';
const WORLD_FRAME = 'world';
const ACTIONS = [
  ['plan', 'Plan', 'CT centreline fit, via-points and registration'],
  ['preview', 'Preview', 'show the planned via-point poses without moving'],
  ['pre_position', 'Pre-position', 'move above the first via-point'],
  ['start', 'Start', 'sweep the via-points under force control'],
  ['pause', 'Pause', 'stop at the current via-point'],
  ['abort', 'Abort', 'retract and hold'],
];
// Which actions make sense in which phase (the server decides; this only avoids buttons that would be
// refused anyway). Abort and pause stay available whenever the arm may move.
const ALLOWED = {
  idle: ['plan'],
  planned: ['plan', 'preview', 'pre_position'],
  pre_positioning: ['pause', 'abort'],
  ready: ['plan', 'preview', 'pre_position', 'start', 'abort'],
  approaching: ['pause', 'abort'],
  acquiring: ['pause', 'abort'],
  moving: ['pause', 'abort'],
  paused: ['start', 'abort', 'pre_position'],
  done: ['plan', 'preview', 'pre_position', 'abort'],
  aborted: ['plan', 'preview', 'pre_position'],
};

function stampKey(ts) {
  if (!ts) return '';
  if (typeof ts === 'number') return String(Math.round(ts * 1e6));
  return `${ts.sec ?? ts.seconds ?? 0}.${ts.nsec ?? ts.nanos ?? 0}`;
}

function svgEl(tag, attrs) {
  const node = document.createElementNS('http://www.w3.org/2000/svg', tag);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, String(v));
  return node;
}

function rgba(c, fallback) {
  if (!c) return fallback;
  return `rgba(${Math.round((c.r ?? 0) * 255)},${Math.round((c.g ?? 0) * 255)},${Math.round((c.b ?? 0) * 255)},${c.a ?? 1})`;
}

export function createPanel(root, ctx) {
  return new UltrasoundPanel(root, ctx);
}

class UltrasoundPanel {
  constructor(root, ctx) {
    this.root = root;
    this.ctx = ctx;
    this.robot = ctx.robot;
    this.info = ctx.robot.ultrasound || {};
    const name = ctx.robot.name;
    this.t = {
      sweep: `/${name}/sweep`, image: `/${name}/ultrasound/image`, annotations: `/${name}/ultrasound/annotations`,
      reconstruction: `/${name}/reconstruction`, force: `/${name}/force`, tf: '/tf',
    };
    this.topics = [this.t.sweep, this.t.image, this.t.reconstruction, this.t.tf];
    // Small and frequent, or needed to match each image: every message.
    this.everyMessage = [this.t.force, this.t.annotations];
    this.annotations = [];  // the last few, to match an image by its time stamp
    this.frames = 0;
    this.decoding = false;
    this.pendingImage = null;
    this.reconIds = new Set();
    this.forceFromTopic = false;
    this.t0 = NaN;
    this.commandable = false;
    this.phase = null;
    this.build();
    this.setTissueView(true);
  }

  build() {
    const u = (this.ui = {});
    u.age = el('span', {className: 'age', 'data-testid': 'us-age', role: 'status', text: 'no data'});
    u.phase = el('div', {className: 'rp-badge', 'data-testid': 'us-phase', role: 'status', 'aria-live': 'polite',
                         text: 'waiting for /sweep…'});
    u.progressBar = el('div', {className: 'rp-bar-fill', 'data-testid': 'us-progress-bar'});
    u.progress = el('span', {className: 'rp-big', 'data-testid': 'us-progress', text: '—'});
    u.viaPoint = el('div', {className: 'rp-detail', 'data-testid': 'us-via-point'});
    u.gate = el('div', {className: 'rp-detail', 'data-testid': 'us-gate'});
    u.message = el('div', {className: 'rp-reason', 'data-testid': 'us-message'});
    u.buttons = Object.fromEntries(ACTIONS.map(([action, label, title]) => [action, el('button', {
      type: 'button', className: `btn${action === 'abort' ? ' btn-danger' : ''}`, 'data-testid': `us-sweep-${action.replace('_', '-')}`,
      title, text: label, onclick: () => this.sweep(action, label)})]));
    u.canvas = el('canvas', {className: 'rp-canvas', 'data-testid': 'us-image-canvas', role: 'img',
                             'aria-label': 'Live ultrasound image with the fitted artery ellipse'});
    u.overlay = svgEl('svg', {preserveAspectRatio: 'none', 'data-testid': 'us-ellipse'});
    u.image = el('div', {className: 'rp-image', 'data-testid': 'us-image', 'data-state': 'waiting', 'data-frames': '0'},
                 u.canvas, u.overlay);
    u.imageInfo = el('div', {className: 'rp-detail', 'data-testid': 'us-image-info', text: 'no image yet (the probe images only in contact)'});
    u.forceCanvas = el('canvas', {'data-testid': 'us-force-plot', role: 'img', 'aria-label': 'Normal force against the target'});
    u.forceValue = el('div', {className: 'rp-detail', 'data-testid': 'us-force', text: 'force: —'});
    u.tissueView = el('input', {type: 'checkbox', checked: true, 'data-testid': 'us-tissue-view',
                                onchange: () => this.setTissueView(u.tissueView.checked)});
    u.tfInfo = el('div', {className: 'rp-detail', 'data-testid': 'us-tf-info', text: '/tf: waiting for the tissue frame'});
    u.reconInfo = el('div', {className: 'rp-detail', 'data-testid': 'us-recon-info', text: 'reconstruction: nothing yet'});
    u.hint = el('div', {className: 'rp-hint', 'data-testid': 'us-hint'});
    this.calibration = new CalibrationPanel(this.ctx, this.robot);

    this.root.append(
        el('div', {className: 'panel-age'}, 'sweep values ', u.age),
        group('Sweep', `(${this.info.via_points ?? '?'} via-points, ${fmt(Number(this.info.force_target_n ?? 0.8), 1)} N target)`,
              u.phase, el('div', {className: 'rp-scale'},
                          el('div', {className: 'rp-bar', role: 'progressbar', 'aria-label': 'Sweep progress'}, u.progressBar),
                          u.progress),
              u.viaPoint, u.gate, u.message,
              el('div', {className: 'form-row rp-modes'}, Object.values(u.buttons))),
        group('Calibration', '(robot–world and the others the sweep needs)', this.calibration.element),
        group('Ultrasound image', '(SIMULATED B-mode; fitted ellipse in orange, its centre in red)', u.image, u.imageInfo),
        group('Contact force', '(normal force vs target)',
              el('div', {className: 'plot-box rp-plot'}, u.forceCanvas), u.forceValue),
        group('3D reconstruction', '(Heunis et al. 2021, Fig. 7)',
              el('label', {className: 'rp-label'}, u.tissueView, ' tissue-stabilised view (the camera moves with the limb)'),
              u.tfInfo, u.reconInfo),
        u.hint);
    const target = Number(this.info.force_target_n ?? 0.8);
    this.forcePlot = new TimePlot(u.forceCanvas, {
      series: [{label: 'normal force', color: '#4ea1ff', format: (v) => `${v.toFixed(2)} N`},
               {label: `target ${target.toFixed(1)} N`, color: '#e3b341', dash: true}],
      windowS: 20, unit: 'N', minSpan: 1, floorZero: true,
    });
    this.forceTarget = target;
    this.setCommandable(false, 'Waiting for the robot state…');
  }

  setTissueView(on) {
    this.wantFrame = on ? TISSUE_FRAME : WORLD_FRAME;
    this.ctx.view()?.setFixedFrame(this.wantFrame);
    this.updateTfInfo();
  }

  setCommandable(ok, hint, robotState = {}) {
    this.commandable = ok;
    this.commandHint = hint;
    this.calibration?.setCommandable(ok, robotState);
    this.updateButtons();
  }

  updateButtons() {
    const allowed = this.phase ? ALLOWED[this.phase] || ACTIONS.map((a) => a[0]) : ['plan'];
    for (const [action, b] of Object.entries(this.ui.buttons)) {
      // Abort is a stop: it needs the lease, never fresh data or a phase.
      b.disabled = action === 'abort' ? !this.commandable && !/Stale/.test(this.commandHint || '')
                                      : !this.commandable || !allowed.includes(action);
    }
    this.ui.hint.textContent = this.commandable ? '' : this.commandHint || '';
  }

  async sweep(action, label) {
    try {
      const answer = await robotCommand(this.ctx.api, this.robot.name, 'sweep', {action});
      const detail = answer && typeof answer === 'object' && answer.message ? `: ${answer.message}` : '';
      this.ctx.status(`Sweep ${label.toLowerCase()}: accepted${detail}`, 'ok');
    } catch (err) {
      this.ctx.status(`Sweep ${label.toLowerCase()}: ${describe(err)}`, 'error');
    }
  }

  onMessage(topic, msg, stampMs) {
    if (topic === this.t.sweep) this.applySweep(msg, stampMs);
    else if (topic === this.t.force) this.applyForce(msg, stampMs);
    else if (topic === this.t.annotations) this.keepAnnotations(msg);
    else if (topic === this.t.image) this.applyImage(msg, stampMs);
    else if (topic === this.t.tf) {
      const view = this.ctx.view();
      // The 3D view may have started after the panel (it loads three.js on its own).
      if (view && view.fixedFrame !== this.wantFrame) view.setFixedFrame(this.wantFrame);
      view?.setFrameTransforms(msg);
      this.updateTfInfo();
    } else if (topic === this.t.reconstruction) this.applyReconstruction(msg);
  }

  applySweep(msg, stampMs) {
    if (msg?.calibration) this.calibration.apply(msg.calibration);
    const s = msg?.sweep;
    if (!s) return;
    this.stampMs = stampMs;
    const u = this.ui;
    this.phase = s.phase || null;
    u.phase.textContent = (s.phase || 'unknown').replace(/_/g, ' ').toUpperCase();
    u.phase.dataset.phase = s.phase || '';
    u.phase.className = `rp-badge rp-${s.phase === 'aborted' ? 'bad' : s.phase === 'paused' ? 'warn' : 'ok'}`;
    const p = Math.min(1, Math.max(0, Number(s.progress) || 0));
    u.progressBar.style.width = `${Math.round(p * 100)}%`;
    u.progress.textContent = `${Math.round(p * 100)} %`;
    u.progress.dataset.value = String(p);
    u.viaPoint.textContent = `via-point ${Number.isFinite(Number(s.via_point)) ? Number(s.via_point) : '—'} of ${s.via_points ?? '—'}` +
        ` · ${Number(s.slices) || 0} slices acquired`;
    u.viaPoint.dataset.viaPoint = String(s.via_point ?? '');
    u.viaPoint.dataset.slices = String(Number(s.slices) || 0);
    const g = s.gate || {};
    u.gate.textContent = `gate ${g.open ? 'OPEN' : 'closed'}: position ${fmt(Number(g.position_error_mm), 2, 'mm')} (≤ 0.5)` +
        ` · angle ${fmt(Number(g.angle_error_rad), 3, 'rad')} (≤ 0.01) · force ${g.force_ok ? 'held' : 'not held'}`;
    u.gate.dataset.open = String(!!g.open);
    u.message.textContent = operatorWords(s.message || '');
    u.message.title = s.message || '';
    if (Number.isFinite(Number(s.force_target_n))) this.forceTarget = Number(s.force_target_n);
    // Until /{robot}/force arrives (a server without it), the 20 Hz F_n of /sweep is plotted instead.
    if (!this.forceFromTopic && Number.isFinite(Number(s.force_n))) {
      this.plotForce(Number(s.force_n), stampMs, s.in_contact ? 'contact' : 'free space');
    }
    this.updateButtons();
    this.updateAge();
  }

  applyForce(msg, stampMs) {
    const normal = Number(msg?.normal_n);
    if (!Number.isFinite(normal)) return;
    this.forceFromTopic = true;
    if (Number.isFinite(Number(msg.target_n))) this.forceTarget = Number(msg.target_n);
    this.plotForce(normal, stampMs, msg.in_contact ? 'contact' : 'free space');
  }

  // `mode`: the controller's mode: the hybrid controller's force phase is "contact".
  plotForce(normal, stampMs, mode) {
    if (!Number.isFinite(this.t0)) this.t0 = stampMs;
    const t = (stampMs - this.t0) / 1000;
    this.forcePlot.push(0, t, normal);
    this.forcePlot.push(1, t, this.forceTarget);
    this.ui.forceValue.textContent = `force: ${normal.toFixed(3)} N (target ${this.forceTarget.toFixed(2)} N) · ${mode}`;
    this.ui.forceValue.dataset.value = String(normal);
    this.ui.forceValue.dataset.source = this.forceFromTopic ? 'force' : 'sweep';
    this.ui.forceValue.dataset.samples = String(Number(this.ui.forceValue.dataset.samples || 0) + 1);
  }

  keepAnnotations(msg) {
    this.annotations.push(msg);
    if (this.annotations.length > 16) this.annotations.shift();
  }

  // Decodes the PNG off the frame (createImageBitmap) and draws it; a newer image that arrives while
  // one decodes replaces the waiting one (never a queue of old images).
  applyImage(msg, stampMs) {
    if (typeof msg?.data !== 'string') return;
    this.pendingImage = {msg, stampMs};
    if (this.decoding) return;
    this.decodeNext();
  }

  async decodeNext() {
    const next = this.pendingImage;
    if (!next) return;
    this.pendingImage = null;
    this.decoding = true;
    try {
      const format = /jpe?g/i.test(next.msg.format || '') ? 'jpeg' : 'png';
      const bytes = Uint8Array.from(atob(next.msg.data), (c) => c.charCodeAt(0));
      const bitmap = await createImageBitmap(new Blob([bytes], {type: `image/${format}`}));
      this.drawImage(bitmap, next.msg);
      bitmap.close();
    } catch (err) {
      this.ui.image.dataset.state = 'error';
      this.ui.imageInfo.textContent = `image could not be decoded (${err.message})`;
    } finally {
      this.decoding = false;
    }
    if (this.pendingImage) this.decodeNext();
  }

  drawImage(bitmap, msg) {
    const {canvas, overlay} = this.ui;
    if (canvas.width !== bitmap.width || canvas.height !== bitmap.height) {
      canvas.width = bitmap.width;
      canvas.height = bitmap.height;
    }
    canvas.getContext('2d').drawImage(bitmap, 0, 0);
    this.frames++;
    this.ui.image.dataset.frames = String(this.frames);
    this.ui.image.dataset.state = 'live';
    overlay.setAttribute('viewBox', `0 0 ${bitmap.width} ${bitmap.height}`);
    // The annotation of this image's time stamp; else the newest (marked as not matched).
    const key = stampKey(msg.timestamp);
    let ann = this.annotations.find((a) => stampKey(a.points?.[0]?.timestamp ?? a.timestamp) === key);
    const matched = !!ann;
    ann ??= this.annotations[this.annotations.length - 1];
    overlay.replaceChildren();
    let shapes = 0;
    for (const p of ann?.points || []) {
      const pts = (p.points || []).filter((q) => Number.isFinite(q.x) && Number.isFinite(q.y));
      if (p.type === 1) {
        // POINTS (e.g. the ellipse's centre): a small cross each.
        for (const q of pts) {
          overlay.append(svgEl('path', {d: `M${q.x - 6},${q.y}h12M${q.x},${q.y - 6}v12`, stroke: rgba(p.outline_color, '#3fb950'),
                                        'stroke-width': 2, 'vector-effect': 'non-scaling-stroke'}));
        }
        continue;
      }
      if (pts.length < 2) continue;
      const d = pts.map((q) => `${q.x},${q.y}`).join(' ');
      // PointsAnnotationType: 1 points, 2 line loop, 3 line strip, 4 line list
      const tag = p.type === 3 || p.type === 4 ? 'polyline' : 'polygon';
      overlay.append(svgEl(tag, {points: d, fill: rgba(p.fill_color, 'none'), stroke: rgba(p.outline_color, '#3fb950'),
                                 'stroke-width': Math.max(1, Number(p.thickness) || 2), 'vector-effect': 'non-scaling-stroke'}));
      shapes++;
    }
    for (const c of ann?.circles || []) {
      const pos = c.position || {};
      overlay.append(svgEl('circle', {cx: pos.x, cy: pos.y, r: (c.diameter || 4) / 2, fill: rgba(c.fill_color, 'none'),
                                      stroke: rgba(c.outline_color, '#3fb950'), 'stroke-width': c.thickness || 2,
                                      'vector-effect': 'non-scaling-stroke'}));
      shapes++;
    }
    const caption = (ann?.texts || []).map((t) => t.text).filter(Boolean).join(' · ');
    overlay.dataset.shapes = String(shapes);
    overlay.dataset.matched = String(matched);
    this.ui.imageInfo.textContent = `${bitmap.width}×${bitmap.height} px · ${this.frames} frames · ellipse ${
      shapes ? (matched ? 'of this frame' : 'of an earlier frame') : 'not fitted'}${caption ? ` · ${caption}` : ''}` +
        (Number.isFinite(Number(msg.via_point)) ? ` · via-point ${msg.via_point}` : '');
  }

  applyReconstruction(msg) {
    const view = this.ctx.view();
    if (!view) return;
    for (const e of msg.entities || []) this.reconIds.add(e.id);
    view.applySceneUpdate(msg);
    // Keep the camera on the limb's skin once it is first drawn (unless the operator placed it): the
    // reconstruction is the subject here, not the arm (whose base is half a metre away).
    if (!this.framed && !view.userCamera) {
      const surface = (msg.entities || []).find((e) => /(^|\/)surface$/.test(e.id || '') && (e.spheres || []).length);
      const obj = surface && view.entities.get(surface.id);
      if (obj && obj.visible) {
        obj.updateMatrixWorld(true);
        view.setFocus(obj);
        this.framed = true;
      }
    }
    // What each entity holds now (the topic sends every entity in every message, possibly empty).
    const count = this.reconCount ??= {};
    for (const e of msg.entities || []) {
      const name = String(e.id || '').replace(/^.*\//, '');
      const lines = e.lines || [];
      count[name] = name === 'surface' ? (e.spheres || []).length
                  : name === 'via_points' ? Math.max(0, ...lines.map((l) => Math.floor((l.points || []).length / 2)))  // a LINE_LIST per axis: 2 points per via-point
                  : name === 'contours' ? lines.length
                  : name === 'artery_mesh' ? (e.triangles || []).reduce((n, t) => n + Math.floor(((t.indices?.length || t.points?.length) || 0) / 3), 0)
                  : name === 'catheter' ? lines.reduce((n, l) => n + (l.points || []).length, 0)
                  : name === 'contacts' ? (e.spheres || []).length
                  : name === 'curvature_warnings' ? (e.texts || []).length
                  : (lines.length + (e.spheres || []).length + (e.arrows || []).length + (e.triangles || []).length);
    }
    const info = this.ui.reconInfo;
    for (const [k, v] of Object.entries(count)) info.dataset[k.replace(/_([a-z])/g, (_, c) => c.toUpperCase())] = String(v);
    const part = (k, label) => (k in count ? `${count[k]} ${label}` : null);
    info.textContent = [part('surface', 'skin points'), part('via_points', 'via-points'), part('contours', 'contours'),
                        part('artery_mesh', 'mesh triangles'), part('catheter', 'catheter points'),
                        part('contacts', 'contacts'), part('curvature_warnings', 'curvature warnings')]
      .filter(Boolean).join(' · ') || 'reconstruction: nothing yet';
  }

  updateTfInfo() {
    const view = this.ctx.view();
    if (!view) return;
    const tissue = view.frameOrigin(TISSUE_FRAME);
    const world = view.frameOrigin(WORLD_FRAME);
    const fixed = this.ui.tissueView.checked ? TISSUE_FRAME : WORLD_FRAME;
    const known = view.frames.has(TISSUE_FRAME);
    this.ui.tfInfo.dataset.fixedFrame = fixed;
    this.ui.tfInfo.dataset.tissueKnown = String(known);
    if (!known) {
      this.ui.tfInfo.textContent = `view fixed to "${fixed}"; /tf has not given the tissue frame yet`;
    } else if (fixed === TISSUE_FRAME && world) {
      this.ui.tfInfo.textContent = `view fixed to the tissue; the world origin is at ${world.map((v) => v.toFixed(1)).join(', ')} mm`;
    } else if (tissue) {
      this.ui.tfInfo.textContent = `view fixed to the world; the tissue is at ${tissue.map((v) => v.toFixed(1)).join(', ')} mm`;
    }
  }

  updateAge() {
    if (!Number.isFinite(this.stampMs)) return;
    const age = this.ctx.ageMs ? this.ctx.ageMs(this.stampMs) : Date.now() - this.stampMs;
    this.ui.age.textContent = age < 1000 ? `${Math.max(0, Math.round(age))} ms` : `${(age / 1000).toFixed(1)} s`;
    this.ui.age.dataset.ageMs = String(Math.round(age));
  }

  destroy() {
    const view = this.ctx.view();
    if (!view) return;
    view.setFixedFrame(null);
    view.setFocus(null);
    for (const id of this.reconIds) view.removeEntity(id);
    view.removeEntities(ENTITY_PREFIX);
  }
}
