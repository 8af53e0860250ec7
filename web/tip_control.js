// The Tip tab (issue 31 item 7): the tip or tool of a robot with a Cartesian mode — the arm's cartesian
// mode (serial_arm), the variable-diameter robot's task mode (mbcr_vd), the continuum robot's tip mode
// (sdu_continuum). It shows where the tip is (GET measured_cp, mm), jogs it along an axis while a button
// is held (servo_cv, refreshed within the robot's command timeout, a zero twist on release), moves it
// to a typed position after showing what will move (move_cp, the orientation kept), and for a robot
// with a force sensor shows the measured force against its limit, as a number and a plot.
import {el, group, fmt, describe, holdToRun} from './panel_kit.js';
import {TimePlot} from './plot.js';
import {operatorWords} from './words.js';
import {STALE_MS} from './live.js';

// The mode in which each kind takes Cartesian commands, and whether it takes a goal pose (move_cp):
// the continuum robot's three joints place its tip but cannot also hold an orientation, so its server
// takes servo_cv only (sdu_robot.cpp).
const CARTESIAN_MODES = {serial_arm: 'cartesian', mbcr_vd: 'task', sdu_continuum: 'tip'};
const TAKES_GOAL = {serial_arm: true, mbcr_vd: true, sdu_continuum: false};
const POLL_MS = 100;
const JOG_REFRESH_MS = 50;  // well within every robot's 150 ms command timeout
const JOG_SPEEDS_MM_S = [1, 5, 10];
const AXES = ['x', 'y', 'z'];

const title = (mode) => mode.charAt(0).toUpperCase() + mode.slice(1);

// The robot's Cartesian mode, or null when it has none.
export function cartesianModeOf(robot) {
  const mode = CARTESIAN_MODES[robot?.kind];
  return mode && Array.isArray(robot.modes) && robot.modes.includes(mode) ? mode : null;
}

// What a goal will do from where the tip is: {text, distance} (pure: tested through the page).
export function goalPreview(current, goal) {
  const d = goal.map((v, i) => v - current[i]);
  const distance = Math.hypot(...d);
  const parts = AXES.map((a, i) => `${a} ${d[i] >= 0 ? '+' : '−'}${Math.abs(d[i]).toFixed(1)}`);
  return {distance, text: `will move: ${parts.join(', ')} mm (${distance.toFixed(1)} mm in a straight line), orientation kept`};
}

export class TipPanel {
  // container: the tab panel; ctx: {api, status(text, kind)}.
  constructor(container, ctx) {
    this.container = container;
    this.ctx = ctx;
    this.robot = null;
    this.timer = null;
    this.commandable = false;
    this.hint = 'Waiting for the robot state…';
    this.robotState = {};
    this.pose = null;
    this.edited = false;
    this.jogAxis = null;
  }

  setRobot(robot) {
    if (robot?.name === this.robot?.name) return;
    this.stopJog();
    clearInterval(this.timer);
    this.robot = robot;
    this.pose = null;
    this.edited = false;
    this.container.replaceChildren();
    // The previous robot's controls are gone: nothing may update them (a robot without a Cartesian
    // mode has none, and the page's state updates keep coming).
    this.ui = null;
    this.mode = cartesianModeOf(robot);
    if (!this.mode) {
      this.timer = null;
      return;
    }
    this.build();
    this.timer = setInterval(() => this.poll(), POLL_MS);
  }

