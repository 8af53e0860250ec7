// Imaging panels (AP and lateral fluoroscopy-style views). Each shows the frames of one
// foxglove.CompressedImage topic ({"timestamp","frame_id","format":"jpeg|png","data":"<base64>"}),
// and says plainly why it shows nothing: no connection to the stream, topic not advertised by the
// server, or frames stopped arriving. Nothing is drawn that did not come from the server.

const STALE_MS = 2000;

export class ImagePanel {
  // root: element with [data-role=image], [data-role=status] and [data-role=placeholder] inside.
  constructor(root, topic, label) {
    this.root = root;
    this.topic = topic;
    this.label = label;
    this.img = root.querySelector('[data-role="image"]');
    this.status = root.querySelector('[data-role="status"]');
    this.placeholder = root.querySelector('[data-role="placeholder"]');
    this.frames = 0;
    this.lastFrameMs = 0;
    this.frameTimes = [];
    this.advertised = false;
    this.connected = false;
    this.pendingUrl = null;
    this.img.alt = `${label} image`;
    this.render();
    setInterval(() => this.render(), 500);
  }

  setConnected(connected) {
    this.connected = connected;
    this.render();
  }

  setAdvertised(advertised) {
    this.advertised = advertised;
    this.render();
  }

  frame(msg) {
    if (!msg || typeof msg.data !== 'string' || !msg.data) return;
    const format = String(msg.format || 'jpeg').toLowerCase().replace(/^image\//, '');
    const mime = format === 'png' ? 'image/png' : format === 'webp' ? 'image/webp' : 'image/jpeg';
    // A data URL decodes off the main thread in the browser; only the newest frame is kept.
    this.img.src = `data:${mime};base64,${msg.data}`;
    const now = performance.now();
    this.frames++;
    this.lastFrameMs = now;
    this.frameTimes.push(now);
    while (this.frameTimes.length && this.frameTimes[0] < now - 2000) this.frameTimes.shift();
    this.root.dataset.frames = String(this.frames);
    if (this.frames === 1 || this.frames % 15 === 0) this.render();
  }

  render() {
    const now = performance.now();
    let state;
    let text;
    if (!this.connected) {
      state = 'offline';
      text = 'No stream connection: imaging needs the live WebSocket stream.';
    } else if (!this.advertised) {
      state = 'absent';
      text = `Not available: the server does not publish ${this.topic}.`;
    } else if (this.frames === 0) {
      state = 'waiting';
      text = `Waiting for the first frame on ${this.topic}…`;
    } else if (now - this.lastFrameMs > STALE_MS) {
      state = 'stale';
      text = `No new frame for ${((now - this.lastFrameMs) / 1000).toFixed(0)} s: the image is old.`;
    } else {
      state = 'live';
      const fps = this.frameTimes.length > 1
        ? (this.frameTimes.length - 1) / ((this.frameTimes[this.frameTimes.length - 1] - this.frameTimes[0]) / 1000)
        : 0;
      const size = this.img.naturalWidth ? ` · ${this.img.naturalWidth}×${this.img.naturalHeight}` : '';
      text = `live · ${fps.toFixed(0)} fps${size}`;
    }
    this.root.dataset.state = state;
    // The head line is short (the panel may be narrow); the placeholder carries the whole sentence.
    const short = {offline: 'no stream', absent: 'not available', waiting: 'waiting…', stale: 'stale'}[state];
    this.status.textContent = short ?? text;
    this.status.title = text;
    this.placeholder.textContent = state === 'live' || state === 'stale' ? '' : text;
    this.placeholder.hidden = state === 'live' || state === 'stale';
    this.img.hidden = !(state === 'live' || state === 'stale');
  }
}
