// tendril console: wires the REST API (commands, fallback polling) and the Foxglove WebSocket stream
// (live joint states, operating state, scene, safety events) to the page. The joint panel is built
// from GET /api/v1/robots, so any robot the server describes gets its own rows and limits.
// Terms: CRTK measured_js / setpoint_js / move_jp (CRTK's names); lease = the right to command.
import {panelFor} from './robot_panels.js';
import {Api, ApiError} from './api.js';
import {FoxgloveConnection} from './foxglove.js';
import {CatheterPanel} from './catheter.js';
import {MbcrPanel} from './mbcr.js';
import {TipPanel, cartesianModeOf} from './tip_control.js';
import {buildJointPanel, displayUnit} from './joints.js';
import {ImagePanel} from './images.js';
import {decodeCompressedImage} from './protobuf.js';
import {Backoff, LatestByTopic, STALE_MS, ServerClock, formatAge, wallNowMs} from './live.js';
import {PlanPanel} from './plan.js';
import {ProcedurePanel} from './procedure.js';
import {arrangeImaging, wireEnlarge} from './layout.js';
import {TimePlot, shedPlots} from './plot.js';
import {TRACKING_TOPIC, TrackingPanel} from './tracking.js';
import {ReplayBar} from './replay.js';
import {operatorWords} from './words.js';

const api = new Api();
const $ = (sel) => document.querySelector(sel);

const ui = {
  robotSelect: $('#robot-select'),
  robotKind: $('[data-testid="robot-kind"]'),
  badge: $('[data-testid="state-badge"]'),
  badgeValue: $('[data-testid="state-value"]'),
  connection: $('[data-testid="connection-indicator"]'),
  connectionText: $('[data-testid="connection-indicator"] .connection-text'),
  connectionRtt: $('[data-testid="connection-rtt"]'),
  lease: $('[data-testid="lease-status"]'),
  leaseButton: $('#lease-button'),
  enableButton: $('#enable-button'),
  disableButton: $('#disable-button'),
  pauseButton: $('#pause-button'),
  resumeButton: $('#resume-button'),
  bannerNext: $('[data-testid="banner-next"]'),
  relaxButton: $('#relax-button'),
  withdrawButton: $('#withdraw-button'),
  bannerResume: $('#banner-resume-button'),
  resetButton: $('#estop-reset-button'),
  estopButton: $('#estop-button'),
  banner: $('[data-testid="banner"]'),
  bannerTitle: $('[data-testid="banner"] .banner-title'),
  bannerCause: $('[data-testid="banner"] .banner-cause'),
  form: $('#joint-form'),
  moveButton: $('#move-button'),
  moveHint: $('[data-testid="move-hint"]'),
  movePreview: $('[data-testid="move-preview"]'),
  goalsCleared: $('[data-testid="goals-cleared"]'),
  goalFromSetpoint: $('#goal-from-setpoint-button'),
  status: $('[data-testid="command-status"]'),
  events: $('[data-testid="event-log"]'),
  tip: $('[data-testid="tip-position"]'),
  fitView: $('#fit-view-button'),
  scene: $('#scene'),
  modeButtons: $('#mode-buttons'),
  modeBar: $('[data-testid="mode-bar"]'),
  modeRefusal: $('[data-testid="mode-refusal"]'),
  catheterTab: $('#tab-catheter'),
  mbcrTab: $('#tab-mbcr'),
  tabs: [...document.querySelectorAll('[role="tab"]')],
  eventCount: $('[data-testid="event-count"]'),
  configTip: $('[data-testid="config-tip"]'),
  configDirection: $('[data-testid="config-direction"]'),
  configStep: $('[data-testid="config-step"]'),
  plotJoint: $('#plot-joint-select'),
  timingSource: $('[data-testid="timing-source"]'),
  timingLegend: $('[data-testid="timing-legend"]'),
  takeoverDialog: $('[data-testid="takeover-dialog"]'),
  takeoverText: $('[data-testid="takeover-text"]'),
  role: $('[data-testid="role-status"]'),
  // Age of what each panel shows (issue 12: stale data must never look live).
  ages: {
    joints: $('[data-testid="age-joints"]'),
    scene: $('[data-testid="age-scene"]'),
    plots: $('[data-testid="age-plots"]'),
    catheter: $('[data-testid="age-catheter"]'),
  },
};

const state = {
  robots: [],
  robot: null,          // description of the selected robot from GET /robots
  operating: null,      // latest operating_state
  leaseHeld: false,
  wsLive: false,        // WebSocket open
  lastWsJointMs: 0,     // browser time the newest joint_states message arrived
  lastRestOkMs: 0,      // browser time the last polled joint state arrived
  stale: true,          // what the page shows is older than STALE_MS (or there is none): no commands
  streamAgeMs: Infinity,  // age of the joint values shown
  latencyMs: [],        // stream latency (arrival - server stamp) of the last second's joint messages
  role: null,           // 'operator' | 'viewer', from the stream's serverInfo
  estopSentMs: -Infinity,  // browser wall clock when this page last sent the e-stop
  events: [],           // newest first
  lastFaultCause: '',
  offline: false,       // neither stream nor REST answered lately
  advertised: new Set(),  // topics the stream currently offers
  timingSource: null,   // 'diagnostics' | 'metrics' | null
  catheterMsg: null,    // newest /{robot}/catheter message (operating_state with the live catheter values)
  catheterMsgMs: 0,
};

// Titles of the hold causes the server names in operating_state.hold.cause.
const HOLD_TITLES = {
  operator_pause: 'Paused',
  spring_deflection: 'Held: spring deflection',
  sensor_stale: 'Held: spring sensor silent',
};

// The hold (cause, wording, what is allowed) while PAUSED, else null. The operating_state topic
// carries the hold in the core's wording, which changes only with the hold; the robot's live wording
// (which changes with every sensor reading) comes on its 10 Hz topic and wins while fresh.
function currentHold(os = state.operating) {
  if (!os || os.state !== 'PAUSED' || os.estop) return null;
  const hold = os.hold || {cause: 'unknown', message: 'the robot holds its position', next: 'Resume to continue.',
                           allowed: ['resume'], cleared: true};
  const c = state.catheterMsg?.hold;
  if (c && c.cause === hold.cause && Date.now() - state.catheterMsgMs < 1000) return {...hold, ...c};
  return hold;
}

const HOLD_ACTIONS = {resume: 'Resume', relax: 'Relax springs', withdraw: 'Withdraw'};

const capitalise = (text) => (text ? text.charAt(0).toUpperCase() + text.slice(1) : '');

let joints = null;      // joint panel controller
let view = null;        // CatheterView, loaded lazily so a WebGL/three failure cannot break the controls
let plan = null;        // PlanPanel
let catheter = null;    // CatheterPanel, for robots with a configuration space
let mbcr = null;        // MbcrPanel, for the variable-diameter robot (mbcr_vd)
let tipPanel = null;    // TipPanel: the tip or tool of a robot with a Cartesian mode (web/tip_control.js)
let trackingPlot = null;  // setpoint against measured, one joint
let timingPlot = null;    // control loop timing
let tipTracking = null;   // TrackingPanel: the imaged tip and the segmentation editor
const procedure = new ProcedurePanel($('[data-testid="procedure"]'));
const images = {
  ap: new ImagePanel($('[data-testid="image-ap"]'), '/imaging/ap/compressed', 'AP', {ageMs: (stamp) => clock.ageMs(stamp)}),
  lateral: new ImagePanel($('[data-testid="image-lateral"]'), '/imaging/lateral/compressed', 'Lateral',
                          {ageMs: (stamp) => clock.ageMs(stamp)}),
};

// ---------------------------------------------------------------- token handling
// The server turns ?token= into a session cookie on this page load; keep the token out of the address
// bar (and so out of history, screenshots and shoulder-surfing) but in memory for Bearer fallback.
(function takeTokenFromUrl() {
  const url = new URL(window.location.href);
  const token = url.searchParams.get('token');
  if (!token) return;
  api.token = token;
  url.searchParams.delete('token');
  history.replaceState(null, '', url.pathname + (url.search || '') + url.hash);
})();

// ---------------------------------------------------------------- status line
let statusTimer = null;
let statusSetMs = 0;
// In operator words (what to press, not the request to send); the server's sentence is in the title.
function showStatus(text, kind = 'ok') {
  ui.status.textContent = operatorWords(text);
  ui.status.title = text;
  ui.status.className = `command-status ${kind}`;
  statusSetMs = Date.now();
  // A motion under way, until it ends or a stop ends it (applyOperatingState says which).
  if (kind === 'ok' && /^(Moving|Step |Withdrawing)/.test(text)) state.motionStatus = {text, atMs: Date.now()};
  clearTimeout(statusTimer);
  if (kind === 'ok') statusTimer = setTimeout(() => { ui.status.textContent = ''; }, 6000);
}

function describeError(err) {
  if (err instanceof ApiError) {
    if (err.status === 401) return 'Not authorised: open the console link that tendrild printed (it carries ?token=…).';
    return err.message;
  }
  return String(err && err.message ? err.message : err);
}

// Runs a command; shows the server's message on failure. Returns the answer or null.
async function runCommand(label, fn) {
  try {
    const result = await fn();
    showStatus(`${label}: done`, 'ok');
    return result ?? {};
  } catch (err) {
    if (err instanceof ApiError && err.code === 'lease_held') setLease(false, err.message);
    showStatus(`${label} refused: ${describeError(err)}`, 'error');
    return null;
  }
}