  build() {
    const robot = this.robot;
    const u = (this.ui = {});
    const tool = robot.kind === 'serial_arm' ? 'tool' : 'tip';
    this.tool = tool;
    u.position = el('div', {className: 'rp-big tip-position', 'data-testid': 'cart-position', role: 'status', text: '—'});
    u.frame = el('div', {className: 'rp-detail', 'data-testid': 'cart-frame'});
    u.age = el('span', {className: 'age', 'data-testid': 'cart-age', text: 'no data'});

    // Jog: a pair of buttons per axis, held to move. The press itself is the operator's presence: the
    // stream stops on release, on leaving the button, when the page loses focus and on E-STOP.
    u.jogButtons = [];
    const rows = AXES.map((axis, i) => {
      const button = (sign) => {
        const b = el('button', {type: 'button', className: 'btn tip-jog', 'data-testid': `cart-jog-${axis}-${sign > 0 ? 'plus' : 'minus'}`,
                                text: `${axis.toUpperCase()} ${sign > 0 ? '+' : '−'}`,
                                'aria-label': `Hold to move the ${tool} along ${axis} ${sign > 0 ? 'plus' : 'minus'}`});
        holdToRun(b, {start: () => this.startJog(i, sign), stop: () => this.stopJog('released')});
        u.jogButtons.push(b);
        return b;
      };
      return el('div', {className: 'form-row tip-jog-row'}, button(-1), button(1));
    });
    u.speed = el('select', {'data-testid': 'cart-jog-speed', 'aria-label': 'Jog speed'},
                 JOG_SPEEDS_MM_S.map((v) => el('option', {value: String(v), text: `${v} mm/s`})));
    u.speed.value = '5';
    u.jogWhy = el('div', {className: 'rp-hint', 'data-testid': 'cart-jog-why', role: 'status'});
    u.jogging = el('div', {className: 'rp-detail', 'data-testid': 'cart-jogging', text: 'not moving'});

    // Goal: typed in mm, previewed, sent with Go.
    u.goal = AXES.map((axis) => el('input', {type: 'number', step: '0.5', className: 'rp-num', 'data-testid': `cart-goal-${axis}`,
                                             'aria-label': `Goal ${axis} in mm`, oninput: () => this.goalTyped()}));
    u.fromCurrent = el('button', {type: 'button', className: 'btn btn-small', 'data-testid': 'cart-goal-clear', text: 'From current',
                                  onclick: () => this.clearGoal()});
    u.go = el('button', {type: 'button', className: 'btn btn-go', 'data-testid': 'cart-go', text: 'Go', onclick: () => this.go()});
    u.preview = el('div', {className: 'move-preview', 'data-testid': 'cart-preview', role: 'status', 'aria-live': 'polite'});
    u.goWhy = el('div', {className: 'rp-hint', 'data-testid': 'cart-go-why', role: 'status'});

    const modeNote = `(${title(this.mode)} mode)`;
    const parts = [
      el('div', {className: 'panel-age'}, `${tool} position `, u.age),
      group(`${title(tool)} position`, `(mm, in the robot's base frame)`, u.position, u.frame),
    ];
    this.addForce(parts);
    parts.push(
      group(`Jog the ${tool}`, `(${title(this.mode)} mode; hold a button)`,
            el('div', {className: 'form-row'}, el('label', {className: 'rp-label'}, 'speed ', u.speed)),
            el('div', {className: 'tip-jog-grid'}, rows), u.jogging, u.jogWhy),
      group(`Move the ${tool} to`, modeNote,
            el('div', {className: 'form-row'}, AXES.map((a, i) => el('label', {className: 'rp-label'}, `${a} `, u.goal[i])), u.fromCurrent),
            u.preview, el('div', {className: 'form-row'}, u.go), u.goWhy));
    this.container.append(...parts);
    this.update();
  }

  // The arm's force sensor (3 axes at the flange: no torque), right under the position.
  addForce(parts) {
    const u = this.ui;
    const robot = this.robot;
    this.force = robot.arm?.force ? {limit: Number(robot.arm.force.max_contact_force_n)} : null;
    if (this.force) {
      u.force = el('div', {className: 'rp-big cart-force', 'data-testid': 'cart-force', role: 'status', text: '—'});
      u.forceDetail = el('div', {className: 'rp-detail', 'data-testid': 'cart-force-detail'});
      u.forceCanvas = el('canvas', {'data-testid': 'cart-force-plot', role: 'img', 'aria-label': 'Measured force over time (N)'});
      parts.push(group('Measured force', `(limit ${fmt(this.force.limit, 1, 'N')}; torque is not measured: 3-axis sensor)`,
                       u.force, u.forceDetail, el('div', {className: 'plot-box rp-plot'}, u.forceCanvas)));
      this.forcePlot = new TimePlot(u.forceCanvas, {
        series: [{label: 'contact force', color: '#4ea1ff', format: (v) => `${v.toFixed(2)} N`},
                 {label: `limit ${this.force.limit.toFixed(1)} N`, color: '#f85149', dash: true}],
        windowS: 20, unit: 'N', minSpan: 1, floorZero: true,
      });
    }
  }

