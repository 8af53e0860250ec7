// Steerable-catheter panel: spring-deflection gauges and wall force, configuration sliders in degrees
// (move_configuration), and the operator's joystick: an on-screen pad plus sliders and the browser
// Gamepad API, both publishing {axes: [insertion, roll, proximal, distal], deadman} at 30 Hz (scaled by
// the speed preset), and only
// while the operator-presence (deadman) control is held. Releasing it, leaving the page or losing
// focus sends deadman:false at once and stops sending.
const DEG = Math.PI / 180;
const SEND_PERIOD_MS = 33;  // 30 Hz: well inside the 150 ms command timeout
// Standard Gamepad mapping (https://w3c.github.io/gamepad/#remapping): left stick x/y, right stick x/y,
// shoulder buttons 4 (LB) and 5 (RB).
const GAMEPAD_MAP = 'left stick ↔ proximal, ↕ distal · right stick ↔ roll, ↕ insertion · hold LB or RB';

// Configuration indices: 0 insertion (mm), 1 roll, 2 proximal bend, 3 distal bend (rad in the API,
// degrees here).
const API_NAMES = ['insertion', 'roll', 'theta_proximal', 'theta_distal'];
const LABELS = ['insertion', 'roll', 'proximal bend θ', 'distal bend θ'];
const PREVIEW_ORDER = [2, 3, 0, 1];

const clamp1 = (v) => Math.max(-1, Math.min(1, Number.isFinite(v) ? v : 0));
const fmt = (v, digits = 1) => (Number.isFinite(v) ? v.toFixed(digits) : '—');

import {operatorWords} from './words.js';

export class CatheterPanel {
  constructor(root, api, {robotName, showStatus}) {
    this.root = root;
    this.api = api;
    this.robotName = robotName;
    this.showStatus = showStatus;
    this.operating = null;
    this.deadmanPointer = false;
    this.deadmanKey = false;
    this.deadmanGamepad = false;
    this.commandable = true;   // false while the page shows stale data or is disconnected
    this.viewer = false;       // a viewer session commands nothing
    this.pad = {x: 0, y: 0};
    this.padPointer = false;   // a pointer drags the pad
    this.dragFrom = null;      // where a pointer pressed the deadman (its drag steers the bend)
    this.sending = false;
    this.lastError = '';
    this.timer = null;
    const q = (id) => root.querySelector(`[data-testid="${id}"]`);
    this.el = {
      hold: q('hold-banner'),
      gauges: [q('gauge-proximal'), q('gauge-distal')],
      contact: q('contact-force'),
      bend: q('tip-bend'),
      pad: q('stick-pad'),
      knob: root.querySelector('.stick-knob'),
      insertion: q('stick-insertion'),
      roll: q('stick-roll'),
      deadman: q('deadman-button'),
      status: q('joystick-status'),
      gamepad: q('gamepad-status'),
      guidance: q('image-guidance'),
      guidanceStatus: q('guidance-status'),
      guidanceDrive: q('guidance-drive'),
      guidanceMeasured: q('guidance-measured'),
      guidanceTarget: q('guidance-target'),
      guidanceReplans: q('guidance-replans'),
      move: q('cfg-move-button'),
      fromCurrent: q('cfg-from-current-button'),
      preview: q('cfg-preview'),
      speedButtons: [...root.querySelectorAll('[data-speed]')],
      speedReadout: q('speed-readout'),
    };
    this.speed = 0.5;          // the joystick's speed preset (fraction of full-stick speed)
    this.sliders = ['theta-proximal', 'theta-distal', 'insertion', 'roll'].map((name) => ({
      name,
      range: root.querySelector(`#cfg-${name}`),
      number: root.querySelector(`#cfg-${name}-num`),
      now: q(`cfg-${name}-now`),
      touched: false,
      live: NaN,
    }));
    this.wire();
  }