// ---------------------------------------------------------------- operating state
// readAtMs: when a polled state was asked for (browser wall clock): one asked before this page's e-stop
// was sent, arriving just after its answer, is older than what the page knows and does not undo the
// E-STOP (only in the first 2 s: a reset after that is a deliberate act, and is never held back).
function applyOperatingState(os, readAtMs = NaN) {
  if (!os || typeof os.state !== 'string') return;
  if (!os.estop && state.operating?.estop && readAtMs < state.estopSentMs && wallNowMs() - state.estopSentMs < 2000) return;
  const estopNow = !!os.estop && !state.operating?.estop;
  const wasEnabled = state.operating?.state === 'ENABLED' && !state.operating?.estop;
  const wasBusy = !!state.operating?.is_busy;
  state.operating = os;
  if (estopNow) clearGoalsOnEstop();
  // A "Moving to …" line is about a motion that a hold, a fault or an e-stop has ended: it says so.
  // (The motion's line may already have given way to the server's own words about the stop.)
  const motion = state.motionStatus;
  if (motion && !os.is_busy && !wasBusy && Date.now() - motion.atMs > 2000) state.motionStatus = null;
  if (motion && wasEnabled && (os.estop || os.state !== 'ENABLED') && (wasBusy || Date.now() - motion.atMs < 2000)) {
    state.motionStatus = null;
    const cause = currentHold(os)?.cause;
    const why = os.estop ? 'E-STOP' : os.state === 'PAUSED' ? (HOLD_TITLES[cause] || `held: ${String(cause || 'paused').replace(/_/g, ' ')}`).toLowerCase()
        : os.state === 'FAULT' ? 'fault' : os.state.toLowerCase();
    const server = /^server: /.test(ui.status.textContent) ? ` · ${ui.status.title}` : '';
    showStatus(`Stopped before the goal: ${why}. ${motion.text.replace(/:.*$/, '')} did not finish.${server}`, 'notice');
  }
  procedure.onState(os);
  const estop = !!os.estop;
  const label = estop ? 'E-STOP' : os.state;
  ui.badgeValue.textContent = label;
  ui.badge.className = `state-badge state-${estop ? 'estop' : os.state.toLowerCase()}`;
  ui.badge.setAttribute('aria-label', `Operating state: ${label}${os.is_busy ? ', moving' : ''}`);
  ui.badge.dataset.state = os.state;
  ui.badge.dataset.estop = String(estop);
  ui.badge.title = `state ${os.state} · mode ${os.mode ?? '?'} · homed ${!!os.is_homed} · busy ${!!os.is_busy}`;
  updateBanner();
  updateControls();
  updateModeBar();
  plan?.updateButtons();
  if (catheter && os.configuration) catheter.update(os);
}

// An E-STOP ends what was typed: goals typed before it (joint goals, the catheter's configuration
// fields, the preview of what would move) no longer wait, ready to move, through Reset and Enable.
// The page says what it cleared, in the status line and where the preview was, until a goal is typed.
function clearGoalsOnEstop() {
  const cleared = [];
  if (joints?.edited()) {
    cleared.push(joints.preview().replace(/^will move: /, '').split(' · ')[0]);
    joints.clearEdits();
  }
  if (catheter?.hasGoal?.()) {
    cleared.push(catheter.goalText());
    catheter.clearTouched();
  }
  if (!cleared.length) return;
  state.goalsCleared = `E-STOP cleared the goals you had typed (${cleared.join('; ')}): nothing waits to move; ` +
      'type them again after Reset and Enable.';
  ui.goalsCleared.textContent = state.goalsCleared;
  ui.goalsCleared.hidden = false;
  showStatus(state.goalsCleared, 'notice');
  updateControls();
}

function goalsTypedAgain() {
  if (!state.goalsCleared) return;
  state.goalsCleared = '';
  ui.goalsCleared.hidden = true;
  ui.goalsCleared.textContent = '';
}

// "Relax springs" is accepted at once and runs while the robot holds: its status line follows the
// hold's relax (running, then done or stopped short) instead of saying "done" when it was sent.
let relaxWatch = null;  // {sinceMs, seenRunning} while this console's relax runs
function watchRelax(hold) {
  if (!relaxWatch) return;
  const running = !!hold?.relax?.running;
  if (running) {
    relaxWatch.seenRunning = true;
    return;
  }
  if (!relaxWatch.seenRunning && Date.now() - relaxWatch.sinceMs < 1500) return;
  relaxWatch = null;
  if (!hold) showStatus('Relax springs: the hold has ended', 'ok');
  else if (hold.cleared) showStatus('Relax springs: done, the springs are relaxed: Resume to continue', 'ok');
  else showStatus(`Relax springs stopped short: ${hold.message || 'the cause persists'}`, 'notice');
}

// The cause the server gives with the state (operating_state.fault), else the newest safety event.
function faultCause(os) {
  const f = os && os.fault;
  if (f && f.message) return `${f.code ? f.code + ': ' : ''}${f.message}${f.joint ? ` (${f.joint})` : ''}`;
  return state.lastFaultCause;
}

// The status strip is always there (so the layout never jumps when a fault arrives); its level says
// how serious: ok, paused, offline, fault, estop.
function updateBanner() {
  const os = state.operating;
  let level = 'ok';
  let title = 'Normal';
  let cause = 'No active fault.';
  let next = '';
  const hold = currentHold(os);
  if (os && os.estop) {
    level = 'estop';
    title = 'Emergency stop latched';
    cause = `${faultCause(os) || 'Motion is stopped on every robot.'} — find the cause, press Reset, then Enable.`;
  } else if (os && os.state === 'FAULT') {
    level = 'fault';
    title = 'Fault';
    // The cause first and whole; what to do next is in the Move hint and the Reset button's title.
    cause = faultCause(os) || 'The robot stopped; see the events for the cause.';
  } else if (state.offline && state.robot) {
    level = 'offline';
    title = 'No connection';
    cause = `The values shown are stale${Number.isFinite(state.streamAgeMs) ? ` (${formatAge(state.streamAgeMs)} old)` : ''}. ` +
        'The server keeps the robot safe on its own; check the network or tendrild. Commands are disabled; E-STOP still works.';
  } else if (state.stale && state.robot && os) {
    // Connected but behind: the page shows the past. Said above everything but an e-stop or a fault.
    level = 'stale';
    title = `Stale data: ${formatAge(state.streamAgeMs)} old`;
    cause = `What this page shows is older than ${STALE_MS} ms, so it may not be where the robot is. ` +
        'Commands are disabled until fresh data arrives; E-STOP, Pause and Disable still work.';
    // A hold's cause and way out stay in view, as last received and in the hold's own words (the same
    // height as the hold's banner, so a page that turns STALE now and then does not jump).
    if (hold) {
      title += ` · ${HOLD_TITLES[hold.cause] || `Held: ${String(hold.cause).replace(/_/g, ' ')}`}`;
      cause = `${capitalise(hold.message || 'the robot holds its position')}.`;
      next = hold.next || '';
    }
  } else if (hold) {
    // Always the cause and the way out, here where the operator looks (not on another tab).
    level = 'paused';
    title = HOLD_TITLES[hold.cause] || `Held: ${String(hold.cause).replace(/_/g, ' ')}`;
    cause = `${capitalise(hold.message || 'the robot holds its position')}.`;
    next = hold.next || '';
  } else if (!os) {
    title = 'Starting';
    cause = 'Waiting for the robot state…';
  }
  ui.banner.className = `banner level-${level}`;
  ui.banner.dataset.level = level;
  ui.banner.title = `${title}: ${cause} ${next}`.trim();
  ui.banner.dataset.cause = hold ? hold.cause : '';
  ui.bannerTitle.textContent = title;
  ui.bannerCause.textContent = operatorWords(cause);
  ui.bannerNext.textContent = operatorWords(next);
  // The ways out the server allows now, as buttons beside the words. They stay in place while the
  // page shows old data (disabled below), so the way out does not vanish on a slow frame.
  const allowed = new Set(hold ? hold.allowed || [] : []);
  const relaxing = !!hold?.relax?.running;
  ui.relaxButton.hidden = !(allowed.has('relax') || relaxing);
  ui.relaxButton.textContent = relaxing ? 'Stop relaxing' : 'Relax springs';
  ui.relaxButton.dataset.relaxing = String(relaxing);
  ui.withdrawButton.hidden = !allowed.has('withdraw');
  ui.bannerResume.hidden = !hold;
  ui.bannerResume.classList.toggle('btn-go', !!hold?.cleared);
  for (const b of [ui.relaxButton, ui.withdrawButton, ui.bannerResume]) {
    b.disabled = !state.leaseHeld || state.stale;
    b.title = !state.leaseHeld ? 'Take the lease to command' : state.stale ? 'Waits for fresh data (the page shows old data)' : '';
  }
  // Resume only once the hold's cause has cleared (it was offered, and refused, while it persisted);
  // the banner's words say what clears it.
  if (hold && !hold.cleared) {
    ui.bannerResume.disabled = true;
    ui.bannerResume.title = `Not yet: ${operatorWords(hold.next || 'the cause persists')}`;
  }
  watchRelax(hold);
}