  // From the console (app.js): commands allowed (lease, fresh data, not a viewer) or why not, and the
  // robot's state {enabled, estop, mode}.
  setCommandable(ok, hint, robotState = {}) {
    this.commandable = ok;
    this.hint = hint;
    this.robotState = robotState;
    if (this.ui) this.update();
  }

  // Why a motion cannot start now, in words, or '' when it can.
  blocked() {
    const s = this.robotState;
    if (!this.commandable) return this.hint || 'Commands are not available.';
    if (s.estop) return 'E-STOP latched: Reset, then Enable.';
    // The mode first: it may be chosen while disabled, and a freshly enabled arm refuses a mode switch
    // while it settles.
    if (s.mode !== this.mode) {
      return `Press the ${title(this.mode)} mode button${s.enabled ? '' : ', then Enable'} (the ${this.tool} moves in ${title(this.mode)} mode).`;
    }
    if (!s.enabled) return 'Enable the robot first.';
    // An enabled robot's drives take a moment to switch on; the server refuses a move until they have.
    if (s.drivesReady === false) return 'The drives are switching on: a moment.';
    if (!this.pose) return `Waiting for the ${this.tool} position…`;
    return '';
  }

  update() {
    const u = this.ui;
    const why = this.blocked();
    for (const b of u.jogButtons) {
      b.disabled = !!why;
      b.title = why || b.getAttribute('aria-label');
    }
    u.speed.disabled = !!why;
    u.jogWhy.textContent = why ? `Jog: ${why}` : '';
    if (why) this.stopJog(why);
    if (!this.edited && this.pose) this.pose.position.forEach((v, i) => { u.goal[i].value = v.toFixed(1); });
    let goWhy = why;
    const goal = u.goal.map((g) => Number(g.value));
    if (!TAKES_GOAL[this.robot.kind]) goWhy = `This robot takes no goal position: its three joints place the ${this.tool} but cannot also hold its orientation. Jog it instead.`;
    else if (!goWhy && !this.edited) goWhy = 'Type a goal position (mm); the preview shows what will move.';
    else if (!goWhy && goal.some((v, i) => u.goal[i].value === '' || !Number.isFinite(v))) goWhy = 'Each of x, y and z needs a number (mm).';
    u.preview.textContent = this.edited && this.pose && goal.every(Number.isFinite) ? goalPreview(this.pose.position, goal).text : '';
    for (const g of u.goal) g.disabled = !TAKES_GOAL[this.robot.kind];
    u.fromCurrent.disabled = !TAKES_GOAL[this.robot.kind];
    u.go.disabled = !!goWhy;
    u.go.title = goWhy;
    u.goWhy.textContent = goWhy ? `Go: ${goWhy}` : '';
  }

  goalTyped() {
    this.edited = true;
    this.ui.goal.forEach((g) => g.classList.add('edited'));
    this.update();
  }

  clearGoal() {
    this.edited = false;
    this.ui.goal.forEach((g) => g.classList.remove('edited'));
    this.update();
  }

  async go() {
    if (this.blocked() || !this.edited) return;
    const position = this.ui.goal.map((g) => Number(g.value));
    const {text} = goalPreview(this.pose.position, position);
    try {
      const answer = await this.ctx.api.moveCp(this.robot.name, {position, orientation: this.pose.orientation});
      this.ctx.status(`${title(this.tool)} moving to ${position.map((v) => v.toFixed(1)).join(', ')} mm` +
                      ` (${text.replace(/^will move: /, '')}; about ${Number(answer?.duration_s ?? 0).toFixed(1)} s)`, 'ok');
      this.clearGoal();
    } catch (err) {
      this.ctx.status(`Go refused: ${operatorWords(describe(err))}`, 'error');
    }
  }

  startJog(axis, sign) {
    this.stopJog();
    if (this.blocked()) return;
    const speed = Number(this.ui.speed.value) || 5;
    const linear = [0, 0, 0];
    linear[axis] = sign * speed;
    this.jogAxis = {axis, sign};
    let answered = 0;
    const timer = setInterval(() => send(), JOG_REFRESH_MS);
    // One command in flight at a time (a slow server gets no backlog; a command that waits longer than
    // the robot's timeout lets the robot stop, the safe side).
    const send = () => {
      if (this.jogInFlight || this.jogTimer !== timer) return;
      this.jogInFlight = this.ctx.api.servoCv(this.robot.name, linear).then(() => {
        // For whoever checks a jog: how many of its commands the server took.
        this.container.dataset.jogAnswered = String(++answered);
      }, (err) => {
        this.stopJog('refused');
        this.ctx.status(`Jog: ${operatorWords(describe(err))}`, 'error');
      }).finally(() => { this.jogInFlight = null; });
    };
    this.jogTimer = timer;
    send();
    this.ui.jogging.textContent = `moving ${AXES[axis]} ${sign > 0 ? '+' : '−'} at ${speed} mm/s (release to stop)`;
    this.container.dataset.jogging = 'true';
  }

