// The replay bar: shown only when the server replays a recording (tendrild --replay: GET /api/v1/health
// says mode "replay"; a live server is not asked for GET /replay, which it answers 404). Play/pause, a position slider over the recording's span, the rate
// and the time (elapsed / total, and the recorded wall-clock time). It reads GET /replay four times a
// second and changes the playback with PUT /replay ({playing}, {position_ns}, {rate}); the recorded
// topics themselves arrive on the WebSocket as from a live server.

const RATES = [0.1, 0.25, 0.5, 1, 2, 4, 10];
const POLL_MS = 250;

// "m:ss.s" for a duration in ns (recordings are minutes to hours long).
export function formatSpan(ns) {
  const s = Math.max(0, ns / 1e9);
  const hours = Math.floor(s / 3600);
  const minutes = Math.floor((s % 3600) / 60);
  const seconds = (s % 60).toFixed(1).padStart(4, '0');
  return hours > 0 ? `${hours}:${String(minutes).padStart(2, '0')}:${seconds}` : `${minutes}:${seconds}`;
}

export class ReplayBar {
  // root: the bar's element (hidden until the server says it replays); api: the console's Api;
  // status(text, kind): the console's status line.
  constructor(root, {api, status}) {
    this.root = root;
    this.api = api;
    this.status = status;
    this.state = null;
    this.dragging = false;
    this.play = root.querySelector('[data-testid="replay-play"]');
    this.slider = root.querySelector('[data-testid="replay-position"]');
    this.rate = root.querySelector('[data-testid="replay-rate"]');
    this.time = root.querySelector('[data-testid="replay-time"]');
    this.clock = root.querySelector('[data-testid="replay-clock"]');
    this.rate.replaceChildren(...RATES.map((r) => new Option(`${r}×`, String(r))));
    this.play.addEventListener('click', () => this.send({playing: !this.state?.playing}));
    this.rate.addEventListener('change', () => this.send({rate: Number(this.rate.value)}));
    this.slider.addEventListener('input', () => {
      this.dragging = true;
      if (this.state) this.showTime(this.positionFromSlider());
    });
    this.slider.addEventListener('change', () => {
      this.dragging = false;
      if (this.state) this.send({position_ns: this.positionFromSlider()});
    });
  }

  // Resolves true when the server replays (the bar is then shown and kept up to date), false otherwise.
  async start() {
    try {
      if ((await this.api.health()).mode !== 'replay') return false;
      this.apply(await this.api.get('/replay'));
    } catch (err) {
      if (err.status !== 404) this.status(`Replay: ${err.message}`, 'error');
      return false;
    }
    this.root.hidden = false;
    document.body.classList.add('replaying');
    setInterval(() => this.refresh(), POLL_MS);
    return true;
  }

  async refresh() {
    try {
      this.apply(await this.api.get('/replay'));
    } catch {
      // the connection indicator says when the server does not answer
    }
  }

  async send(change) {
    try {
      this.apply(await this.api.request('PUT', '/replay', change));
    } catch (err) {
      this.status(`Replay: ${err.message}`, 'error');
    }
  }

  positionFromSlider() {
    const {start_ns: start, end_ns: end} = this.state;
    return Math.round(start + (end - start) * (Number(this.slider.value) / Number(this.slider.max)));
  }

  apply(state) {
    this.state = state;
    this.play.textContent = state.playing ? 'Pause' : 'Play';
    this.play.setAttribute('aria-label', state.playing ? 'Pause the replay' : 'Play the replay');
    this.root.dataset.playing = String(state.playing);
    // The console's age badges stop their clock while paused (app.js replayPaused()).
    document.body.dataset.replayPlaying = String(state.playing);
    if (document.activeElement !== this.rate) this.rate.value = String(state.rate);
    if (!this.dragging) {
      const span = Math.max(1, state.end_ns - state.start_ns);
      this.slider.value = String(Math.round((Number(this.slider.max) * (state.position_ns - state.start_ns)) / span));
      this.showTime(state.position_ns);
    }
    if (state.error) this.status(`Replay stopped: ${state.error}`, 'error');
  }

  showTime(position) {
    const {start_ns: start, end_ns: end} = this.state;
    this.time.textContent = `${formatSpan(position - start)} / ${formatSpan(end - start)}`;
    // The recorded time of day (UTC), so a replay can be matched with notes and other logs.
    this.clock.textContent = new Date(position / 1e6).toISOString().replace('T', ' ').slice(0, 21) + ' UTC';
  }
}