function updateControls() {
  const os = state.operating;
  const estop = !!(os && os.estop);
  const enabled = !!(os && os.state === 'ENABLED');
  const fault = !!(os && os.state === 'FAULT');
  const paused = !!(os && os.state === 'PAUSED' && !estop);
  // Nothing that starts motion while the page shows old data; the stops stay (and a viewer sees no
  // command it could not send).
  const stale = state.stale;
  const viewer = state.role === 'viewer';
  ui.enableButton.disabled = !os || estop || enabled || fault || paused || stale || viewer;
  ui.disableButton.disabled = !os || os.state === 'DISABLED' || viewer;
  ui.pauseButton.hidden = paused;
  ui.pauseButton.disabled = !enabled || estop || viewer;
  ui.resumeButton.hidden = !paused;
  ui.resumeButton.disabled = stale || viewer;
  ui.leaseButton.disabled = viewer;
  const hold = currentHold(os);
  ui.resumeButton.classList.toggle('btn-go', !!hold?.cleared);
  ui.resumeButton.title = hold && !hold.cleared ? `Not yet: ${operatorWords(hold.next || 'the cause persists')}`
      : stale ? 'Waits for fresh data (the page shows old data)' : '';
  if (hold && !hold.cleared) ui.resumeButton.disabled = true;
  // Enable is not offered (nor green) while another operator holds this robot's lease.
  const leaseOther = !state.leaseHeld && state.leaseOther;
  if (leaseOther) ui.enableButton.disabled = true;
  ui.enableButton.classList.toggle('btn-go', !ui.enableButton.disabled);
  ui.enableButton.title = leaseOther ? `Another operator holds the lease (${state.leaseOther}): take it over first`
      : stale && !enabled ? 'Waits for fresh data (the page shows old data)' : '';
  ui.resetButton.disabled = !os || (!estop && os.state !== 'FAULT') || stale || viewer;
  let hint = '';
  if (!os) hint = 'Waiting for the robot state…';
  else if (viewer) hint = 'Viewer: this session may watch but not command (open the operator link to command).';
  else if (state.offline) hint = 'No connection: the values shown are old; nothing can be commanded.';
  else if (stale) hint = 'Stale data (its age is in the banner): commands wait for fresh data.';
  else if (estop) hint = 'E-stop latched: Reset, then Enable.';
  else if (fault) hint = 'Fault: Reset to acknowledge, then Enable.';
  else if (hold) hint = `${HOLD_TITLES[hold.cause] || 'Held'}: the banner above says why and offers ` +
      `${[...(hold.allowed || [])].map((a) => HOLD_ACTIONS[a] || a).join(', ') || 'the way out'}.`;
  else if (!enabled) hint = 'Enable the robot to move.';
  else if (!state.leaseHeld) hint = 'Take the lease to command.';
  const pathMode = !!(os && os.mode === 'path_following');
  if (!hint && pathMode) hint = 'Path-following mode: step through the plan (Plan tab), or switch to Joint mode.';
  const invalid = joints ? joints.invalidJoints() : [];
  if (!hint && invalid.length) hint = `Goal outside limits: ${invalid.join(', ')}`;
  const edited = !!joints && joints.edited();
  if (!hint && !edited) hint = 'Type or drag a goal; joints you do not touch stay where they are.';
  ui.moveButton.disabled = !os || estop || !enabled || pathMode || invalid.length > 0 || !edited || stale || viewer;
  // A step moves one joint from the live setpoint: allowed whenever a joint move could be sent.
  const stepBlocked = !os || estop || !enabled || pathMode || stale || viewer || !state.leaseHeld;
  joints?.setStepsEnabled(!stepBlocked, hint || 'Steps need an ENABLED robot in a joint-space mode.');
  ui.moveHint.textContent = hint;
  ui.movePreview.textContent = joints ? joints.preview() : '';
  // The robot's own panel: its commands need what a move needs but not ENABLED (a mode or a plan may
  // be chosen while disabled); the panel disables its motion buttons itself from its robot's state.
  const panelHint = !os ? 'Waiting for the robot state…' : viewer ? 'Viewer: watch only.'
      : state.offline ? 'No connection.' : stale ? 'Stale data: commands wait for fresh data.'
      : !state.leaseHeld ? 'Take the lease to command.' : '';
  kindPanel?.setCommandable?.(!panelHint, panelHint, {enabled, estop, mode: os?.mode ?? ''});
  tipPanel?.setCommandable(!panelHint, panelHint, {enabled, estop, mode: os?.mode ?? '', drivesReady: os?.drives_ready !== false});
}

// The session's role as the server states it (serverInfo metadata): a viewer may watch and subscribe
// but not command, so its page shows no command as available (E-STOP stays: the server decides).
function setRole(role) {
  if (role !== 'operator' && role !== 'viewer') return;
  state.role = role;
  document.body.dataset.role = role;
  // Said only for a viewer (the exception); an operator's role shows in the lease status.
  ui.role.textContent = role === 'viewer' ? 'VIEWER: watch only' : '';
  ui.role.dataset.role = role;
  ui.role.title = role === 'viewer'
    ? 'This session has the viewer role: it sees everything and commands nothing (the server refuses with 403).'
    : 'This session has the operator role: it may command while it holds the lease.';
  catheter?.setViewer(role === 'viewer');
  updateControls();
  updateModeBar();
  updateBanner();
  plan?.updateButtons();
}

function setLease(held, otherMessage = '') {
  const changed = state.leaseHeld !== held || state.leaseOther !== (held ? '' : otherMessage);
  state.leaseHeld = held;
  state.leaseOther = held ? '' : otherMessage;
  if (changed) updateBanner();
  ui.lease.classList.toggle('held', held);
  ui.lease.classList.toggle('other', !held && !!otherMessage);
  // With several robots each has its own lease: the badge names the selected robot's.
  // On a laptop screen the name gives way (CSS): the selector beside the badge shows it.
  const of = state.robots.length > 1 && state.robot ? ` (${state.robot.name})` : '';
  const ofSpan = document.createElement('span');
  ofSpan.className = 'lease-of';
  ofSpan.textContent = of;
  ui.lease.replaceChildren(held ? 'lease: yours' : otherMessage ? 'lease: other operator' : 'lease: free', ofSpan);
  ui.lease.title = [of ? `The lease of ${state.robot.name}` : '', otherMessage].filter(Boolean).join(': ');
  ui.leaseButton.textContent = held ? 'Release lease' : 'Take lease';
  ui.leaseButton.setAttribute('aria-label', held ? 'Release operator lease' : 'Take operator lease');
  updateControls();
}

// ---------------------------------------------------------------- events
function formatTime(t) {
  if (typeof t !== 'number' || !Number.isFinite(t)) return '';
  return new Date(t * 1000).toLocaleTimeString([], {hour12: false});
}

function addEvents(list) {
  let changed = false;
  const known = new Set(state.events.map((e) => e.key));
  for (const ev of list) {
    const key = `${ev.time}|${ev.kind}|${ev.message}`;
    if (known.has(key)) continue;
    known.add(key);
    state.events.push({...ev, key});
    changed = true;
  }
  if (!changed) return;
  state.events.sort((a, b) => (b.time || 0) - (a.time || 0));
  state.events.length = Math.min(state.events.length, 200);
  // The cause shown in the banner: the newest event that is not a plain state transition (nor a
  // warning, such as images that stopped coming, which causes no state change).
  const cause = state.events.find((e) => e.kind !== 'transition' && e.kind !== 'warning') || state.events[0];
  if (cause) state.lastFaultCause = `${cause.kind ? cause.kind + ': ' : ''}${cause.message || ''}`;
  scheduleEventsRender();
}

// The list and the banner drawn at most every EVENTS_RENDER_MS: a robot that logs an event per sample
// (seen: 100 a second, a contact alternating between two Hall windows) had the page rebuild the
// 200-row list 100 times a second and fall 9 s behind its stream. The events themselves are taken at
// once; only the drawing waits.
const EVENTS_RENDER_MS = 150;
let eventsRenderTimer = null;
function scheduleEventsRender() {
  if (eventsRenderTimer) return;
  eventsRenderTimer = setTimeout(() => {
    eventsRenderTimer = null;
    renderEvents();
    updateBanner();
  }, EVENTS_RENDER_MS);
}

function renderEvents() {
  ui.eventCount.textContent = state.events.length ? `(${state.events.length})` : '';
  ui.events.replaceChildren();
  if (state.events.length === 0) {
    const li = document.createElement('li');
    li.className = 'empty';
    li.textContent = 'No safety events.';
    ui.events.appendChild(li);
    return;
  }
  for (const ev of state.events) {
    const li = document.createElement('li');
    const t = document.createElement('span');
    t.className = 't';
    t.textContent = formatTime(ev.time);
    const k = document.createElement('span');
    k.className = 'k';
    k.textContent = ev.kind || '';
    k.title = `${ev.robot || ''} ${ev.kind || ''}`;
    const m = document.createElement('span');
    m.textContent = ev.robot ? `${ev.robot}: ${ev.message || ''}` : ev.message || '';
    li.append(t, k, m);
    ui.events.appendChild(li);
  }
}

function eventsFromFaults(data) {
  if (Array.isArray(data)) return data;
  if (data && Array.isArray(data.events)) return data.events;
  if (data && Array.isArray(data.faults)) return data.faults;
  return [];
}

// ---------------------------------------------------------------- live data
// The stream's messages go into `latest` (newest per topic, undecoded); one animation frame decodes
// and shows them, the cheap ones first, the 3D view and the images within a frame budget. Every panel
// knows the server time of the state it shows, so its age is always on screen.
const latest = new LatestByTopic();
const clock = new ServerClock();
const FRAME_BUDGET_MS = 8;     // work per frame beyond which the expensive panels wait for the next one
const SCENE_SHARE = 3;         // the 3D view may take at most 1 / (1 + SCENE_SHARE) of the main thread
const POLL_MS = 125;           // REST fallback (stream refused): 8 Hz keeps polled values under STALE_MS
let topics = null;             // topic names of the selected robot
// Server time (ms) of the state each panel shows. The on-change topics (operating state, scene) are
// as new as the joint stream once nothing of theirs waits to be shown.
const shown = {joints: NaN, scene: NaN, catheter: NaN};
let sceneNextAt = 0;
const MAX_WAIT_MS = 250;       // an expensive panel is brought up to date at least this often
const lastTaken = new Map();   // topic -> frame time its newest message was last shown
let lastAgeUpdate = 0;

// REST requests pause while the server does not answer; one probe (GET /health) with exponential
// backoff (0.5, 1, 2, 4, 5, 5 … s) decides when it is back. The stream reconnects with the same
// backoff (foxglove.js). Commands the operator presses are always sent (E-STOP above all).
const net = new Backoff({
  probe: async () => {
    await api.health();
    return true;
  },
  onChange: () => refreshConnectionIndicator(),
});
api.onNetwork = (answered) => (answered ? net.answered() : net.failed());

function applyJointState(js, withSetpoint) {
  if (!joints || !js) return;
  joints.updateMeasured(js);
  procedure.onJoints(js);
  kindPanel?.onJointState?.(js);
  if (withSetpoint && Array.isArray(js.setpoint)) joints.updateSetpoint({name: js.name, position: js.setpoint});
  plotJointState(js.name, js.position, 1);
  if (withSetpoint) plotJointState(js.name, js.setpoint, 0);
}

// Feeds the setpoint (series 0) or measured (series 1) value of the joint chosen for the plot.
function plotJointState(names, values, series) {
  if (!trackingPlot || !Array.isArray(values)) return;
  const joint = ui.plotJoint.value;
  const index = Array.isArray(names) ? names.indexOf(joint) : state.robot.joints.findIndex((j) => j.name === joint);
  // In the unit the Joints tab shows (degrees for a revolute joint).
  const scale = displayUnit(state.robot.joints.find((j) => j.name === joint)?.unit).scale;
  if (index >= 0) trackingPlot.push(series, performance.now() / 1000, Number(values[index]) * scale);
}

