// Panel of the sdu_continuum robot (Abah 2022, ch. 3): a continuum segment carrying sensing disk units
// with ToF range and Hall sensors. Shows, from the live state topic /{robot}/continuum:
// - the supervisor's state and its reason (the safety path's verdict: normal, slowed, stopped on
//   contact, holding on a fault …), in words a person can act on;
// - the live speed-scale factor ‖v‖ = (d_e/d_max)(v_max − v_min) + v_min as a bar and a number, with the
//   speed limit it gives and the nearest range;
// - the contact: which disk and which angular slot;
// - per disk its nearest range, largest force and fault, in a table, and ON the 3D robot: a ring of
//   slot markers around each disk coloured by that slot's range (red near, green beyond d_max, grey
//   nothing in range), the slot in contact drawn large and red;
// - the HRI mode (off / contactless / contact guidance), the map (/sdu/map point cloud and the
//   extracted planes with the bracing verdict from /sdu/planes) and the SIMULATED human arm's buttons.
import {el, group, fmt, describe, robotCommand, rampColor, holdToRun} from './panel_kit.js';

const SLOTS_DEFAULT = 8;
// The disks' rim radius when GET /robots does not state it: the SDU of Abah 2022, ch. 3 (OD 158 mm).
const DISK_RING_MM = 79;
const ENTITY_PREFIX = 'continuum-panel/';
const PLANE_OPACITY = 0.3;
const GREY = {r: 0.45, g: 0.5, b: 0.56, a: 1};
const RED = {r: 0.97, g: 0.2, b: 0.2, a: 1};

const SUPERVISOR_TEXT = {
  unbiasing: 'Unbiasing Hall sensors',
  normal: 'Normal',
  slowed: 'Slowed (proximity)',
  stopped_contact: 'STOPPED: contact',
  holding_fault: 'HOLDING: sensor fault',
};

function vsub(a, b) { return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]; }
function vcross(a, b) { return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]; }
function vnorm(a) {
  const n = Math.hypot(a[0], a[1], a[2]);
  return n > 1e-9 ? [a[0] / n, a[1] / n, a[2] / n] : null;
}

function matmul(a, b) {
  return a.map((row) => [0, 1, 2].map((j) => row[0] * b[0][j] + row[1] * b[1][j] + row[2] * b[2][j]));
}
function rotZ(t) { return [[Math.cos(t), -Math.sin(t), 0], [Math.sin(t), Math.cos(t), 0], [0, 0, 1]]; }
function rotY(t) { return [[Math.cos(t), 0, Math.sin(t)], [0, 1, 0], [-Math.sin(t), 0, Math.cos(t)]]; }

// The axes u (x, towards slot 0) and v (y) of a disk's plane, in {0}. In order of preference:
// the disk's own orientation when the server sends it ([qx,qy,qz,qw]); the constant-curvature model
// from the measured joints, ⁰R_d = Rz(roll)·Rz(δ)·Ry(θ·s/L)·Rz(−δ) (teleop/sdu_continuum/README.md's frames: {d} with z
// along the tangent and x towards slot 0°); else the tangent estimated from the neighbouring disks and
// x the base's +x projected into the disk's plane (slot 0 then only approximately placed).
function diskAxes(disks, i, model) {
  const d = disks[i];
  if (Array.isArray(d.orientation) && d.orientation.length === 4) {
    const [x, y, z, w] = d.orientation;
    const u = [1 - 2 * (y * y + z * z), 2 * (x * y + z * w), 2 * (x * z - y * w)];
    const v = [2 * (x * y - z * w), 1 - 2 * (x * x + z * z), 2 * (y * z + x * w)];
    return {u, v};
  }
  if (model && Number.isFinite(model.arc[d.index]) && model.length > 0) {
    const R = matmul(matmul(matmul(rotZ(model.roll), rotZ(model.plane)), rotY(model.bending * model.arc[d.index] / model.length)),
                     rotZ(-model.plane));
    return {u: [R[0][0], R[1][0], R[2][0]], v: [R[0][1], R[1][1], R[2][1]]};
  }
  const prev = i > 0 ? disks[i - 1].position_mm : [0, 0, 0];
  const next = i + 1 < disks.length ? disks[i + 1].position_mm : d.position_mm;
  const t = vnorm(vsub(next, prev)) || vnorm(vsub(d.position_mm, prev)) || [0, 0, 1];
  let v = vnorm(vcross(t, [1, 0, 0]));
  if (!v) v = vnorm(vcross(t, [0, 1, 0]));
  const u = vcross(v, t);
  return {u, v};
}