  // Slider ranges from GET /robots: configuration bounds (rad) shown in degrees.
  setRobot(robot) {
    this.robotName = robot.name;
    const c = robot.configuration;
    if (!c) return;
    const toUi = (i, v) => (i === 0 ? v : v / DEG);
    const order = [2, 3, 0, 1];  // slider order: θ proximal, θ distal, insertion, roll
    this.sliders.forEach((s, k) => {
      const i = order[k];
      for (const input of [s.range, s.number]) {
        input.min = String(Math.ceil(toUi(i, c.lower[i]) * 2) / 2);
        input.max = String(Math.floor(toUi(i, c.upper[i]) * 2) / 2);
      }
      s.index = i;
    });
    this.limit = robot.spring_deflection_limit_mm;
    this.joints = robot.joints;
    this.fullSpeed = robot.telemanipulation_max_speed;
    this.renderSpeed();
    this.clearTouched();
  }

  wire() {
    for (const s of this.sliders) {
      const touch = () => {
        s.touched = true;
        s.number.classList.add('edited');
        this.renderPreview();
      };
      s.range.addEventListener('input', () => { s.number.value = s.range.value; touch(); });
      s.number.addEventListener('input', () => { s.range.value = s.number.value; touch(); });
    }
    this.el.fromCurrent.addEventListener('click', () => this.clearTouched());
    for (const b of this.el.speedButtons) b.addEventListener('click', () => this.setSpeed(Number(b.dataset.speed)));
    this.el.move.addEventListener('click', () => this.moveConfiguration());

    // Deadman: held by pointer (button), Space key, or a gamepad shoulder button. With a single mouse
    // the button is also the stick: hold it and drag, and the drag steers the bend (x proximal, up
    // distal) as the pad would; let go and both spring back.
    const d = this.el.deadman;
    d.addEventListener('pointerdown', (ev) => {
      ev.preventDefault();
      d.setPointerCapture?.(ev.pointerId);
      this.deadmanPointer = true;
      this.dragFrom = {x: ev.clientX, y: ev.clientY, steering: false};
      this.refresh();
    });
    d.addEventListener('pointermove', (ev) => {
      const from = this.dragFrom;
      if (!this.deadmanPointer || !from || this.padPointer) return;  // a second finger on the pad wins
      const dx = ev.clientX - from.x;
      const dy = ev.clientY - from.y;
      if (!from.steering && Math.hypot(dx, dy) < 4) return;  // a hand holding still is not a drag
      from.steering = true;
      const reach = this.el.pad.getBoundingClientRect().width * 0.45 || 50;  // the knob's travel
      this.pad = {x: clamp1(dx / reach), y: clamp1(-dy / reach)};
      this.drawKnob();
    });
    for (const type of ['pointerup', 'pointercancel', 'lostpointercapture']) {
      d.addEventListener(type, () => {
        if (this.dragFrom?.steering && !this.padPointer) this.pad = {x: 0, y: 0};
        this.dragFrom = null;
        this.deadmanPointer = false;
        this.drawKnob();
        this.refresh();
      });
    }
    // Space is the deadman wherever it does not type: on a slider, a button, the pad or the page (a
    // slider with focus used to swallow it, and the deadman stopped working without a word). Its
    // default action is prevented, so it neither scrolls nor presses the focused button. In a text or
    // number field or a list it stays a key for that field; on a focused E-STOP it presses the E-STOP.
    const typesSpace = (t) => !!t && (t.isContentEditable || t.tagName === 'TEXTAREA' || t.tagName === 'SELECT' ||
        (t.tagName === 'INPUT' && !['range', 'button', 'submit', 'reset', 'checkbox', 'radio', 'color', 'file'].includes(t.type)) ||
        !!t.closest?.('.estop'));
    document.addEventListener('keydown', (ev) => {
      if (ev.code !== 'Space' || this.root.hidden || typesSpace(ev.target)) return;
      ev.preventDefault();
      if (ev.repeat) return;
      this.deadmanKey = true;
      this.refresh();
    });
    document.addEventListener('keyup', (ev) => {
      if (ev.code !== 'Space') return;
      // The release is never missed, whatever has focus now; a button that had it is not pressed.
      if (this.deadmanKey) ev.preventDefault();
      this.deadmanKey = false;
      this.refresh();
    });
    const releaseAll = () => {
      this.deadmanPointer = this.deadmanKey = this.deadmanGamepad = false;
      this.centre();
      this.refresh();
    };
    window.addEventListener('blur', releaseAll);
    document.addEventListener('visibilitychange', () => { if (document.hidden) releaseAll(); });

    // On-screen pad: drag; x = proximal, y (up) = distal; springs back to the centre on release.
    const pad = this.el.pad;
    const fromEvent = (ev) => {
      const r = pad.getBoundingClientRect();
      this.pad.x = clamp1(((ev.clientX - r.left) / r.width) * 2 - 1);
      this.pad.y = clamp1(1 - ((ev.clientY - r.top) / r.height) * 2);
      this.drawKnob();
    };
    pad.addEventListener('pointerdown', (ev) => {
      pad.setPointerCapture?.(ev.pointerId);
      this.padPointer = true;
      fromEvent(ev);
    });
    pad.addEventListener('pointermove', (ev) => { if (ev.buttons) fromEvent(ev); });
    for (const type of ['pointerup', 'pointercancel']) {
      pad.addEventListener(type, () => { this.padPointer = false; this.pad = {x: 0, y: 0}; this.drawKnob(); });
    }
    pad.addEventListener('keydown', (ev) => {
      const step = 0.25;
      const moves = {ArrowLeft: [-step, 0], ArrowRight: [step, 0], ArrowUp: [0, step], ArrowDown: [0, -step]};
      if (!moves[ev.key]) return;
      ev.preventDefault();
      this.pad.x = clamp1(this.pad.x + moves[ev.key][0]);
      this.pad.y = clamp1(this.pad.y + moves[ev.key][1]);
      this.drawKnob();
    });
    pad.addEventListener('blur', () => { this.pad = {x: 0, y: 0}; this.drawKnob(); });
    for (const slider of [this.el.insertion, this.el.roll]) {
      // Speed sliders spring back to zero when let go, like a stick.
      for (const type of ['pointerup', 'pointercancel', 'blur']) slider.addEventListener(type, () => { slider.value = '0'; });
    }
    this.timer = setInterval(() => this.tick(), SEND_PERIOD_MS);
  }