function applyShape(shape) {
  if (view && shape && Array.isArray(shape.points)) view.setBackbone(shape.points);
}

function showTip(position, zAxis) {
  const [x, y, z] = position;
  ui.tip.textContent = `tip x ${x.toFixed(1)}  y ${y.toFixed(1)}  z ${z.toFixed(1)} mm`;
  ui.configTip.textContent = `${x.toFixed(1)}, ${y.toFixed(1)}, ${z.toFixed(1)} mm`;
  plan?.showTip(position);
  if (zAxis) {
    // The tip frame's z axis (the catheter's heading) as azimuth in XY and elevation above XY.
    const [zx, zy, zz] = zAxis;
    const deg = 180 / Math.PI;
    ui.configDirection.textContent =
        `az ${(Math.atan2(zy, zx) * deg).toFixed(1)}°, el ${(Math.atan2(zz, Math.hypot(zx, zy)) * deg).toFixed(1)}°`;
  }
}

// Tip pose from GET measured_cp (REST fallback only).
function applyTipPose(cp) {
  if (!cp || !Array.isArray(cp.position)) return;
  const q = cp.orientation;
  let zAxis = null;
  if (Array.isArray(q) && q.length === 4) {
    const [qx, qy, qz, qw] = q;
    zAxis = [2 * (qx * qz + qw * qy), 2 * (qy * qz - qw * qx), 1 - 2 * (qx * qx + qy * qy)];
  }
  showTip(cp.position, zAxis);
  view?.setTipPose(cp.position, cp.orientation);
}

// Tip pose from the scene's tip frame (tendril draws it as three arrows along the tip's x, y, z axes,
// each the x axis rotated by its pose): the read-out and the 3D view come from the same message.
function applyTipFromScene(update) {
  const tip = (update?.entities || []).find((e) => /(^|\/)tip_frame$/.test(e.id || ''));
  const arrows = tip?.arrows;
  if (!Array.isArray(arrows) || arrows.length < 3) return;
  const p = arrows[2].pose?.position;
  const o = arrows[2].pose?.orientation;
  if (!p || !o) return;
  // x axis rotated by the quaternion (x, y, z, w): the first column of its rotation matrix.
  const zAxis = [1 - 2 * (o.y * o.y + o.z * o.z), 2 * (o.x * o.y + o.w * o.z), 2 * (o.x * o.z - o.w * o.y)];
  showTip([p.x, p.y, p.z], zAxis);
}

// `detail` may start with a word that a laptop screen drops (CSS .latency-word): [word, rest].
function setConnection(kind, text, detail = '') {
  ui.connection.className = `connection ${kind}`;
  ui.connectionText.textContent = text;
  if (Array.isArray(detail)) {
    const word = document.createElement('span');
    word.className = 'latency-word';
    word.textContent = detail[0];
    ui.connectionRtt.replaceChildren(word, detail[1]);
    detail = detail.join('');
  } else {
    ui.connectionRtt.textContent = detail;
  }
  ui.connection.setAttribute('aria-label', `Connection: ${text}${detail ? `, ${detail}` : ''}`);
  ui.connection.dataset.kind = kind;
}

// Stream latency: arrival time minus the server's publish stamp, worst of the last second (the worst
// is what an operator acts on). Needs the clocks compared (ServerClock); the tooltip says how well.
function streamLatencyMs() {
  const now = wallNowMs();
  state.latencyMs = state.latencyMs.filter((l) => now - l.at < 1000);
  return state.latencyMs.length ? Math.max(...state.latencyMs.map((l) => l.ms)) : NaN;
}

// A paused replay sends nothing, by request: the page's clock for ages and for "is the stream live"
// stops where the playback stopped (the newest joint message's arrival), so the page shows the ages the
// data had then instead of turning STALE and offline. A live server never pauses.
function replayPaused() { return document.body.dataset.replayPlaying === 'false' && state.lastWsJointMs > 0; }
function ageClockMs() { return replayPaused() ? state.lastWsJointMs : Date.now(); }

function wsStreaming() { return state.wsLive && ageClockMs() - state.lastWsJointMs < 1000; }

function refreshConnectionIndicator() {
  const now = Date.now();
  const streaming = wsStreaming();
  const polling = !streaming && now - state.lastRestOkMs < 2000;
  const offline = !streaming && !polling;
  const age = state.streamAgeMs;
  const clockNote = clock.known
    ? `server clock offset ${clock.offsetMs.toFixed(1)} ms (± ${clock.errorMs.toFixed(1)} ms)`
    : 'server clock not compared yet: ages assume the browser and the server clocks agree';
  if (offline) {
    setConnection('offline', net.reachable ? 'no data from server' : 'no connection to server',
                  Number.isFinite(age) ? `data ${formatAge(age)} old` : '');
  } else if (replayPaused()) {
    setConnection('replay-paused', 'replay paused', Number.isFinite(age) ? `data ${formatAge(age)} old when paused` : '');
  } else if (state.stale) {
    setConnection('stale', `STALE ${formatAge(age)}`, streaming ? 'stream behind' : 'polling behind');
  } else if (streaming) {
    const latency = streamLatencyMs();
    setConnection('live', 'live stream', Number.isFinite(latency) ? ['latency ', formatAge(latency)] : '');
    ui.connection.dataset.latencyMs = Number.isFinite(latency) ? latency.toFixed(1) : '';
  } else {
    setConnection('polling', 'polling (REST)', `data ${formatAge(age)} old`);
  }
  ui.connection.title = `${streaming && !state.stale ? 'The number is the stream latency: arrival minus the server\'s stamp, ' +
      'the worst of the last second. ' : ''}${clockNote}. Data older than ${STALE_MS} ms is marked STALE and commands other than ` +
      `the stops are disabled.${net.reachable ? '' : ` Server not answering: retrying in ${(net.delayMs / 1000).toFixed(1)} s.`}`;
  if (offline !== state.offline) {
    state.offline = offline;
    updateStale(true);
  }
}

// One age badge: "12 ms" while fresh, "STALE 1.3 s" past the bound.
function setAge(el, ageMs) {
  if (!el) return;
  const stale = !(ageMs <= STALE_MS);
  el.textContent = Number.isFinite(ageMs) ? (stale ? `STALE ${formatAge(ageMs)}` : formatAge(ageMs)) : 'no data';
  el.dataset.stale = String(stale);
  el.dataset.ageMs = Number.isFinite(ageMs) ? ageMs.toFixed(0) : '';
  el.title = `age of the data shown here (server time stamp to now); STALE past ${STALE_MS} ms`;
  const panel = el.closest('[data-age-panel]');
  if (panel) {
    panel.dataset.stale = String(stale);
    panel.dataset.staleText = stale ? `STALE · ${Number.isFinite(ageMs) ? `${formatAge(ageMs)} old` : 'no data'}` : '';
  }
}

function updateAges() {
  const now = replayPaused() ? state.lastWsJointMs : wallNowMs();
  lastAgeUpdate = performance.now();
  const jointsAge = clock.ageMs(shown.joints, now);
  state.streamAgeMs = jointsAge;
  setAge(ui.ages.joints, jointsAge);
  setAge(ui.ages.plots, jointsAge);
  // The 3D view's age is that of what its canvas shows (a render may wait on a slow machine).
  const sceneShownMs = view?.shownAtMs?.();
  setAge(ui.ages.scene, clock.ageMs(Number.isFinite(sceneShownMs) ? sceneShownMs : shown.scene, now));
  if (catheter && topics && state.advertised.has(topics.catheter)) setAge(ui.ages.catheter, clock.ageMs(shown.catheter, now));
  updateStale(false);
  refreshConnectionIndicator();
}

// Stale or offline: the page says so everywhere and offers no command but the stops (E-STOP, Pause,
// Disable) until fresh data arrives.
function updateStale(force) {
  const stale = state.offline || !(state.streamAgeMs <= STALE_MS);
  document.body.dataset.stale = String(stale);
  if (stale === state.stale && !force) {
    if (stale) updateBanner();  // the age in the banner grows
    return;
  }
  state.stale = stale;
  document.body.classList.toggle('stale', stale);
  catheter?.setCommandable(!stale);
  mbcr?.setCommandable(!stale);
  updateBanner();
  updateControls();
  updateModeBar();
  plan?.updateButtons();
  refreshConnectionIndicator();
}

// The operating state is shown as it arrives, not at the next animation frame: it is small, it changes
// only with the state, and an E-STOP must not wait for a page whose frames lag (a software-rendered
// 4K page drew a frame every 0.6-0.8 s, and the badge said PAUSED that long after the latch).
function takeOperatingState() {
  if (!topics) return;
  const os = latest.take(topics.operating);
  // Not held back by its stamp: the stream is in order, and an estimate of the server's clock once held
  // back a reset (the topic sends a state once, so the page kept showing E-STOP). A state published
  // before the latch and sent after the answer shows for at most one publish period.
  if (os) applyOperatingState(os.msg);
}

// Shedding (issue 31: under load the pages went STALE up to 100 % of the time, and while STALE every
// command button is disabled and the joystick stops). The console's own work gives way before its
// data: when the animation frames come late (an average gap over SHED_GAP_MS, software rendering on
// two loaded cores), the 3D view renders at most ~3 times a second and its scene messages are decoded
// less often, the plots redraw at 2 Hz, and the joint values no longer wait for a frame: they are
// applied as they arrive (a few text nodes), so the data shown stays current.
const SHED_GAP_MS = 60;
const LONG_FRAME_MS = 150;
const SHED_HOLD_MS = 5000;
const LATE_FRAME_MS = 80;
let lastFrameStart = 0;
let frameGapAvg = 16;
let shedding = false;
let lateJointsAt = 0;

let longFrameAt = -Infinity;
function noteFrame(start) {
  const gap = lastFrameStart ? Math.min(2000, start - lastFrameStart) : 16;
  lastFrameStart = start;
  frameGapAvg = 0.85 * frameGapAvg + 0.15 * gap;
  // A frame that took more than LONG_FRAME_MS (a software render of the 3D view now and then is enough
  // to make the data old) sheds for SHED_HOLD_MS after it; so does an average gap over SHED_GAP_MS.
  if (gap > LONG_FRAME_MS && !document.hidden) longFrameAt = start;
  const shed = frameGapAvg > SHED_GAP_MS || start - longFrameAt < SHED_HOLD_MS;
  if (shed === shedding) return;
  shedding = shed;
  document.body.dataset.shedding = String(shed);
  shedPlots(shed);
  view?.setShedding?.(shed);
}