export function createPanel(root, ctx) {
  return new ContinuumPanel(root, ctx);
}

// The roll stream: 0.05 rad/s asked (the server caps the disk centre at 5 mm/s, 0.063 rad/s on a 79 mm
// rim), refreshed every 50 ms, well within the robot's 150 ms command timeout.
const ROLL_RATE_RAD_S = 0.05;
const ROLL_REFRESH_MS = 50;
const ROLL_TITLE = 'Hold (pointer, or Enter / Space) to roll along the contact (the disk centre at most 5 mm/s)';

class ContinuumPanel {
  constructor(root, ctx) {
    this.root = root;
    this.ctx = ctx;
    this.robot = ctx.robot;
    const c = ctx.robot.continuum || {};
    this.info = c;
    this.dMax = Number(c.speed?.d_max_mm) || 100;
    this.slots = Number(c.disks?.[0]?.slots) || SLOTS_DEFAULT;
    this.ringMm = Number(c.segment?.disk_radius_mm) || Number(c.disks?.[0]?.radius_mm) || DISK_RING_MM;
    // Window angles around a disk (degrees from its x axis): the Hall windows sit between the ToF ones.
    const num = (v, fallback) => (Number.isFinite(Number(v)) ? Number(v) : fallback);
    this.pitchDeg = num(c.segment?.slot_pitch_deg, 360 / this.slots);
    this.tofSlot0Deg = num(c.segment?.tof_slot0_deg, 0);
    this.hallSlot0Deg = num(c.segment?.hall_slot0_deg, this.pitchDeg / 2);
    const name = ctx.robot.name;
    this.topicState = `/${name}/continuum`;
    this.topicMap = `/${name}/map`;
    this.topicPlanes = `/${name}/planes`;
    this.topics = [this.topicState, this.topicMap, this.topicPlanes];
    this.planeIds = new Set();
    this.lastState = null;
    this.commandable = false;
    this.build();
  }