  centre() {
    this.pad = {x: 0, y: 0};
    this.el.insertion.value = '0';
    this.el.roll.value = '0';
    this.drawKnob();
  }

  drawKnob() {
    this.el.knob.style.left = `${50 + this.pad.x * 45}%`;
    this.el.knob.style.top = `${50 - this.pad.y * 45}%`;
    this.el.pad.setAttribute('aria-valuenow', fmt(this.pad.x, 2));
    this.el.pad.setAttribute('aria-valuetext', `proximal ${fmt(this.pad.x, 2)}, distal ${fmt(this.pad.y, 2)}`);
  }

  get deadman() { return this.deadmanPointer || this.deadmanKey || this.deadmanGamepad; }

  readGamepad() {
    const pads = typeof navigator.getGamepads === 'function' ? [...navigator.getGamepads()].filter(Boolean) : [];
    const gp = pads[0];
    if (!gp) {
      this.deadmanGamepad = false;
      this.el.gamepad.textContent = 'gamepad: none connected';
      return null;
    }
    this.el.gamepad.textContent = `gamepad: ${gp.id.slice(0, 40)} — ${GAMEPAD_MAP}`;
    const pressed = (i) => !!(gp.buttons[i] && gp.buttons[i].pressed);
    this.deadmanGamepad = pressed(4) || pressed(5);
    const dead = (v) => (Math.abs(v) < 0.08 ? 0 : v);  // stick rest noise
    return [-dead(gp.axes[3] ?? 0), dead(gp.axes[2] ?? 0), dead(gp.axes[0] ?? 0), -dead(gp.axes[1] ?? 0)];
  }

  axes(gamepadAxes) {
    const screen = [Number(this.el.insertion.value), Number(this.el.roll.value), this.pad.x, this.pad.y];
    // The on-screen controls win when touched; otherwise the gamepad. The speed preset scales what is
    // sent: the server moves a joint at axis × its full-stick speed (telemanipulation_max_speed).
    const touched = screen.some((v) => v !== 0);
    return (touched || !gamepadAxes ? screen : gamepadAxes).map((v) => clamp1(v) * this.speed);
  }