// The newest joint state, applied now (never older than what is shown: a late stream message after a
// fresher REST answer is dropped).
function takeJoints() {
  const js = latest.take(topics.joints);
  if (js && !(js.stampMs < shown.joints)) {
    applyJointState(js.msg, true);
    shown.joints = js.stampMs;
  }
}

// A joint message that arrives while the next frame is late is shown without waiting for it.
function jointsArrived() {
  const now = performance.now();
  if (now - lastFrameStart < LATE_FRAME_MS || now - lateJointsAt < 40) return;
  lateJointsAt = now;
  takeJoints();
  if (now - lastAgeUpdate >= 100) updateAges();
}

// One animation frame: the newest message of each topic, decoded once.
function renderFrame() {
  requestAnimationFrame(renderFrame);
  if (!topics) return;
  const start = performance.now();
  noteFrame(start);
  takeOperatingState();
  takeJoints();
  const cath = latest.take(topics.catheter);
  if (cath) {
    state.catheterMsg = cath.msg;
    state.catheterMsgMs = Date.now();
    shown.catheter = cath.stampMs;
    catheter?.update(cath.msg);
    if (cath.msg.state === 'PAUSED') {
      updateBanner();
      updateControls();
      plan?.renderStopReason();
    }
  }
  const diag = latest.take(topics.diagnostics);
  if (diag) applyDiagnostics(diag.msg);
  // The expensive panels take what is left of the frame's budget; one that has waited MAX_WAIT_MS
  // goes regardless, so that a slow machine (where the cheap part alone fills the budget) delays it but
  // never starves it. The 3D view also waits SCENE_SHARE times its own last cost (at most 1 s).
  const due = (topic) => latest.pending(topic) &&
      (performance.now() - start < FRAME_BUDGET_MS || start - (lastTaken.get(topic) ?? 0) >= MAX_WAIT_MS);
  if (start >= sceneNextAt && due(topics.scene)) {
    const t0 = performance.now();
    const scene = latest.take(topics.scene);
    lastTaken.set(topics.scene, start);
    if (scene) {
      view?.applySceneUpdate(ownEntities(scene.msg));
      applyTipFromScene(scene.msg);
    }
    sceneNextAt = t0 + Math.min(shedding ? 2000 : 1000, (performance.now() - t0) * (1 + (shedding ? 3 * SCENE_SHARE : SCENE_SHARE)));
  }
  if (!latest.pending(topics.scene)) shown.scene = shown.joints;
  if (view) view.contentStampMs = shown.scene;
  for (const key of ['ap', 'lateral', 'map']) {
    if (!due(topics[key])) continue;
    if (key !== 'map') {
      // The overlay first: the frame of the same time stamp finds it waiting.
      const overlay = latest.take(topics[`${key}Overlay`]);
      if (overlay) images[key].overlayMessage(overlay.msg);
    }
    const m = key === 'map' ? latest.take(topics[key]) : latest.take(topics[key], decodeCompressedImage);
    lastTaken.set(topics[key], start);
    if (m && key === 'map') view?.setPointCloud(m.msg);
    else if (m) images[key].frame(m.msg, m.stampMs);
  }
  feedKindPanel(due, start);
  if (start - lastAgeUpdate >= 100) updateAges();
}

// REST polling: the whole picture while the stream is not delivering (refused by a proxy, or gone),
// never while the server does not answer (then Backoff probes). The tip pose comes from the scene on
// the stream, from GET measured_cp only here.
let pollTick = 0;
async function poll() {
  const robot = state.robot?.name;
  if (!robot || wsStreaming() || !net.reachable) return;
  // A replaying server has no live state to poll (409 replay_mode): the recording is on the stream.
  if (document.body.classList.contains('replaying')) return;
  pollTick++;
  const jobs = [];
  jobs.push(api.measuredJs(robot).then((js) => {
    applyJointState(js, false);
    if (Number.isFinite(Number(js?.timestamp))) shown.joints = shown.scene = Number(js.timestamp) * 1000;
    state.lastRestOkMs = Date.now();
  }));
  jobs.push(api.setpointJs(robot).then((sp) => {
    joints?.updateSetpoint(sp);
    plotJointState(sp?.name, sp?.position, 0);
  }));
  const askedMs = wallNowMs();
  jobs.push(api.operatingState(robot).then((os) => applyOperatingState(os, askedMs)));
  if (pollTick % 4 === 0) {
    jobs.push(api.shape(robot).then(applyShape));
    jobs.push(api.measuredCp(robot).then(applyTipPose));
  }
  if (pollTick % 40 === 0) jobs.push(api.faults().then((d) => addEvents(eventsFromFaults(d))));
  const results = await Promise.allSettled(jobs);
  const unauthorised = results.find((r) => r.status === 'rejected' && r.reason?.status === 401);
  if (unauthorised) showStatus(describeError(unauthorised.reason), 'error');
  updateAges();
  refreshConnectionIndicator();
}

// Compares the clocks (for the ages) when the stream (re)connects and once a minute.
async function syncClock() {
  const robot = state.robot?.name;
  if (!robot || !net.reachable) return;
  try {
    await clock.measure(async () => (await api.measuredJs(robot)).timestamp);
  } catch {
    // ages keep the previous comparison (or assume agreeing clocks)
  }
  refreshConnectionIndicator();
}

// The lease lapses when unused (server side), so an open console that holds it renews it; GET /lease
// also tells who holds it when it is someone else.
async function pollLease() {
  if (!net.reachable) return;
  let status;
  try {
    status = await api.lease(state.robot?.name);
  } catch {
    return;  // a server without GET /lease: rely on command answers
  }
  if (!status) return;
  const mine = status.mine ?? status.yours;
  const expires = status.expires_s ?? status.expires_in_s;
  if (mine) {
    setLease(true);
    if (typeof expires === 'number' && expires < 15) {
      try {
        await api.takeLease(state.robot?.name);
      } catch (err) {
        setLease(false, describeError(err));
      }
    }
  } else if (status.holder) {
    setLease(false, `the operator lease is held by ${status.holder}`);
  } else {
    setLease(false);
  }
}

function startPolling() {
  setInterval(pollLease, 2000);
  let busy = false;
  setInterval(async () => {
    if (busy) return;  // never stack requests on a slow server
    busy = true;
    try {
      await poll();
    } finally {
      busy = false;
    }
  }, POLL_MS);
}

function topicNames(robotName) {
  return {
    joints: `/${robotName}/joint_states`, operating: `/${robotName}/operating_state`, scene: `/${robotName}/scene`,
    diagnostics: `/${robotName}/diagnostics`, events: '/safety/events',
    // The images in protobuf (foxglove.CompressedImage: the JPEG's bytes, no base64) and, beside each,
    // its overlay in JSON; the server builds /imaging/{view} (base64 JSON) only for clients that ask.
    ap: '/imaging/ap/compressed', lateral: '/imaging/lateral/compressed',
    apOverlay: '/imaging/ap/overlay', lateralOverlay: '/imaging/lateral/overlay',
    map: '/maps/vessel', catheter: `/${robotName}/catheter`,
    actuation: `/${robotName}/actuation`,  // mbcr_vd only (web/mbcr.js); not advertised for other kinds
  };
}

function connectWebSocket(robotName) {
  const scheme = location.protocol === 'https:' ? 'wss:' : 'ws:';
  const t = topicNames(robotName);
  topics = t;
  latest.clear();
  // Every handler acts for its own socket only: the socket of the robot shown before closes after this
  // one opened (the close handshake and the new upgrade race), and its close once cleared this one's
  // live flag, so the page polled REST with no images for minutes while its new stream was connected.
  const mine = () => window.tendrilConnection === conn;
  const conn = new FoxgloveConnection(`${scheme}//${location.host}/ws`, [...Object.values(t), ...kindPanelTopics()], {
    onOpen: () => {
      if (!mine()) return;
      state.wsLive = true;
      net.answered();
      images.ap.setConnected(true);
      images.lateral.setConnected(true);
      syncClock();
      // The stream carries only new events: fetch the ones raised while the socket was down (the
      // server closes a socket whose reader falls 5 s behind), so the log never has a hole.
      api.faults().then((d) => addEvents(eventsFromFaults(d))).catch(() => {});
    },
    onClose: () => {
      if (!mine()) return;
      state.wsLive = false;
      images.ap.setConnected(false);
      images.lateral.setConnected(false);
      refreshConnectionIndicator();
    },
    onServerInfo: (info) => { if (mine()) setRole(info?.metadata?.role); },
    onChannels: (advertised) => {
      if (!mine()) return;
      state.advertised = advertised;
      images.ap.setAdvertised(advertised.has(t.ap));
      images.lateral.setAdvertised(advertised.has(t.lateral));
      chooseTimingSource();
    },
    onRaw: (topic, bytes, stampNs) => {
      if (!mine()) return;
      if (topic === TRACKING_TOPIC) {
        try {
          tipTracking?.onMessage(JSON.parse(new TextDecoder().decode(bytes)));
        } catch {
          // not JSON: ignored
        }
        return;
      }
      if (topic === t.actuation) {
        try {
          mbcr?.onMessage(JSON.parse(new TextDecoder().decode(bytes)));
        } catch {
          // not JSON: ignored
        }
        return;
      }
      if (topic === t.events) {
        // Events are never coalesced here; the server gives a slow reader only a topic's newest
        // message, so `recent` repeats the last events and a message never seen loses none.
        try {
          const msg = JSON.parse(new TextDecoder().decode(bytes));
          addEvents(Array.isArray(msg.recent) ? msg.recent : Array.isArray(msg.events) ? msg.events : [msg]);
        } catch {
          // not JSON: ignored
        }
        return;
      }
      if (kindPanel?.everyMessage?.includes(topic)) {
        // Small, frequent messages (a force plot's samples): every one, not the newest per frame.
        try {
          kindPanel.onMessage(topic, JSON.parse(new TextDecoder().decode(bytes)), Number(stampNs) / 1e6);
        } catch {
          // not JSON: ignored
        }
        return;
      }
      latest.put(topic, bytes, stampNs);
      if (topic === t.operating) takeOperatingState();
      if (topic === t.joints) {
        state.lastWsJointMs = Date.now();
        const stampMs = latest.stampOf(topic);
        state.latencyMs.push({at: wallNowMs(), ms: clock.ageMs(stampMs)});
        if (state.latencyMs.length > 200) state.latencyMs.splice(0, 100);
        jointsArrived();
      }
    },
    // The server's warnings; one about another robot ("ur5 e-stop: …", also in the Events tab) does not
    // take the status line of the robot shown (it overwrote what had become of this robot's move).
    onStatus: (msg) => {
      if (!mine() || !(msg.level >= 1)) return;
      const text = String(msg.message ?? '');
      if (state.robots.some((r) => r !== state.robot && text.startsWith(`${r.name} `))) return;
      // A note this page has just made about the same event (what an E-STOP cleared, a move it ended)
      // keeps its place; the server's words follow it.
      if (ui.status.classList.contains('notice') && Date.now() - statusSetMs < 3000) {
        if (!ui.status.title.includes(text)) showStatus(`${ui.status.title} · server: ${text}`, 'notice');
        return;
      }
      showStatus(`server: ${text}`, msg.level >= 2 ? 'error' : 'ok');
    },
  });
  if (tipTracking?.on) conn.addTopic(TRACKING_TOPIC);  // the switch stays on across a robot change
  window.tendrilConnection = conn;
  conn.open();  // for debugging from the browser console, and the browser tests
  window.tendrilLive = {latest, clock, state, shown, net, view: () => view, tracking: () => tipTracking,
                       load: () => ({shedding, frameGapMs: frameGapAvg})};
}

