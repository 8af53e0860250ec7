// tendril console: wires the REST API (commands, fallback polling) and the Foxglove WebSocket stream
// (live joint states, operating state, scene, safety events) to the page. The joint panel is built
// from GET /api/v1/robots, so any robot the server describes gets its own rows and limits.
// Terms: CRTK measured_js / setpoint_js / move_jp (see API.md); lease = the right to command.
import {Api, ApiError} from './api.js';
import {FoxgloveConnection} from './foxglove.js';
import {buildJointPanel} from './joints.js';

const api = new Api();
const $ = (sel) => document.querySelector(sel);

const ui = {
  robotSelect: $('#robot-select'),
  robotKind: $('[data-testid="robot-kind"]'),
  badge: $('[data-testid="state-badge"]'),
  badgeValue: $('[data-testid="state-value"]'),
  connection: $('[data-testid="connection-indicator"]'),
  connectionText: $('[data-testid="connection-indicator"] .connection-text'),
  lease: $('[data-testid="lease-status"]'),
  leaseButton: $('#lease-button'),
  enableButton: $('#enable-button'),
  disableButton: $('#disable-button'),
  resetButton: $('#estop-reset-button'),
  estopButton: $('#estop-button'),
  banner: $('[data-testid="banner"]'),
  bannerTitle: $('[data-testid="banner"] .banner-title'),
  bannerCause: $('[data-testid="banner"] .banner-cause'),
  form: $('#joint-form'),
  moveButton: $('#move-button'),
  moveHint: $('[data-testid="move-hint"]'),
  goalFromSetpoint: $('#goal-from-setpoint-button'),
  status: $('[data-testid="command-status"]'),
  events: $('[data-testid="event-log"]'),
  tip: $('[data-testid="tip-position"]'),
  fitView: $('#fit-view-button'),
  scene: $('#scene'),
};

const state = {
  robots: [],
  robot: null,          // description of the selected robot from GET /robots
  operating: null,      // latest operating_state
  leaseHeld: false,
  wsLive: false,        // WebSocket open and delivering the joint stream
  lastWsJointMs: 0,
  lastRestOkMs: 0,
  events: [],           // newest first
  lastFaultCause: '',
  offline: false,       // neither stream nor REST answered lately
};

