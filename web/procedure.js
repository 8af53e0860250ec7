// Procedure timer and inserted length (issue 12, the cockpit), shown in the header.
// - The timer starts at the first ENABLED this console sees, or with Start; Stop freezes it and Start
//   begins a new procedure from 0. Its start is kept for the tab (sessionStorage), so a reload of the
//   page does not restart it. It is this console's clock: the server keeps no procedure time.
// - Inserted length: the insertion joint's measured position, from the same joint message as the joint
//   panel; max: the largest this console has seen since the procedure started (not a server record).
const STORE = 'tendril.procedure';

const pad2 = (n) => String(Math.floor(n)).padStart(2, '0');
export function formatDuration(ms) {
  const s = Math.max(0, ms) / 1000;
  const h = Math.floor(s / 3600);
  return h ? `${h}:${pad2((s % 3600) / 60)}:${pad2(s % 60)}` : `${pad2(s / 60)}:${pad2(s % 60)}`;
}

export class ProcedurePanel {
  constructor(root) {
    this.root = root;
    this.el = {
      timer: root.querySelector('[data-testid="procedure-timer"]'),
      button: root.querySelector('[data-testid="procedure-timer-button"]'),
      inserted: root.querySelector('[data-testid="inserted-length"]'),
      max: root.querySelector('[data-testid="inserted-max"]'),
    };
    this.insertionIndex = -1;
    this.unit = 'mm';
    let saved = null;
    try {
      saved = JSON.parse(sessionStorage.getItem(STORE) || 'null');
    } catch {
      saved = null;
    }
    this.startMs = Number.isFinite(saved?.startMs) ? saved.startMs : NaN;     // Date.now() at the start
    this.stopMs = Number.isFinite(saved?.stopMs) ? saved.stopMs : NaN;        // set while stopped
    this.maxInserted = Number.isFinite(saved?.maxInserted) ? saved.maxInserted : -Infinity;
    this.el.button.addEventListener('click', () => (this.running ? this.stop() : this.start()));
    this.render();
    setInterval(() => this.renderTimer(), 500);
  }

  get running() { return Number.isFinite(this.startMs) && !Number.isFinite(this.stopMs); }

  save() {
    try {
      sessionStorage.setItem(STORE, JSON.stringify({startMs: this.startMs, stopMs: this.stopMs, maxInserted: this.maxInserted}));
    } catch {
      // storage refused: the timer still runs for this page
    }
  }

  // The robot description: which joint is the insertion (by name), in which unit.
  setRobot(robot) {
    this.insertionIndex = robot.joints.findIndex((j) => j.name === 'insertion');
    this.unit = robot.joints[this.insertionIndex]?.unit || 'mm';
    for (const line of this.root.querySelectorAll('.proc-inserted')) line.hidden = this.insertionIndex < 0;
    this.render();
  }

  start() {
    this.startMs = Date.now();
    this.stopMs = NaN;
    this.maxInserted = Number.isFinite(this.lastInserted) ? this.lastInserted : -Infinity;
    this.save();
    this.render();
  }

  stop() {
    this.stopMs = Date.now();
    this.save();
    this.render();
  }

  // The first ENABLED starts the timer when nothing has started it in this tab.
  onState(os) {
    if (os?.state === 'ENABLED' && !os.estop && !Number.isFinite(this.startMs)) this.start();
  }

  // A joint state message ({name: [...], position: [...]}, or position in the robot's joint order).
  onJoints(js) {
    if (this.insertionIndex < 0 || !Array.isArray(js?.position)) return;
    const i = Array.isArray(js.name) ? js.name.indexOf('insertion') : this.insertionIndex;
    const v = Number(js.position[i]);
    if (i < 0 || !Number.isFinite(v)) return;
    this.lastInserted = v;
    if (this.running && v > this.maxInserted) {
      this.maxInserted = v;
      this.save();
    }
    this.renderLength();
  }

  render() {
    this.renderTimer();
    this.renderLength();
    this.el.button.textContent = this.running ? 'Stop' : 'Start';
    this.el.button.setAttribute('aria-label', this.running ? 'Stop the procedure timer' : 'Start the procedure timer (from 0)');
    this.root.dataset.running = String(this.running);
  }

  renderTimer() {
    const started = Number.isFinite(this.startMs);
    const end = Number.isFinite(this.stopMs) ? this.stopMs : Date.now();
    this.el.timer.textContent = started ? formatDuration(end - this.startMs) : '--:--';
    this.el.timer.dataset.elapsedMs = started ? String(end - this.startMs) : '';
    this.el.timer.title = started
      ? `Procedure time since ${new Date(this.startMs).toLocaleTimeString([], {hour12: false})} (the first Enable this console saw, or Start)` +
        `${this.running ? '' : '; stopped'}: this console's clock`
      : 'Starts at the first Enable, or with Start';
  }

  renderLength() {
    const v = this.lastInserted;
    this.el.inserted.textContent = Number.isFinite(v) ? `${v.toFixed(1)} ${this.unit}` : '—';
    this.el.inserted.dataset.value = Number.isFinite(v) ? v.toFixed(3) : '';
    const max = this.maxInserted;
    this.el.max.textContent = Number.isFinite(max) ? `${max.toFixed(1)} ${this.unit}` : '—';
    this.el.max.dataset.value = Number.isFinite(max) ? max.toFixed(3) : '';
    this.el.max.title = 'The deepest insertion this console has seen since the procedure started';
  }
}