// ---------------------------------------------------------------- loop timing
// From the /{robot}/diagnostics topic (10 Hz) when the server publishes it; otherwise GET /metrics
// once a second (Prometheus text: tendril_control_period_error_us and tendril_control_work_us). Both give
// the deviation of the loop period from nominal (jitter) and the compute time per cycle.
const TIMING_SERIES = {
  diagnostics: {legend: ['period error p99', 'max', 'work p99'], unit: 'µs',
                source: 'diagnostics topic, 10 Hz', short: 'diagnostics'},
  metrics: {legend: ['period error p99', 'max', 'work p99'], unit: 'µs',
            source: 'GET /metrics, 1 Hz', short: '/metrics'},
};
const TIMING_COLORS = ['#3fb950', '#e3b341', '#f85149'];

function chooseTimingSource() {
  if (!state.robot) return;
  const next = state.advertised.has(`/${state.robot.name}/diagnostics`) ? 'diagnostics' : 'metrics';
  if (next === state.timingSource) return;
  state.timingSource = next;
  const spec = TIMING_SERIES[next];
  timingPlot.configure({unit: spec.unit, minSpan: 10});
  spec.legend.forEach((label, i) => { timingPlot.series[i].label = label; });
  ui.timingSource.textContent = `(${spec.unit} · ${spec.short})`;
  ui.timingSource.title = `source: ${spec.source}`;
  ui.timingSource.dataset.source = next;
  renderTimingLegend();
}

// Legend with the latest value of each series: the max can dwarf the p99 on the shared axis.
function renderTimingLegend() {
  const spec = TIMING_SERIES[state.timingSource];
  if (!spec) return;
  // Drawn inside the plot; the same numbers as text for screen readers.
  ui.timingLegend.textContent = spec.legend.map((label, i) => {
    const v = timingPlot.latest(i);
    return `${label} ${Number.isFinite(v) ? formatMicros(v) : '—'}`;
  }).join(', ');
}

function showOverruns(overruns) {
  const spec = TIMING_SERIES[state.timingSource];
  const n = Number.isFinite(overruns) ? ` · ${overruns} overrun${overruns === 1 ? '' : 's'}` : '';
  ui.timingSource.textContent = `(${spec.unit} · ${spec.short}${n})`;
  ui.timingSource.title = `source: ${spec.source}; overruns: control cycles past their deadline since start`;
}

function formatMicros(us) {
  return us >= 1000 ? `${(us / 1000).toFixed(1)} ms` : `${us.toFixed(0)} µs`;
}

function applyDiagnostics(msg) {
  if (state.timingSource !== 'diagnostics' || !msg || !msg.period_us) return;
  const now = performance.now() / 1000;
  timingPlot.setMessage(null);
  timingPlot.push(0, now, Number(msg.period_us.p99));
  timingPlot.push(1, now, Number(msg.period_us.max));
  timingPlot.push(2, now, Number(msg.work_us?.p99));
  showOverruns(Number(msg.overruns));
  renderTimingLegend();
}

// Value of one Prometheus sample line (name and exact label set), NaN when absent.
function prometheusValue(text, name, labels = '') {
  const wanted = labels ? `${name}{${labels}}` : name;
  for (const line of text.split('\n')) {
    if (line.startsWith('#')) continue;
    const at = line.lastIndexOf(' ');
    if (at > 0 && line.slice(0, at).trim() === wanted) return Number(line.slice(at + 1));
  }
  return NaN;
}

async function pollMetrics() {
  if (state.timingSource !== 'metrics' || !net.reachable) return;
  let text;
  try {
    text = await api.metricsText();
  } catch (err) {
    timingPlot.setMessage(err instanceof ApiError && err.status === 404
      ? 'Loop timing not available: the server has neither a diagnostics topic nor GET /metrics.'
      : `Loop timing unavailable: ${describeError(err)}`);
    return;
  }
  const p99 = prometheusValue(text, 'tendril_control_period_error_us', 'quantile="0.99"');
  const max = prometheusValue(text, 'tendril_control_period_error_us', 'quantile="1"');
  const work = prometheusValue(text, 'tendril_control_work_us', 'quantile="0.99"');
  if (![p99, max, work].some(Number.isFinite)) {
    timingPlot.setMessage('Loop timing not available: /metrics has no tendril_control_* samples.');
    return;
  }
  timingPlot.setMessage(null);
  const now = performance.now() / 1000;
  timingPlot.push(0, now, p99);
  timingPlot.push(1, now, max);
  timingPlot.push(2, now, work);
  renderTimingLegend();
  const overruns = prometheusValue(text, 'tendril_control_overruns_total');
  showOverruns(overruns);
}

// ---------------------------------------------------------------- commands
async function estop() {
  // Sent first, before anything else on the page reacts: this is the one command that must not wait.
  state.estopSentMs = wallNowMs();
  try {
    const answer = await api.estop();
    // The server's answer says the e-stop is latched: shown at once, not when the stream or the next
    // animation frame brings it (a page whose frames lag showed PAUSED for seconds after the latch).
    if (answer?.estop === true && state.operating) applyOperatingState({...state.operating, estop: true});
    showStatus(`E-STOP sent: every robot is stopping${state.goalsCleared ? `. ${state.goalsCleared}` : ''}`,
               state.goalsCleared ? 'notice' : 'ok');
  } catch (err) {
    showStatus(`E-STOP FAILED: ${describeError(err)}. Use the hardware stop.`, 'error');
  }
  refreshStateSoon();
}

// Withdraws the catheter by `mm` while held (the one motion a limit hold allows); the server moves the
// insertion back by exactly that at the joystick's full speed, however slow the link is.
async function withdraw(mm) {
  const answer = await runCommand(`Withdraw ${mm} mm`, () => api.stateCommand(state.robot.name, 'withdraw', {distance_mm: mm}));
  if (answer) showStatus(`Withdrawing ${mm} mm (to ${Number(answer.withdrawing_to_mm).toFixed(1)} mm)`, 'ok');
}

function selectTab(tab) {
  for (const t of ui.tabs) {
    const selected = t === tab;
    t.setAttribute('aria-selected', String(selected));
    t.tabIndex = selected ? 0 : -1;
    document.getElementById(t.getAttribute('aria-controls')).hidden = !selected;
  }
  if (tab.id === 'tab-plan') plan?.refresh();
  if (tab.id === 'tab-tracking') tipTracking?.refresh();
}

// Asks before taking the lease from another operator; the server's token is valid for 15 s.
async function offerTakeover(err) {
  const holder = err.details.holder || 'another operator';
  const robot = state.robots.length > 1 && state.robot ? ` of ${state.robot.name}` : '';
  ui.takeoverText.textContent = `The operator lease${robot} is held by ${holder}. Taking it over stops their control ` +
    'of the robot at once; they are told. Do this only when you have agreed it with them.';
  ui.takeoverDialog.returnValue = '';
  ui.takeoverDialog.showModal();
  const choice = await new Promise((resolve) => {
    ui.takeoverDialog.addEventListener('close', () => resolve(ui.takeoverDialog.returnValue), {once: true});
  });
  if (choice !== 'confirm') {
    showStatus(`Lease takeover cancelled: the lease stays with ${holder}`, 'ok');
    return;
  }
  try {
    await api.takeLease(state.robot?.name, err.details.takeover_token);
    setLease(true);
    showStatus(`Lease taken over from ${holder}: you are the operator`, 'ok');
  } catch (e) {
    showStatus(`Takeover refused: ${describeError(e)}`, 'error');
  }
}

function prettyMode(mode) {
  const s = String(mode).replace(/_/g, ' ');
  return s.charAt(0).toUpperCase() + s.slice(1);
}

function buildModeBar(robot) {
  const modes = Array.isArray(robot.modes) && robot.modes.length ? robot.modes : ['joint'];
  ui.modeButtons.replaceChildren(...modes.map((mode) => {
    const b = document.createElement('button');
    b.type = 'button';
    b.className = 'btn mode-btn';
    b.dataset.mode = mode;
    b.dataset.testid = `mode-${mode}`;
    b.textContent = prettyMode(mode);
    b.setAttribute('aria-label', `${prettyMode(mode)} mode`);
    b.setAttribute('aria-pressed', 'false');
    return b;
  }));
  updateModeBar();
}