  // Speed preset: the fraction of the full-stick speed the joystick commands (slow ¼, normal ½, fast 1).
  setSpeed(fraction) {
    this.speed = fraction;
    for (const b of this.el.speedButtons) b.setAttribute('aria-pressed', String(Number(b.dataset.speed) === fraction));
    this.renderSpeed();
  }

  // The top speed of each joint at full stick with the preset, in the joint's units (rad/s as °/s).
  renderSpeed() {
    const full = this.fullSpeed;
    const joints = this.joints || [];
    if (!Array.isArray(full) || full.length !== joints.length) {
      this.el.speedReadout.textContent = `${Math.round(this.speed * 100)} % of full speed`;
      return;
    }
    const parts = joints.map((j, i) => {
      const v = full[i] * this.speed;
      const text = j.unit === 'rad' ? `${fmt(v / DEG, 0)}°/s` : `${fmt(v, v < 1 ? 2 : 1)} ${j.unit}/s`;
      return `${j.name.replace(/_/g, ' ')} ${text}`;
    });
    this.el.speedReadout.textContent = `full stick: ${parts.join(', ')}`;
    this.el.speedReadout.title = `${Math.round(this.speed * 100)} % of the full-stick speed the server allows ` +
        `(telemanipulation_max_speed, within each joint's max_velocity)`;
  }

  // 30 Hz: publish while the deadman is held; one deadman:false when it is let go.
  async tick() {
    if (this.root.hidden && !this.sending) return;  // nothing to read or send while the panel is closed
    const gamepadAxes = this.readGamepad();
    const mode = this.operating?.mode;
    const movable = mode === 'telemanipulation' || mode === 'active_compliance' || mode === 'image_guided' ||
        this.operating?.retraction_only;
    // Stale data or a viewer session: the deadman counts as released (one deadman:false goes out).
    const held = this.deadman && movable && !this.root.hidden && this.commandable && !this.viewer;
    this.el.deadman.setAttribute('aria-pressed', String(this.deadman));
    this.el.deadman.classList.toggle('held', this.deadman);
    if (!held && !this.sending) return;
    const axes = this.axes(gamepadAxes);
    // Image-guided: the operator owns insertion only (the replanner steers roll and bends; the server
    // ignores the other axes there too), so a drag on the deadman sends no bend at all.
    if (mode === 'image_guided') axes.fill(0, 1);
    this.sending = held;
    try {
      await this.api.joystick(this.robotName, axes, held);
      this.lastError = '';
    } catch (err) {
      const text = `Joystick: ${err.message || err}`;
      if (text !== this.lastError) this.showStatus(text, 'error');
      this.lastError = text;
    }
  }

  setCommandable(commandable) {
    this.commandable = commandable;
    this.updateMoveButton();
  }

  setViewer(viewer) {
    this.viewer = viewer;
    this.el.deadman.disabled = viewer;
    this.updateMoveButton();
  }

  refresh() {
    this.el.deadman.setAttribute('aria-pressed', String(this.deadman));
    this.el.deadman.classList.toggle('held', this.deadman);
  }

  // Untouched fields show the live configuration; a field the surgeon touched keeps its value until
  // it is sent or cleared. Only touched fields go into the command (the server takes every other value
  // from the robot's state when the command arrives), so nothing moves that nobody set.
  showLive() {
    const c = this.operating?.configuration;
    if (!Array.isArray(c)) return;
    for (const s of this.sliders) {
      s.live = s.index === 0 ? c[0] : c[s.index] / DEG;
      // Not while the field has focus: the live value would land in the middle of the surgeon's typing
      // (the selection is lost and the keys are appended: "15" typed became 0.115).
      const focused = document.activeElement === s.number || document.activeElement === s.range;
      if (!s.touched && !focused) s.range.value = s.number.value = fmt(s.live, 1);
    }
    this.renderPreview();
  }

  // A configuration goal typed and not yet sent, and what it says ("proximal bend θ 0.0° → 5.0°").
  hasGoal() { return this.sliders.some((s) => s.touched); }
  goalText() { return this.el.preview.textContent.replace(/^will move: /, '').split(' · ')[0]; }