  build() {
    const modes = this.info.hri_modes || ['off', 'contactless', 'contact'];
    this.ui = {};
    const u = this.ui;
    u.age = el('span', {className: 'age', 'data-testid': 'continuum-age', role: 'status', text: 'no data'});
    u.supervisor = el('div', {className: 'rp-badge', 'data-testid': 'continuum-supervisor', role: 'status',
                              'aria-live': 'polite', text: 'waiting for /continuum…'});
    u.reason = el('div', {className: 'rp-reason', 'data-testid': 'continuum-reason'});
    u.scaleBar = el('div', {className: 'rp-bar-fill', 'data-testid': 'continuum-speed-bar'});
    u.scale = el('span', {className: 'rp-big', 'data-testid': 'continuum-speed-scale', text: '—'});
    u.scaleDetail = el('div', {className: 'rp-detail', 'data-testid': 'continuum-speed-detail'});
    u.contact = el('div', {className: 'rp-contact', 'data-testid': 'continuum-contact', 'data-contact': 'false',
                           role: 'status', 'aria-live': 'assertive', text: 'no contact'});
    u.modeButtons = Object.fromEntries(modes.map((m) => [m, el('button', {
      type: 'button', className: 'btn', 'data-testid': `continuum-hri-${m}`, 'aria-pressed': 'false',
      text: m === 'off' ? 'Off' : m === 'contactless' ? 'Contactless' : m === 'contact' ? 'Contact' : m,
      onclick: () => this.command('hri_mode', {mode: m}, `HRI mode ${m}`)})]));
    u.disks = el('tbody');
    u.map = el('div', {className: 'rp-detail', 'data-testid': 'continuum-map', text: 'no map yet'});
    u.bracing = el('div', {className: 'rp-verdict', 'data-testid': 'continuum-bracing', text: 'bracing: not evaluated'});
    u.armSpeed = el('input', {type: 'number', min: '0.5', max: '50', step: '0.5', value: '10',
                              'data-testid': 'continuum-arm-speed', 'aria-label': 'Arm speed in mm/s', className: 'rp-num'});
    const armButton = (action, label) => el('button', {
      type: 'button', className: 'btn', 'data-testid': `continuum-arm-${action}`, text: label,
      onclick: () => this.command('simulation_scene', {action, speed_mm_s: Number(u.armSpeed.value) || 10},
                                  `SIMULATED arm: ${action}`)});
    u.armButtons = [armButton('approach', 'Approach'), armButton('retreat', 'Retreat'), armButton('reset', 'Reset')];
    u.arm = el('div', {className: 'rp-detail', 'data-testid': 'continuum-arm'});
    u.unbias = el('button', {type: 'button', className: 'btn', 'data-testid': 'continuum-unbias', text: 'Unbias Hall',
                             title: 'Take the Hall sensors\' baseline again (refused while in contact)',
                             onclick: () => this.command('unbias', {}, 'Hall unbias')});
    u.mapButtons = [
      el('button', {type: 'button', className: 'btn', 'data-testid': 'continuum-map-extract', text: 'Extract planes',
                    onclick: () => this.command('map', {action: 'extract'}, 'Plane extraction')}),
      el('button', {type: 'button', className: 'btn', 'data-testid': 'continuum-map-clear', text: 'Clear map',
                    onclick: () => this.command('map', {action: 'clear'}, 'Map cleared')}),
    ];
    u.hint = el('div', {className: 'rp-hint', 'data-testid': 'continuum-hint'});
    // The no-slip roll about a contact (the way out of a contact hold besides moving the object): a
    // stream while a button is held, refreshed within the robot's command timeout, stopped on release.
    const rollButton = (sign, label) => {
      const b = el('button', {type: 'button', className: 'btn', 'data-testid': `continuum-roll-${sign > 0 ? 'plus' : 'minus'}`,
                              text: label, title: ROLL_TITLE});
      // Held (pointer, or Enter / Space on the focused button) it rolls; let go it stops (panel_kit.js).
      holdToRun(b, {start: () => this.startRoll(sign * ROLL_RATE_RAD_S), stop: () => this.stopRoll()});
      return b;
    };
    u.rollButtons = [rollButton(-1, '◀ Roll'), rollButton(1, 'Roll ▶')];
    // Why the Roll buttons are disabled, in words beside them (they were disabled without a word).
    u.rollWhy = el('div', {className: 'rp-hint', 'data-testid': 'continuum-roll-why', role: 'status'});

    this.root.append(
        el('div', {className: 'panel-age'}, 'continuum values ', u.age),
        group('Safety supervisor', '(no mode bypasses it)', u.supervisor, u.reason, u.contact,
              el('div', {className: 'form-row'}, u.unbias, u.rollButtons), u.rollWhy),
        group('Speed scale', `(proximity: v_min ${fmt(this.info.speed?.min_mm_s, 2)} … v_max ${fmt(this.info.speed?.max_mm_s, 0)} mm/s over ${fmt(this.dMax, 0)} mm)`,
              el('div', {className: 'rp-scale'},
                 el('div', {className: 'rp-bar', role: 'meter', 'aria-label': 'Speed-scale factor'}, u.scaleBar), u.scale),
              u.scaleDetail),
        group('HRI mode', '(the law moves the robot in the Guidance mode)', el('div', {className: 'form-row rp-modes'}, Object.values(u.modeButtons))),
        group('Sensing disks', '(nearest ToF range, largest Hall force)',
              el('table', {className: 'rp-table', 'data-testid': 'continuum-disks'},
                 el('thead', {}, el('tr', {}, ['disk', 'nearest', 'force', 'contact', 'state'].map((h) => el('th', {text: h})))),
                 u.disks)),
        group('Map and bracing', '(/map point cloud, RANSAC planes)', u.map, u.bracing, el('div', {className: 'form-row'}, u.mapButtons)),
        group('SIMULATED human arm', '(the scene the disks see)',
              el('div', {className: 'form-row'}, el('label', {className: 'rp-label'}, 'speed ', u.armSpeed, ' mm/s'), u.armButtons),
              u.arm),
        u.hint);
    this.setCommandable(false, 'Waiting for the robot state…');
  }