// This console's refused switches (mode, the server's sentence, when): a refusal the server keeps is
// this console's when it names the same mode and reason as one of them, else another client's.
const ownRefusals = [];
function isOwnRefusal(refusal) {
  return ownRefusals.some((r) => r.mode === refusal.mode && !!refusal.reason && r.message.includes(refusal.reason));
}

function updateModeBar() {
  const os = state.operating;
  for (const b of ui.modeButtons.querySelectorAll('button[data-mode]')) {
    const active = !!os && os.mode === b.dataset.mode;
    b.setAttribute('aria-pressed', String(active));
    b.classList.toggle('active', active);
    b.disabled = state.stale || state.role === 'viewer';
  }
  ui.modeBar.dataset.currentMode = os?.mode ?? '';
  // The last refused switch, as the server keeps it (until the next switch that succeeds) for whoever
  // asked. This console's own refusal is its error, said whole (wrapped in its box); another client's
  // (a script, another console) is only noted, compactly and attributed, with the reason in the title:
  // a curl script's refusal once filled every console's mode bar with 640 px of text that did not wrap.
  const refusal = os?.mode_refusal;
  const own = refusal && isOwnRefusal(refusal);
  ui.modeRefusal.textContent = !refusal ? '' : own ? `${prettyMode(refusal.mode)} refused: ${operatorWords(refusal.reason)}`
      : `Another client's switch to ${prettyMode(refusal.mode)} was refused`;
  ui.modeRefusal.title = refusal ? `${own ? 'Your' : 'Another client\'s (not this console\'s)'} switch to ` +
      `${prettyMode(refusal.mode)} was refused: ${refusal.reason}` : '';
  ui.modeRefusal.dataset.owner = !refusal ? '' : own ? 'this' : 'other';
  ui.modeRefusal.hidden = !refusal;
  const path = plan?.path;
  ui.configStep.textContent = path && path.loaded ? (path.step >= 0 ? `${path.step} / ${path.steps - 1}` : `— / ${path.steps - 1}`) : '—';
}

async function refreshStateSoon() {
  // With the stream live it is the authority: it sends every change, and a REST answer that was
  // read before the control loop took the command would overwrite a newer streamed state.
  if (!state.robot || state.wsLive) return;
  try {
    applyOperatingState(await api.operatingState(state.robot.name));
  } catch {
    // the next poll or stream message will bring it
  }
}

function wireCommands() {
  ui.estopButton.addEventListener('click', estop);
  document.addEventListener('keydown', (ev) => {
    if (ev.key === 'Escape' && !ev.repeat) {
      ev.preventDefault();
      estop();
    }
  }, {capture: true});
  ui.resetButton.addEventListener('click', async () => {
    // A latched e-stop is reset for every robot; a drive fault is acknowledged by disabling the robot
    // (the server wants that before it enables again).
    if (state.operating && state.operating.estop) {
      await runCommand('Reset e-stop', () => api.estopReset());
    } else {
      const os = await runCommand('Acknowledge fault', () => api.stateCommand(state.robot.name, 'disable'));
      if (os && os.state) applyOperatingState(os);
    }
    refreshStateSoon();
  });
  ui.enableButton.addEventListener('click', async () => {
    const os = await runCommand('Enable', () => api.stateCommand(state.robot.name, 'enable'));
    if (os) applyOperatingState(os);
  });
  ui.disableButton.addEventListener('click', async () => {
    const os = await runCommand('Disable', () => api.stateCommand(state.robot.name, 'disable'));
    if (os) applyOperatingState(os);
  });
  ui.pauseButton.addEventListener('click', async () => {
    await runCommand('Pause', () => api.stateCommand(state.robot.name, 'pause'));
    refreshStateSoon();
  });
  const resume = async () => {
    // Refused (409) while the hold's cause persists: the status line then says why and what to do.
    await runCommand('Resume', () => api.stateCommand(state.robot.name, 'resume'));
    refreshStateSoon();
  };
  ui.resumeButton.addEventListener('click', resume);
  ui.bannerResume.addEventListener('click', resume);
  ui.relaxButton.addEventListener('click', async () => {
    // While relaxing the same button stops it (a pause while held stops the relax).
    if (ui.relaxButton.dataset.relaxing === 'true') await runCommand('Stop relaxing', () => api.stateCommand(state.robot.name, 'pause'));
    else if (await runCommand('Relax springs', () => api.stateCommand(state.robot.name, 'relax'))) {
      showStatus('Relaxing the springs: the bend drives follow them…', 'notice');
      relaxWatch = {sinceMs: Date.now(), seenRunning: false};
    }
    refreshStateSoon();
  });
  ui.withdrawButton.addEventListener('click', () => withdraw(1.0));
  ui.leaseButton.addEventListener('click', async () => {
    if (state.leaseHeld) {
      if (await runCommand('Release lease', () => api.releaseLease(state.robot?.name))) setLease(false);
      return;
    }
    try {
      await api.takeLease(state.robot?.name);
      setLease(true);
      showStatus('Lease taken: you are the operator', 'ok');
    } catch (err) {
      // 409 lease_held: the message names who holds it and why
      setLease(false, err instanceof ApiError && err.code === 'lease_held' ? err.message : '');
      const offer = err instanceof ApiError && err.code === 'lease_held' && err.details.takeover_token;
      // With a takeover offer the server's message carries the token: say it in words instead.
      showStatus(offer ? `Lease held by ${err.details.holder || 'another operator'}: take it over only after confirming`
                       : `Lease refused: ${describeError(err)}`, 'error');
      // A server that allows takeover sends a short-lived token: taking over needs a deliberate yes.
      if (err instanceof ApiError && err.code === 'lease_held' && err.details.takeover_token) {
        await offerTakeover(err);
      }
    }
  });
  ui.modeButtons.addEventListener('click', async (ev) => {
    const button = ev.target.closest('button[data-mode]');
    if (!button) return;
    const mode = button.dataset.mode;
    let refusedWith = '';
    const answer = await runCommand(`Mode ${prettyMode(mode)}`, async () => {
      try {
        return await api.setMode(state.robot.name, mode);
      } catch (err) {
        refusedWith = describeError(err);
        throw err;
      }
    });
    if (!answer) {
      ownRefusals.push({mode, message: refusedWith, atMs: wallNowMs()});
      if (ownRefusals.length > 8) ownRefusals.shift();
    }
    ui.modeBar.dataset.refused = answer ? '' : mode;
    updateModeBar();
    refreshStateSoon();
  });
  for (const tab of ui.tabs) {
    tab.addEventListener('click', () => selectTab(tab));
    tab.addEventListener('keydown', (ev) => {
      // Arrow keys move between tabs (WAI-ARIA tabs pattern).
      const shown = ui.tabs.filter((t) => !t.hidden);
      const i = shown.indexOf(tab);
      const next = ev.key === 'ArrowRight' ? shown[(i + 1) % shown.length]
                 : ev.key === 'ArrowLeft' ? shown[(i + shown.length - 1) % shown.length] : null;
      if (next) {
        ev.preventDefault();
        selectTab(next);
        next.focus();
      }
    });
  }
  ui.plotJoint.addEventListener('change', () => {
    const joint = state.robot.joints.find((j) => j.name === ui.plotJoint.value);
    trackingPlot.configure({unit: displayUnit(joint?.unit).symbol || '', minSpan: 0.1});
  });
  ui.form.addEventListener('submit', async (ev) => {
    ev.preventDefault();
    if (!joints || ui.moveButton.disabled) return;
    // Joints nobody touched go at the setpoint the server has now, not at what the page last saw.
    const answer = await runCommand('Move', async () => {
      const live = await api.setpointJs(state.robot.name);
      joints.updateSetpoint(live);
      const preview = joints.preview();
      const result = await api.moveJp(state.robot.name, joints.goals(live.position));
      return {...result, preview};
    });
    if (answer) {
      const d = typeof answer.duration_s === 'number' ? ` (about ${answer.duration_s.toFixed(1)} s)` : '';
      showStatus(`Moving to goal${d}: ${answer.preview.replace(/^will move: /, '')}`, 'ok');
      joints.clearEdits();
    }
  });
  ui.goalFromSetpoint.addEventListener('click', () => { joints?.clearEdits(); updateControls(); });
  ui.fitView.addEventListener('click', () => view?.fit());
}

// A step move: one joint by ±1 mm or ±5° from the setpoint the server has now (never from what the page
// last saw); every other joint stays where it is.
async function stepJoint(index, delta, amount) {
  if (!joints || !state.robot) return;
  const name = joints.jointName(index);
  const answer = await runCommand(`Step ${name} ${amount}`, async () => {
    const live = await api.setpointJs(state.robot.name);
    const goal = joints.stepGoal(live.position, index, delta);
    if (!goal) throw new Error(`${name} is at its ${delta > 0 ? 'upper' : 'lower'} limit`);
    return {...(await api.moveJp(state.robot.name, goal)), from: live.position[index], to: goal[index]};
  });
  if (answer) showStatus(`Step ${name} ${amount}: moving ${joints.format(index, answer.from)} → ${joints.format(index, answer.to)}`, 'ok');
}

// ---------------------------------------------------------------- start-up
async function loadView() {
  try {
    const {CatheterView} = await import('./scene.js');
    view = new CatheterView(ui.scene);
    view.setShedding?.(shedding);
  } catch (err) {
    const div = document.createElement('div');
    div.className = 'scene-message';
    div.textContent = `3D view unavailable (${err.message}). Joint control still works.`;
    ui.scene.appendChild(div);
  }
}

// ---------------------------------------------------------------- kind-specific panel
// The selected robot kind's own panel (robot_panels.js) in the "robot" tab; none for the catheter.
let kindPanel = null;
let kindPanelSeq = 0;

function kindPanelTopics() {
  return kindPanel ? [...new Set([...(kindPanel.topics || []), ...(kindPanel.everyMessage || [])])] : [];
}