  clearTouched() {
    for (const s of this.sliders) {
      s.touched = false;
      s.number.classList.remove('edited');
    }
    this.showLive();
  }

  // The goal the Move button would send: {name: value in API units} of the touched fields only.
  goal() {
    const goal = {};
    for (const s of this.sliders) {
      if (!s.touched || s.number.value.trim() === '') continue;
      const v = Number(s.number.value);
      goal[API_NAMES[s.index]] = Number.isFinite(v) ? (s.index === 0 ? v : v * DEG) : NaN;
    }
    return goal;
  }

  // "will move: proximal bend θ 0.0° → 5.0° · insertion 30.0 mm (unchanged), …"
  renderPreview() {
    const moving = [];
    const still = [];
    for (const k of PREVIEW_ORDER) {
      const s = this.sliders.find((x) => x.index === k);
      const unit = k === 0 ? ' mm' : '°';
      const now = `${fmt(s.live, 1)}${unit}`;
      const v = Number(s.number.value);
      if (s.touched && s.number.value.trim() !== '' && Number.isFinite(v)) moving.push(`${LABELS[k]} ${now} → ${fmt(v, 1)}${unit}`);
      else still.push(`${LABELS[k]} ${now} (unchanged)`);
    }
    const bad = this.sliders.filter((s) => s.touched && !Number.isFinite(Number(s.number.value)));
    this.el.preview.dataset.moves = String(moving.length);
    this.el.preview.textContent = bad.length ? `${bad.map((s) => LABELS[s.index]).join(', ')}: not a number`
        : moving.length ? `will move: ${moving.join(', ')} · ${still.join(', ')}`
        : 'Nothing set yet: type or drag the value you want to change; the rest stays as it is.';
    this.updateMoveButton();
  }

  async moveConfiguration() {
    const goal = this.goal();
    const names = Object.keys(goal);
    if (!names.length) {
      this.showStatus('Configuration: nothing set; type or drag the value you want to change', 'error');
      return;
    }
    if (names.some((k) => !Number.isFinite(goal[k]))) {
      this.showStatus('Configuration: a value is not a number', 'error');
      return;
    }
    try {
      const answer = await this.api.moveConfiguration(this.robotName, goal);
      this.showStatus(`Moving to the configuration (${fmt(answer.duration_s, 1)} s): ${this.el.preview.textContent.replace(/^will move: /, '').split(' · ')[0]}`, 'ok');
      this.clearTouched();
    } catch (err) {
      this.showStatus(`Configuration refused: ${err.message || err}`, 'error');
    }
  }

  update(os) {
    this.operating = os;
    this.showLive();
    const limit = os.spring_deflection_limit_mm || this.limit || 1;
    const d = Array.isArray(os.spring_deflection_mm) ? os.spring_deflection_mm : null;
    this.el.gauges.forEach((g, i) => {
      const track = g.querySelector('.gauge-track');
      const bar = g.querySelector('.gauge-bar');
      const value = g.querySelector('.gauge-value');
      if (!d) {
        g.dataset.level = 'stale';
        bar.style.width = '0';
        value.textContent = 'no reading';
        track.setAttribute('aria-valuetext', 'no reading');
        return;
      }
      const f = Math.max(-1, Math.min(1, d[i] / limit));
      bar.style.left = f >= 0 ? '50%' : `${50 + f * 50}%`;
      bar.style.width = `${Math.abs(f) * 50}%`;
      g.dataset.level = Math.abs(f) >= 1 ? 'over' : Math.abs(f) > 0.66 ? 'high' : 'ok';
      value.textContent = `${fmt(d[i], 2)} mm`;
      track.setAttribute('aria-valuenow', fmt(f, 2));
      track.setAttribute('aria-valuetext', `${fmt(d[i], 2)} mm of ±${fmt(limit, 1)} mm`);
    });
    const contact = os.contact_force_n;
    this.el.contact.textContent = contact === null || contact === undefined
        ? 'wall force: not measured'
        : `wall force ${fmt(contact, 3)} N (bound ${fmt(os.max_contact_force_n, 2)} N, simulated)`;
    this.el.contact.dataset.over = String(Number(contact) > Number(os.max_contact_force_n));
    const bend = os.simulation?.tip_bend_rad;
    this.el.bend.textContent = Number.isFinite(bend) ? `tip bend ${fmt(bend / DEG, 1)}° (simulated)` : '';
    const c = os.configuration;
    if (Array.isArray(c)) {
      for (const s of this.sliders) s.now.textContent = s.index === 0 ? `${fmt(c[0], 1)} mm` : `${fmt(c[s.index] / DEG, 1)}°`;
    }
    // The same cause and way out as the banner, next to the gauges they are about.
    const hold = os.state === 'PAUSED' && os.hold && os.hold.message ? os.hold : null;
    this.el.hold.hidden = !hold;
    if (hold) this.el.hold.textContent = operatorWords(`Held: ${hold.message}. ${hold.next || ''}`);
    this.renderGuidance(os.image_guidance, os);
    const j = os.joystick || {};
    const guided = os.mode === 'image_guided';
    this.el.status.textContent = j.conflict ? 'two joysticks hold their deadman: nothing moves'
        : j.source ? `moving from ${j.source} joystick` + (guided ? ' (insertion; the replanner steers)' : '') +
          (j.deadman ? '' : ' (deadman released)')
        : this.deadman ? 'deadman held — waiting for the robot (telemanipulation, active compliance or image-guided mode)'
        : 'no joystick input';
    this.updateMoveButton();
  }