  setCommandable(ok, hint) {
    this.commandable = ok;
    this.notCommandable = ok ? '' : hint || 'commands are not available';
    const buttons = [...Object.values(this.ui.modeButtons), ...this.ui.armButtons, ...this.ui.mapButtons, this.ui.unbias];
    for (const b of buttons) b.disabled = !ok;
    this.updateRollButtons();
    this.ui.armSpeed.disabled = !ok;
    this.ui.hint.textContent = ok ? '' : hint || '';
  }

  // Roll only while commandable and held on a contact; a lost condition ends a running roll.
  updateRollButtons() {
    const ok = this.commandable && this.inContact;
    const why = ok ? '' : !this.commandable ? `Roll: ${String(this.notCommandable).replace(/\.$/, '')}.`
        : 'Roll: only while the robot holds on a contact (rolls along the object it touches).';
    for (const b of this.ui.rollButtons) {
      b.disabled = !ok;
      b.title = ok ? ROLL_TITLE : why;
    }
    this.ui.rollWhy.textContent = why;
    if (!ok) this.stopRoll();
  }

  startRoll(rate) {
    this.stopRoll();
    if (!this.commandable || !this.inContact) return;
    const send = () => robotCommand(this.ctx.api, this.robot.name, 'roll', {rate_rad_s: rate}).catch((err) => {
      this.stopRoll();
      this.ctx.status(`Roll: ${describe(err)}`, 'error');
    });
    send();
    this.rollTimer = setInterval(send, ROLL_REFRESH_MS);
  }

  stopRoll() {
    if (this.rollTimer) clearInterval(this.rollTimer);
    this.rollTimer = null;
  }

  async command(name, body, label) {
    if (!this.commandable) return;
    try {
      await robotCommand(this.ctx.api, this.robot.name, name, body);
      this.ctx.status(`${label}: sent`, 'ok');
    } catch (err) {
      this.ctx.status(`${label}: ${describe(err)}`, 'error');
    }
  }

  onMessage(topic, msg, stampMs) {
    if (topic === this.topicState) this.applyState(msg, stampMs);
    else if (topic === this.topicMap) {
      const n = this.ctx.view()?.setPointCloud(msg, `${ENTITY_PREFIX}map`, 0x58a6ff);
      this.mapDrawn = n;
    } else if (topic === this.topicPlanes) {
      for (const e of msg.entities || []) this.planeIds.add(e.id);
      // The plates drawn translucent: a plane's patch spans hundreds of millimetres and, opaque, hid
      // the segment and its disks behind it. Their colour (green: carries the bracing patch) stays.
      const entities = (msg.entities || []).map((e) => ({
        ...e, cubes: (e.cubes || []).map((c) => ({...c, color: {...(c.color || {r: 0.8, g: 0.6, b: 0.1}), a: Math.min(c.color?.a ?? 1, PLANE_OPACITY)}})),
      }));
      this.ctx.view()?.applySceneUpdate({...msg, entities});
    }
  }