async function mountKindPanel(robot) {
  const seq = ++kindPanelSeq;
  const tab = $('#tab-robot');
  const root = $('#panel-robot');
  if (kindPanel) {
    for (const t of kindPanelTopics()) window.tendrilConnection?.removeTopic(t);
    try {
      kindPanel.destroy?.();
    } catch {
      // a panel that fails to clean up must not stop the robot change
    }
    kindPanel = null;
  }
  root.replaceChildren();
  const entry = panelFor(robot);
  if (!entry) {
    if (tab.getAttribute('aria-selected') === 'true') selectTab($('#tab-joints'));
    tab.hidden = true;
    return;
  }
  let mod;
  try {
    mod = await entry.load();
  } catch (err) {
    root.textContent = `The ${entry.title} panel could not be loaded (${err.message}).`;
    tab.hidden = false;
    return;
  }
  if (seq !== kindPanelSeq) return;  // another robot was selected meanwhile
  tab.textContent = entry.title;
  tab.hidden = false;
  kindPanel = mod.createPanel(root, {
    api, robot, view: () => view, status: showStatus, ageMs: (stampMs) => clock.ageMs(stampMs),
    commandable: () => !state.stale && state.role !== 'viewer' && !state.offline,
  });
  for (const t of kindPanelTopics()) window.tendrilConnection?.addTopic(t);
  updateControls();
}

function feedKindPanel(due, start) {
  if (!kindPanel) return;
  for (const topic of kindPanel.topics || []) {
    if (!due(topic)) continue;
    const m = latest.take(topic);
    lastTaken.set(topic, start);
    if (!m) continue;
    try {
      kindPanel.onMessage(topic, m.msg, m.stampMs);
    } catch (err) {
      console.error(`robot panel: ${topic}:`, err);
    }
  }
}

// What a robot offers, from its GET /robots entry: the Plan tab (vessel plans, path following) and the
// Tracking tab (the imaged tip) only for a robot with those modes; the arm asked GET path_following
// every 5 s and got a 422 each time.
const hasModes = (robot, mode) => Array.isArray(robot?.modes) && robot.modes.includes(mode);
const offersPlan = (robot) => hasModes(robot, 'path_following');
const offersTracking = (robot) => hasModes(robot, 'image_guided');

// The robot shown is kept across a reload: ?robot= in the address (a link to one robot), else the one
// this browser showed last.
const ROBOT_KEY = 'tendril.robot';
function rememberedRobot() {
  const fromUrl = new URL(window.location.href).searchParams.get('robot');
  if (fromUrl && state.robots.some((r) => r.name === fromUrl)) return fromUrl;
  let stored = null;
  try {
    stored = localStorage.getItem(ROBOT_KEY);
  } catch {
    // storage unavailable (private mode): the first robot
  }
  return stored && state.robots.some((r) => r.name === stored) ? stored : state.robots[0].name;
}
function rememberRobot(name) {
  try {
    localStorage.setItem(ROBOT_KEY, name);
  } catch {
    // storage unavailable: the address still says it
  }
  const url = new URL(window.location.href);
  if (state.robots.length > 1) url.searchParams.set('robot', name);
  else url.searchParams.delete('robot');
  history.replaceState(null, '', url.pathname + (url.search || '') + url.hash);
}

// A scene message's entities of the shown robot only (ids are "<robot>/…"; a panel's own have no robot).
function ownEntities(update) {
  const others = state.robots.filter((r) => r !== state.robot).map((r) => `${r.name}/`);
  if (!update || !Array.isArray(update.entities) || !others.length) return update;
  return {...update, entities: update.entities.filter((e) => !others.some((p) => String(e.id || '').startsWith(p)))};
}

function selectRobot(name) {
  const robot = state.robots.find((r) => r.name === name) || state.robots[0];
  if (ui.robotSelect.value !== robot.name) ui.robotSelect.value = robot.name;
  rememberRobot(robot.name);
  // Nothing of the robot shown before stays in the 3D view.
  for (const other of state.robots) if (other !== robot) view?.removeEntities(`${other.name}/`);
  // Tabs for what this robot offers; a hidden tab that was open gives way to Joints.
  for (const [tab, offered] of [[$('#tab-plan'), offersPlan(robot)], [$('#tab-tracking'), offersTracking(robot)]]) {
    tab.hidden = !offered;
    if (!offered && tab.getAttribute('aria-selected') === 'true') selectTab($('#tab-joints'));
  }
  // A status line about the last robot (e.g. "Lease taken") would read as if it were about this one.
  if (state.robot && state.robot !== robot) showStatus(`Showing ${robot.name}`, 'ok');
  state.robot = robot;
  ui.robotKind.textContent = robot.kind ? robot.kind.replace(/_/g, ' ') : '';
  // The 3D view is titled by what it draws: "Steerable catheter shape", "Serial arm shape".
  const kind = robot.kind ? robot.kind.replace(/_/g, ' ') : 'robot';
  $('[data-testid="scene-title"]').textContent = `${kind[0].toUpperCase()}${kind.slice(1)} shape`;
  document.title = `${robot.name.toUpperCase()} · tendril console`;
  joints = buildJointPanel(ui.form, robot.joints, () => {
    if (joints?.edited()) goalsTypedAgain();
    updateControls();
  }, {onStep: stepJoint});
  procedure.setRobot(robot);
  buildModeBar(robot);
  ui.catheterTab.hidden = !robot.configuration;
  if (robot.configuration) {
    catheter ??= new CatheterPanel($('#panel-catheter'), api, {robotName: robot.name, showStatus});
    catheter.setRobot(robot);
    catheter.setViewer(state.role === 'viewer');
    catheter.setCommandable(!state.stale);
  }
  // The variable-diameter robot's diameter and forces (web/mbcr.js): only for its kind.
  const isMbcr = robot.kind === 'mbcr_vd';
  ui.mbcrTab.hidden = !isMbcr;
  if (isMbcr) mbcr ??= new MbcrPanel($('#panel-mbcr'), api, {status: showStatus});
  mbcr?.setRobot(isMbcr ? robot : null);
  if (!isMbcr && ui.mbcrTab.getAttribute('aria-selected') === 'true') selectTab(ui.tabs[0]);
  // The Tip tab: the tip's position, jog and goal in the robot's Cartesian mode, the arm's force.
  const tipTab = $('#tab-tip');
  const cartesianMode = cartesianModeOf(robot);
  tipTab.hidden = !cartesianMode;
  tipTab.textContent = robot.kind === 'serial_arm' ? 'Tool' : 'Tip';
  if (cartesianMode) {
    tipPanel ??= new TipPanel($('#panel-tip'), {api, status: showStatus});
  }
  tipPanel?.setRobot(cartesianMode ? robot : null);
  if (!cartesianMode && tipTab.getAttribute('aria-selected') === 'true') selectTab(ui.tabs[0]);
  ui.plotJoint.replaceChildren(...robot.joints.map((j) => new Option(`${j.name.replace(/_/g, ' ')} (${displayUnit(j.unit).symbol})`, j.name)));
  const first = robot.joints[0];
  trackingPlot?.configure({unit: displayUnit(first?.unit).symbol || '', minSpan: 0.1});
  state.timingSource = null;
  if (timingPlot) chooseTimingSource();
  // Each robot has its own lease: show the new robot's, not the last one's, until GET says otherwise.
  if (state.robots.length > 1) {
    setLease(false);
    pollLease();
  }
  updateControls();
  mountKindPanel(robot);
  if (window.tendrilConnection) {
    window.tendrilConnection.close();
    state.wsLive = false;  // until the new robot's socket opens
    connectWebSocket(robot.name);
  }
}

async function start() {
  trackingPlot = new TimePlot($('[data-testid="tracking-plot"]'), {
    series: [{label: 'setpoint', color: '#e6edf3', dash: true}, {label: 'measured', color: '#4ea1ff'}], windowS: 10,
  });
  timingPlot = new TimePlot($('[data-testid="timing-plot"]'), {
    series: TIMING_COLORS.map((color) => ({color, format: formatMicros})), windowS: 60, floorZero: true, minSpan: 10,
  });
  plan = new PlanPanel({
    api, view: () => view, robot: () => state.robot, operating: () => state.operating, status: showStatus,
    commandable: () => !state.stale && state.role !== 'viewer',
    hold: () => currentHold(),
    onPathLoaded: () => updateModeBar(),
  });
  tipTracking = new TrackingPanel($('#panel-tracking'), {
    api, connection: () => window.tendrilConnection ?? null, view: () => view, status: showStatus,
  });
  document.body.dataset.shedding = 'false';
  wireCommands();
  wireEnlarge($('main.layout'));
  arrangeImaging($('.images-panel'));
  renderEvents();
  setLease(false);
  setConnection('offline', 'connecting…');
  loadView();
  for (;;) {
    try {
      state.robots = await api.robots();
      if (Array.isArray(state.robots) && state.robots.length) break;
      showStatus('The server describes no robots.', 'error');
    } catch (err) {
      showStatus(`Cannot load the robot list: ${describeError(err)}`, 'error');
    }
    await new Promise((r) => setTimeout(r, 1500));
  }
  ui.robotSelect.replaceChildren(...state.robots.map((r) => new Option(r.name, r.name)));
  ui.robotSelect.addEventListener('change', () => selectRobot(ui.robotSelect.value));
  selectRobot(rememberedRobot());
  try {
    addEvents(eventsFromFaults(await api.faults()));
  } catch {
    // events are a convenience; the stream brings new ones
  }
  connectWebSocket(state.robot.name);
  // A server replaying a recording shows its replay bar (and drives no robot: commands answer 409).
  new ReplayBar($('[data-testid="replay-bar"]'), {api, status: showStatus}).start();
  startPolling();
  setInterval(refreshConnectionIndicator, 500);
  setInterval(syncClock, 60000);
  setInterval(pollMetrics, 1000);
  requestAnimationFrame(renderFrame);
  setInterval(() => { if (performance.now() - lastAgeUpdate > 250) updateAges(); }, 250);  // rAF sleeps in hidden tabs
  plan.refresh();
  if (offersPlan(state.robot)) plan.refreshPath();
  // Path-following state (step, moving) is not on the stream (see the README): GET it once a second
  // while a plan is loaded, every 5 s otherwise, never while the server does not answer.
  let pathTick = 0;
  setInterval(() => {
    pathTick++;
    if (plan.pathAvailable === false || !net.reachable || !offersPlan(state.robot)) return;
    if (plan.path?.loaded || pathTick % 5 === 0) plan.refreshPath().then(updateModeBar);
  }, 1000);
}

start();