  // operating_state.image_guidance (null outside the mode): what the loop does and why, in words.
  // The loop's word follows the robot's state: "tracking" only while the robot can follow (it said
  // tracking while PAUSED with both bend drives held).
  renderGuidance(g, os = this.operating) {
    this.el.guidance.hidden = !g;
    if (!g) return;
    const words = {
      waiting: 'waiting for the first tip fix',
      tracking: 'tracking: roll and bends follow the replanned targets',
      not_found: 'tip not found in the images',
      refused: 'tip fix refused',
      lost: 'tracking lost: the bends hold; insertion stays with you',
    };
    const moving = os && os.state === 'ENABLED' && !os.estop;
    if (!moving && !g.tracking_lost) {
      words[g.status] = `not following: the robot is ${os?.estop ? 'E-STOPPED' : String(os?.state || '?')}` +
          `${os?.state === 'PAUSED' ? ' (held: the bends stay where they are until Resume)' : ''}`;
    }
    const status = g.tracking_lost ? 'lost' : g.status;
    const age = Number.isFinite(g.tracking_age_s) ? ` · last fix ${fmt(g.tracking_age_s, 1)} s ago` : '';
    this.el.guidanceStatus.dataset.status = status;
    this.el.guidanceStatus.textContent = `${words[status] || status}${g.reason ? ` (${g.reason})` : ''}${age}`;
    this.el.guidanceDrive.textContent = `${fmt(g.drive_insertion_mm, 1)} mm`;
    this.el.guidanceMeasured.textContent = Number.isFinite(g.measured_insertion_mm)
        ? `${fmt(g.measured_insertion_mm, 1)} mm (images ${fmt(g.image_insertion_mm, 1)} mm)` : '—';
    const t = Array.isArray(g.replanned_target) ? g.replanned_target : null;
    this.el.guidanceTarget.textContent = t
        ? `${fmt(t[1] / DEG, 1)}° · ${fmt(t[2] / DEG, 1)}° · ${fmt(t[3] / DEG, 1)}°` : '—';
    this.el.guidanceReplans.textContent = String(g.replans ?? 0);
  }

  updateMoveButton() {
    const os = this.operating;
    const configurationMode = os?.mode === 'configuration';
    const set = Number(this.el.preview.dataset.moves) > 0;
    this.el.move.disabled = !configurationMode || os?.state !== 'ENABLED' || !set || !this.commandable || this.viewer;
    this.el.move.title = this.viewer ? 'Viewer session: watch only' : !this.commandable ? 'Stale data: wait for fresh data'
        : !configurationMode ? 'Switch to Configuration mode to move in bend angles'
        : os?.state !== 'ENABLED' ? 'The robot must be ENABLED to move' : !set ? 'Set a value first' : '';
  }
}