let joints = null;      // joint panel controller
let view = null;        // CatheterView, loaded lazily so a WebGL/three failure cannot break the controls

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
function showStatus(text, kind = 'ok') {
  ui.status.textContent = text;
  ui.status.className = `command-status ${kind}`;
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
function applyOperatingState(os) {
  if (!os || typeof os.state !== 'string') return;
  state.operating = os;
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
}

// The status strip is always there (so the layout never jumps when a fault arrives); its level says
// how serious: ok, paused, offline, fault, estop.
function updateBanner() {
  const os = state.operating;
  let level = 'ok';
  let title = 'Normal';
  let cause = 'No active fault.';
  if (os && os.estop) {
    level = 'estop';
    title = 'Emergency stop latched';
    cause = `${state.lastFaultCause || 'Motion is stopped on every robot.'} — find the cause, press Reset, then Enable.`;
  } else if (os && os.state === 'FAULT') {
    level = 'fault';
    title = 'Fault';
    // The cause first and whole; what to do next is in the Move hint and the Reset button's title.
    cause = state.lastFaultCause || 'The robot stopped; see the events for the cause.';
  } else if (state.offline && state.robot) {
    level = 'offline';
    title = 'No connection';
    cause = 'The values shown are stale. The server keeps the robot safe on its own; check the network or tendrild.';
  } else if (os && os.state === 'PAUSED') {
    level = 'paused';
    title = 'Paused';
    cause = 'The robot holds its position.';
  } else if (!os) {
    title = 'Starting';
    cause = 'Waiting for the robot state…';
  }
  ui.banner.className = `banner level-${level}`;
  ui.banner.dataset.level = level;
  ui.banner.title = `${title}: ${cause}`;
  ui.bannerTitle.textContent = title;
  ui.bannerCause.textContent = cause;
}

function updateControls() {
  const os = state.operating;
  const estop = !!(os && os.estop);
  const enabled = !!(os && os.state === 'ENABLED');
  const fault = !!(os && os.state === 'FAULT');
  ui.enableButton.disabled = !os || estop || enabled || fault;
  ui.disableButton.disabled = !os || os.state === 'DISABLED';
  ui.resetButton.disabled = !os || (!estop && os.state !== 'FAULT');
  let hint = '';
  if (!os) hint = 'Waiting for the robot state…';
  else if (estop) hint = 'E-stop latched: Reset, then Enable.';
  else if (fault) hint = 'Fault: Reset to acknowledge, then Enable.';
  else if (!enabled) hint = 'Enable the robot to move.';
  else if (!state.leaseHeld) hint = 'Take the lease to command.';
  const invalid = joints ? joints.invalidJoints() : [];
  if (!hint && invalid.length) hint = `Goal outside limits: ${invalid.join(', ')}`;
  ui.moveButton.disabled = !os || estop || !enabled || invalid.length > 0;
  ui.moveHint.textContent = hint;
}

function setLease(held, otherMessage = '') {
  state.leaseHeld = held;
  ui.lease.classList.toggle('held', held);
  ui.lease.classList.toggle('other', !held && !!otherMessage);
  ui.lease.textContent = held ? 'lease: yours' : otherMessage ? 'lease: other operator' : 'no lease (viewer)';
  ui.lease.title = otherMessage;
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
  for (const ev of list) {
    const key = `${ev.time}|${ev.kind}|${ev.message}`;
    if (state.events.some((e) => e.key === key)) continue;
    state.events.push({...ev, key});
    changed = true;
  }
  if (!changed) return;
  state.events.sort((a, b) => (b.time || 0) - (a.time || 0));
  state.events.length = Math.min(state.events.length, 200);
  // The cause shown in the banner: the newest event that is not a plain state transition.
  const cause = state.events.find((e) => e.kind !== 'transition') || state.events[0];
  if (cause) state.lastFaultCause = `${cause.kind ? cause.kind + ': ' : ''}${cause.message || ''}`;
  renderEvents();
  updateBanner();
}

function renderEvents() {
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
function applyJointState(js, withSetpoint) {
  if (!joints || !js) return;
  joints.updateMeasured(js);
  if (withSetpoint && Array.isArray(js.setpoint)) joints.updateSetpoint({name: js.name, position: js.setpoint});
}

function applyShape(shape) {
  if (view && shape && Array.isArray(shape.points)) view.setBackbone(shape.points);
}

function applyTipPose(cp) {
  if (!cp || !Array.isArray(cp.position)) return;
  const [x, y, z] = cp.position;
  ui.tip.textContent = `tip x ${x.toFixed(1)}  y ${y.toFixed(1)}  z ${z.toFixed(1)} mm`;
  view?.setTipPose(cp.position, cp.orientation);
}

function setConnection(kind, text) {
  ui.connection.className = `connection ${kind}`;
  ui.connectionText.textContent = text;
  ui.connection.setAttribute('aria-label', `Connection: ${text}`);
  ui.connection.dataset.kind = kind;
}

function refreshConnectionIndicator() {
  const now = Date.now();
  let offline = false;
  if (state.wsLive && now - state.lastWsJointMs < 1500) setConnection('live', 'live (WebSocket)');
  else if (now - state.lastRestOkMs < 2000) setConnection('polling', 'polling (REST)');
  else {
    setConnection('offline', 'no connection to server');
    offline = true;
  }
  if (offline !== state.offline) {
    state.offline = offline;
    // Stale numbers must not look live: grey them out and say so.
    document.body.classList.toggle('stale', offline);
    updateBanner();
  }
}

function wsStreaming() { return state.wsLive && Date.now() - state.lastWsJointMs < 1000; }

// REST polling: the whole picture while the WebSocket is down, and the tip pose always (the stream
// has no tip-pose topic the console reads).
let pollTick = 0;
async function poll() {
  const robot = state.robot?.name;
  if (!robot) return;
  pollTick++;
  const fallback = !wsStreaming();
  const jobs = [];
  if (fallback) {
    jobs.push(api.measuredJs(robot).then((js) => applyJointState(js, false)));
    jobs.push(api.setpointJs(robot).then((sp) => joints?.updateSetpoint(sp)));
    jobs.push(api.operatingState(robot).then(applyOperatingState));
    if (pollTick % 2 === 0) jobs.push(api.shape(robot).then(applyShape));
    if (pollTick % 10 === 0) jobs.push(api.faults().then((d) => addEvents(eventsFromFaults(d))));
  }
  if (pollTick % 2 === 0) jobs.push(api.measuredCp(robot).then(applyTipPose));
  const results = await Promise.allSettled(jobs);
  if (results.length && results.some((r) => r.status === 'fulfilled')) state.lastRestOkMs = Date.now();
  const unauthorised = results.find((r) => r.status === 'rejected' && r.reason?.status === 401);
  if (unauthorised) showStatus(describeError(unauthorised.reason), 'error');
  refreshConnectionIndicator();
}

// The lease lapses when unused (server side), so an open console that holds it renews it; GET /lease
// also tells who holds it when it is someone else.
async function pollLease() {
  let status;
  try {
    status = await api.lease();
  } catch {
    return;  // a server without GET /lease: rely on command answers
  }
  if (!status) return;
  if (status.yours) {
    setLease(true);
    if (typeof status.expires_in_s === 'number' && status.expires_in_s < 15) {
      try {
        await api.takeLease();
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
  }, 100);
}

function connectWebSocket(robotName) {
  const scheme = location.protocol === 'https:' ? 'wss:' : 'ws:';
  const topics = [`/${robotName}/joint_states`, `/${robotName}/operating_state`, `/${robotName}/scene`, '/safety/events'];
  const conn = new FoxgloveConnection(`${scheme}//${location.host}/ws`, topics, {
    onOpen: () => { state.wsLive = true; },
    onClose: () => { state.wsLive = false; refreshConnectionIndicator(); },
    onMessage: (topic, msg) => {
      if (topic === topics[0]) {
        state.lastWsJointMs = Date.now();
        applyJointState(msg, true);
      } else if (topic === topics[1]) {
        applyOperatingState(msg);
      } else if (topic === topics[2]) {
        view?.applySceneUpdate(msg);
      } else if (topic === '/safety/events') {
        addEvents(Array.isArray(msg.events) ? msg.events : [msg]);
      }
    },
    onStatus: (msg) => { if (msg.level >= 1) showStatus(`server: ${msg.message}`, msg.level >= 2 ? 'error' : 'ok'); },
  });
  conn.open();
  window.tendrilConnection = conn;  // for debugging from the browser console
}

// ---------------------------------------------------------------- commands
async function estop() {
  // Sent first, before anything else on the page reacts: this is the one command that must not wait.
  try {
    await api.estop();
    showStatus('E-STOP sent: every robot is stopping', 'ok');
  } catch (err) {
    showStatus(`E-STOP FAILED: ${describeError(err)}. Use the hardware stop.`, 'error');
  }
  refreshStateSoon();
}

async function refreshStateSoon() {
  if (!state.robot) return;
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
  ui.leaseButton.addEventListener('click', async () => {
    if (state.leaseHeld) {
      if (await runCommand('Release lease', () => api.releaseLease())) setLease(false);
      return;
    }
    try {
      await api.takeLease();
      setLease(true);
      showStatus('Lease taken: you are the operator', 'ok');
    } catch (err) {
      // 409 lease_held: the message names who holds it and why
      setLease(false, err instanceof ApiError && err.code === 'lease_held' ? err.message : '');
      showStatus(`Lease refused: ${describeError(err)}`, 'error');
    }
  });
  ui.form.addEventListener('submit', async (ev) => {
    ev.preventDefault();
    if (!joints || ui.moveButton.disabled) return;
    const goal = joints.goals();
    const answer = await runCommand('Move', () => api.moveJp(state.robot.name, goal));
    if (answer) {
      const d = typeof answer.duration_s === 'number' ? ` (about ${answer.duration_s.toFixed(1)} s)` : '';
      showStatus(`Moving to goal${d}`, 'ok');
      joints.markSent();
    }
  });
  ui.goalFromSetpoint.addEventListener('click', () => { joints?.goalsFromSetpoint(); updateControls(); });
  ui.fitView.addEventListener('click', () => view?.fit());
}

// ---------------------------------------------------------------- start-up
async function loadView() {
  try {
    const {CatheterView} = await import('./scene.js');
    view = new CatheterView(ui.scene);
  } catch (err) {
    const div = document.createElement('div');
    div.className = 'scene-message';
    div.textContent = `3D view unavailable (${err.message}). Joint control still works.`;
    ui.scene.appendChild(div);
  }
}

function selectRobot(name) {
  const robot = state.robots.find((r) => r.name === name) || state.robots[0];
  state.robot = robot;
  ui.robotKind.textContent = robot.kind ? robot.kind.replace(/_/g, ' ') : '';
  document.title = `${robot.name.toUpperCase()} · tendril console`;
  joints = buildJointPanel(ui.form, robot.joints, () => updateControls());
  updateControls();
  if (window.tendrilConnection) {
    window.tendrilConnection.close();
    connectWebSocket(robot.name);
  }
}

async function start() {
  wireCommands();
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
  selectRobot(state.robots[0].name);
  try {
    addEvents(eventsFromFaults(await api.faults()));
  } catch {
    // events are a convenience; the stream brings new ones
  }
  connectWebSocket(state.robot.name);
  startPolling();
  setInterval(refreshConnectionIndicator, 500);
}

start();
