// The Calibration sub-panel of the ultrasound panel (Heunis et al. 2021, §2.3): for every kind the robot
// lists in GET /robots (`calibrations.kinds`) its version in use, when it was taken, its residual and
// summary, and a Calibrate button (POST /robots/{r}/calibrate {"kind"}); while a routine runs its step
// and message; a refusal's sentence next to the button; the kinds the sweep still needs. Generic over
// the kinds: a kind a plug-in adds shows up without a change here.
import {el, fmt, describe, robotCommand} from './panel_kit.js';

// Kinds whose routine moves the arm, and what it needs for that: the robot–world calibration drives
// the probe through 12 poses in Cartesian control, so the server refuses it unless the arm is ENABLED
// in cartesian mode. Its button says so instead of being offered and then refused.
const NEEDS = {robot: {mode: 'cartesian'}};

function when(unixS) {
  if (!Number.isFinite(unixS)) return '—';
  return new Date(unixS * 1000).toISOString().replace('T', ' ').replace(/\.\d+Z$/, ' UTC');
}

export class CalibrationPanel {
  constructor(ctx, robot) {
    this.ctx = ctx;
    this.robot = robot;
    const info = robot.calibrations || {};
    this.kinds = Array.isArray(info.kinds) ? info.kinds : [];
    this.required = new Set(Array.isArray(info.required) ? info.required : []);
    this.commandable = false;
    this.running = null;
    this.rows = {};
    this.ui = {
      missing: el('div', {className: 'rp-reason', 'data-testid': 'us-cal-missing', role: 'status'}),
      running: el('div', {className: 'rp-detail', 'data-testid': 'us-cal-running', role: 'status', 'aria-live': 'polite'}),
      last: el('div', {className: 'rp-detail', 'data-testid': 'us-cal-last'}),
    };
    const rows = this.kinds.map((kind) => {
      const r = (this.rows[kind] = {
        state: el('div', {className: 'rp-detail', 'data-testid': `us-cal-${kind}`, 'data-version': '', text: `${kind}: none yet`}),
        message: el('div', {className: 'rp-reason', 'data-testid': `us-cal-${kind}-message`, role: 'status'}),
        button: el('button', {type: 'button', className: 'btn', 'data-testid': `us-cal-${kind}-calibrate`,
                              title: `run the ${kind} calibration routine`, text: `Calibrate ${kind}`,
                              onclick: () => this.calibrate(kind)}),
      });
      return el('div', {className: 'rp-cal-row', 'data-kind': kind}, r.state, el('div', {className: 'form-row'}, r.button), r.message);
    });
    this.element = el('div', {className: 'rp-calibrations', 'data-testid': 'us-calibrations'},
                      ...rows, this.ui.running, this.ui.last, this.ui.missing,
                      el('div', {className: 'rp-hint', text: info.store ? `store: ${info.store}` : ''}));
    this.updateButtons();
  }

  // robotState: {enabled, mode} of the arm (operating_state), for the kinds that move it.
  setCommandable(ok, robotState = {}) {
    this.commandable = ok;
    this.robotState = robotState;
    this.updateButtons();
  }

  // Why `kind` cannot be calibrated now, in words, or '' when it can.
  notNow(kind) {
    const need = NEEDS[kind];
    if (this.running) return `a ${this.running.kind} calibration is running`;
    if (!need || !this.robotState) return '';
    if (this.robotState.estop) return 'the e-stop is latched: Reset, then Enable';
    if (!this.robotState.enabled) return 'the arm moves through 12 poses: Enable it first';
    if (need.mode && this.robotState.mode !== need.mode) {
      return `the arm moves through 12 poses in ${need.mode} control: press the Cartesian mode button first ` +
          `(it is in ${String(this.robotState.mode || '?').replace(/_/g, ' ')} mode)`;
    }
    return '';
  }

  updateButtons() {
    for (const [kind, r] of Object.entries(this.rows)) {
      const why = this.commandable ? this.notNow(kind) : '';
      r.button.disabled = !this.commandable || !!this.running || !!why;
      r.button.title = why ? `Not now: ${why}` : `run the ${kind} calibration routine`;
      r.button.dataset.why = why;
      // The reason in view beside the button, until it no longer holds.
      if (why) {
        r.message.textContent = `Not now: ${why}`;
        r.message.dataset.why = 'true';
      } else if (r.message.dataset.why === 'true') {
        r.message.textContent = '';
        r.message.dataset.why = '';
      }
    }
  }

  async calibrate(kind) {
    const r = this.rows[kind];
    r.message.textContent = 'sending…';
    r.message.dataset.refused = 'false';
    r.message.dataset.why = '';
    try {
      await robotCommand(this.ctx.api, this.robot.name, 'calibrate', {kind});
      r.message.textContent = 'started';
      this.ctx.status(`Calibration ${kind}: started`, 'ok');
    } catch (err) {
      // The server's sentence says why (a sweep runs, the wrong mode, another routine…).
      r.message.textContent = describe(err);
      r.message.dataset.refused = 'true';
      this.ctx.status(`Calibration ${kind}: ${describe(err)}`, 'error');
    }
  }

  // `c` is operating_state.calibration (also on /{robot}/sweep).
  apply(c) {
    if (!c || typeof c !== 'object') return;
    for (const kind of this.kinds) {
      const r = this.rows[kind];
      const v = c[kind];
      if (v && typeof v === 'object') {
        r.state.textContent = `${kind}: version ${v.version} · ${when(Number(v.taken_unix_s))} · residual ` +
            `${fmt(Number(v.residual_mm), 2, 'mm')} — ${v.summary || ''}`;
        r.state.dataset.version = String(v.version);
      } else {
        r.state.textContent = `${kind}: none yet${this.required.has(kind) ? ' (the sweep needs one)' : ''}`;
        r.state.dataset.version = '';
      }
    }
    this.running = c.running || null;
    if (this.running) {
      this.ui.running.textContent = `${this.running.kind}: step ${this.running.step} of ${this.running.steps || '?'} — ${this.running.message || ''}`;
      this.ui.running.dataset.kind = this.running.kind;
    } else {
      this.ui.running.textContent = '';
      this.ui.running.dataset.kind = '';
    }
    const last = c.last;
    this.ui.last.textContent = last ? `last ${last.kind} calibration ${last.ok ? 'succeeded' : 'FAILED'}: ${last.message}` : '';
    this.ui.last.dataset.ok = last ? String(!!last.ok) : '';
    const missing = Array.isArray(c.missing) ? c.missing : [];
    this.ui.missing.textContent = missing.length ? `the sweep needs: ${missing.join(', ')}` : '';
    this.ui.missing.dataset.missing = missing.join(',');
    this.updateButtons();
  }
}