  // Ends the stream with a zero twist, so the robot stops now rather than at its command timeout.
  // reason: why the jog ended (released, refused, or why motion is not allowed now), kept in
  // data-jog-ended for whoever checks a jog.
  stopJog(reason = '') {
    if (!this.jogTimer) return;
    this.container.dataset.jogEnded = reason;
    clearInterval(this.jogTimer);
    this.jogTimer = null;
    this.jogAxis = null;
    // The zero twist now, and again once a command still in flight has been answered (it may reach the
    // robot after the first zero).
    const stop = () => this.ctx.api.servoCv(this.robot.name, [0, 0, 0]).catch(() => {
      // refused (e.g. after an E-STOP or a mode change): the robot has stopped already
    });
    stop();
    this.jogInFlight?.then(stop);
    if (this.ui) this.ui.jogging.textContent = 'not moving';
    this.container.dataset.jogging = 'false';
  }

  async poll() {
    if (!this.robot || this.container.hidden) return;
    this.showAge();
    if (this.polling) return;
    this.polling = true;
    const robot = this.robot;
    const askedAt = performance.now();
    try {
      const [pose, os] = await Promise.all([this.ctx.api.measuredCp(robot.name),
                                            this.force ? this.ctx.api.operatingState(robot.name) : null]);
      if (robot !== this.robot) return;
      // The answer is at least as new as the request: its age counts from when it was asked for (the
      // robot's own time stamp is simulated time on a --simulated-time server, not the wall clock).
      this.answeredAt = askedAt;
      this.showPose(pose);
      this.showAge();
      if (os?.arm) this.showForce(os.arm);
    } catch {
      // the console's connection indicator reports an unreachable server
    } finally {
      this.polling = false;
    }
  }

  showPose(pose) {
    if (!Array.isArray(pose?.position)) return;
    this.pose = pose;
    const u = this.ui;
    const p = pose.position;
    u.position.textContent = AXES.map((a, i) => `${a} ${p[i].toFixed(1)}`).join('  ') + ' mm';
    u.position.dataset.x = String(p[0]);
    u.position.dataset.y = String(p[1]);
    u.position.dataset.z = String(p[2]);
    u.frame.textContent = `frame: ${String(pose.frame || '').replace(/_/g, ' ')}`;
    this.update();
  }

  showAge() {
    if (!Number.isFinite(this.answeredAt)) return;
    const age = performance.now() - this.answeredAt;
    const stale = age > STALE_MS;
    this.ui.age.textContent = stale ? `STALE ${(age / 1000).toFixed(1)} s` : `${Math.round(age)} ms`;
    this.ui.age.dataset.stale = String(stale);
  }

  showForce(arm) {
    const u = this.ui;
    const f = Array.isArray(arm.force_n) ? arm.force_n : null;
    const contact = Number(arm.contact_force_n);
    if (!f || !Number.isFinite(contact)) {
      u.force.textContent = 'no force reading';
      return;
    }
    if (!Number.isFinite(this.t0)) this.t0 = performance.now();
    const t = (performance.now() - this.t0) / 1000;
    this.forcePlot.push(0, t, contact);
    this.forcePlot.push(1, t, this.force.limit);
    const over = contact >= this.force.limit;
    u.force.textContent = `${contact.toFixed(2)} N`;
    u.force.dataset.value = String(contact);
    u.force.classList.toggle('rp-bad-text', over);
    u.forceDetail.textContent = `contact force (limit ${this.force.limit.toFixed(1)} N)${arm.force_fresh === false ? ' · sensor reading is old' : ''}` +
        ` · vector ${f.map((v) => v.toFixed(2)).join(', ')} N${arm.force_hold ? ' · HELD: over the limit' : ''}`;
  }

  destroy() {
    this.setRobot(null);
  }
}