  applyState(msg, stampMs) {
    const c = msg?.continuum;
    if (!c) return;
    this.lastState = c;
    this.stampMs = stampMs;
    const u = this.ui;
    const sup = c.supervisor || {};
    u.supervisor.textContent = SUPERVISOR_TEXT[sup.state] || (sup.state || 'unknown').replace(/_/g, ' ');
    u.supervisor.dataset.state = sup.state || '';
    u.supervisor.className = `rp-badge rp-${/stop|fault|hold/.test(sup.state || '') ? 'bad' : sup.state === 'slowed' ? 'warn' : 'ok'}`;
    u.reason.textContent = sup.reason || '';

    const scale = Number(c.speed_scale);
    u.scale.textContent = Number.isFinite(scale) ? scale.toFixed(3) : '—';
    u.scale.dataset.value = Number.isFinite(scale) ? String(scale) : '';
    u.scaleBar.style.width = `${Math.round(Math.min(1, Math.max(0, scale || 0)) * 100)}%`;
    u.scaleBar.style.background = `var(--${scale >= 0.999 ? 'go' : scale > 0 ? 'warn' : 'fault'})`;
    u.scaleDetail.textContent = `limit ${fmt(Number(c.speed_limit_mm_s), 2, 'mm/s')} · nearest ${
      c.nearest_mm === null || c.nearest_mm === undefined ? 'nothing in range' : fmt(Number(c.nearest_mm), 1, 'mm')}` +
        (Number.isFinite(Number(c.step_kept)) ? ` · step kept ${(Number(c.step_kept) * 100).toFixed(0)} %` : '');

    const contact = !!c.contact;
    this.inContact = contact;
    this.updateRollButtons();
    u.contact.dataset.contact = String(contact);
    u.contact.dataset.disk = contact && c.contact_disk !== null && c.contact_disk !== undefined ? String(c.contact_disk) : '';
    u.contact.dataset.slot = contact && c.contact_slot !== null && c.contact_slot !== undefined ? String(c.contact_slot) : '';
    u.contact.textContent = contact ? `CONTACT on disk ${c.contact_disk ?? '?'}, slot ${c.contact_slot ?? '?'}` +
        (Number.isFinite(Number(c.contact_slot)) ? ` (${(this.hallSlot0Deg + Number(c.contact_slot) * this.pitchDeg) % 360}°)` : '')
      : 'no contact';
    if (contact && Number.isFinite(Number(c.contact_force_n))) u.contact.textContent += ` · ${Number(c.contact_force_n).toFixed(2)} N`;
    u.contact.classList.toggle('rp-bad', contact);
    const sim = c.simulation;
    u.arm.textContent = sim ? `arm ${sim.arm_action || 'still'}${Array.isArray(sim.arm_centre_mm)
      ? ` at ${sim.arm_centre_mm.map((v) => Number(v).toFixed(0)).join(', ')} mm` : ''}` : 'no SIMULATED arm in this scene';

    for (const [m, b] of Object.entries(u.modeButtons)) {
      const on = c.hri_mode === m;
      b.setAttribute('aria-pressed', String(on));
      b.classList.toggle('btn-go', on);
    }

    const disks = Array.isArray(c.disks) ? c.disks : [];
    u.disks.replaceChildren(...disks.map((d) => {
      const force = Array.isArray(d.force_n) ? Math.max(...d.force_n.map((f) => Math.abs(Number(f)) || 0)) : NaN;
      const row = el('tr', {'data-testid': `continuum-disk-${d.index}`, 'data-contact': String(!!d.contact),
                            'data-fresh': String(d.fresh !== false)},
                     el('td', {text: String(d.index)}),
                     el('td', {text: d.nearest_mm === null || d.nearest_mm === undefined ? '—' : fmt(Number(d.nearest_mm), 1, 'mm')}),
                     el('td', {text: fmt(force, 2, 'N')}),
                     el('td', {text: d.contact ? `slot ${c.contact_disk === d.index ? c.contact_slot ?? '?' : '?'}` : ''}),
                     el('td', {text: d.fault ? d.fault : d.fresh === false ? 'silent' : 'ok'}));
      if (d.contact) row.classList.add('rp-bad');
      else if (d.fault || d.fresh === false) row.classList.add('rp-warn');
      return row;
    }));

    const map = c.map || {};
    u.map.textContent = `${Number(map.points) || 0} points · ${Number(map.planes) || 0} planes` +
        (Number.isFinite(Number(map.points_per_s)) ? ` · ${Number(map.points_per_s).toFixed(0)} points/s` : '');
    u.map.dataset.points = String(Number(map.points) || 0);
    u.map.dataset.planes = String(Number(map.planes) || 0);
    const br = map.bracing;
    u.bracing.dataset.admissible = br ? String(!!br.admissible) : '';
    u.bracing.textContent = br ? `bracing ${br.admissible ? 'ADMISSIBLE' : 'not admissible'}${br.reason ? `: ${br.reason}` : ''}` : 'bracing: not evaluated';
    u.bracing.className = `rp-verdict ${br ? (br.admissible ? 'rp-ok' : 'rp-warn') : ''}`;

    this.drawDisks(disks, c);
    this.updateAge();
  }

  // Slot markers around every disk, in the robot's base frame (the frame of its scene).
  drawDisks(disks, c) {
    const view = this.ctx.view();
    if (!view) return;
    const spheres = [];
    const lines = [];
    disks.forEach((d, i) => {
      if (!Array.isArray(d.position_mm) || d.position_mm.length !== 3 || !d.position_mm.every(Number.isFinite)) return;
      const {u, v} = diskAxes(disks, i, this.model());
      const p = d.position_mm;
      const ring = [];
      const r = this.ringMm;
      const onRim = (deg) => {
        const a = (deg * Math.PI) / 180;
        return [p[0] + r * (Math.cos(a) * u[0] + Math.sin(a) * v[0]),
                p[1] + r * (Math.cos(a) * u[1] + Math.sin(a) * v[1]),
                p[2] + r * (Math.cos(a) * u[2] + Math.sin(a) * v[2])];
      };
      // Marker sizes follow the disk (79 mm rim: 9.5 mm markers, 24 mm for the contact) to stay
      // readable at the zoom that shows the whole 370 mm segment.
      const marker = (at, size, color) => spheres.push({
        pose: {position: {x: at[0], y: at[1], z: at[2]}, orientation: {x: 0, y: 0, z: 0, w: 1}},
        size: {x: size, y: size, z: size}, color});
      // One marker per ToF window, coloured by its range.
      for (let k = 0; k < this.slots; k++) {
        const at = onRim(this.tofSlot0Deg + k * this.pitchDeg);
        ring.push({x: at[0], y: at[1], z: at[2]});
        const range = Array.isArray(d.ranges_mm) ? d.ranges_mm[k] : null;
        const color = d.fault || d.fresh === false ? GREY
                    : range === null || range === undefined || !Number.isFinite(Number(range)) ? GREY
                    : rampColor(Number(range) / this.dMax);
        marker(at, r * 0.12, color);
      }
      // The contact at its Hall window (between two ToF windows), large and red.
      if (d.contact && c.contact_disk === d.index && Number.isFinite(Number(c.contact_slot)))
        marker(onRim(this.hallSlot0Deg + Number(c.contact_slot) * this.pitchDeg), r * 0.3, RED);
      // The disk's rim: amber when the disk is silent or faulty, red in contact, else the nearest range's colour.
      const rim = d.contact ? RED : d.fault || d.fresh === false ? {r: 0.82, g: 0.6, b: 0.13, a: 1}
                : d.nearest_mm === null || d.nearest_mm === undefined ? GREY : rampColor(Number(d.nearest_mm) / this.dMax);
      lines.push({type: 1, points: ring, color: rim, thickness: 1});
    });
    view.applySceneUpdate({entities: [{id: `${ENTITY_PREFIX}disks`, frame_id: '', spheres, lines}]});
  }

  // Measured joints (stage_roll, bending, bending_plane) for the disks' orientation (diskAxes).
  onJointState(js) {
    if (!Array.isArray(js?.name) || !Array.isArray(js?.position)) return;
    const at = (n) => Number(js.position[js.name.indexOf(n)]);
    this.joints = {roll: at('stage_roll'), bending: at('bending'), plane: at('bending_plane')};
  }

  model() {
    const j = this.joints;
    const disks = this.info.disks || [];
    if (!j || ![j.roll, j.bending, j.plane].every(Number.isFinite) || !disks.length) return null;
    const arc = Object.fromEntries(disks.map((d) => [d.index, Number(d.arc_mm)]));
    const length = Number(this.info.segment?.length_mm) || Math.max(...disks.map((d) => Number(d.arc_mm) || 0));
    return {...j, arc, length};
  }

  updateAge() {
    if (!Number.isFinite(this.stampMs)) return;
    const age = this.ctx.ageMs ? this.ctx.ageMs(this.stampMs) : Date.now() - this.stampMs;
    this.ui.age.textContent = age < 1000 ? `${Math.max(0, Math.round(age))} ms` : `${(age / 1000).toFixed(1)} s`;
    this.ui.age.dataset.ageMs = String(Math.round(age));
  }

  destroy() {
    this.stopRoll();
    const view = this.ctx.view();
    if (!view) return;
    view.removeEntities(ENTITY_PREFIX);
    for (const id of this.planeIds) view.removeEntity(id);
    view.removePointCloud(`${ENTITY_PREFIX}map`);
  }
}
