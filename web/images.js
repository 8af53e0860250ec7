// Imaging panels (AP and lateral fluoroscopy-style views). Each shows the frames of one
// foxglove.CompressedImage topic (protobuf on /imaging/{view}/compressed: data is the image's bytes;
// the JSON form's base64 string is read too) and the overlays of /imaging/{view}/overlay,
// and says plainly why it shows nothing: no connection to the stream, topic not advertised by the
// server, or frames stopped arriving. Nothing is drawn that did not come from the server.
// Per panel, as on a fluoroscopy monitor: last-image hold (the shown frame is frozen, labelled HOLD
// with its age, while new frames keep arriving underneath) and zoom (wheel about the pointer, the
// + / − / 1× buttons, drag to pan when zoomed). Over the image, the message's own overlay (the server
// projects them with the plane's geometry): the robot's model backbone and the plan's path, the
// catheter as segmented in the frame and the tracked (EKF) tip, drawn
// with the frame they came with (held with it, zoomed with it); the Overlay button hides them.

const STALE_MS = 2000;
const SVG_NS = 'http://www.w3.org/2000/svg';
const MAX_ZOOM = 8;

// Server time of a frame in ms: its own timestamp ({sec, nsec}), else the stream's stamp.
function frameStampMs(msg, streamStampMs) {
  const t = msg?.timestamp;
  if (t && Number.isFinite(t.sec)) return t.sec * 1000 + (Number(t.nsec) || 0) / 1e6;
  return streamStampMs;
}

export class ImagePanel {
  // root: element with [data-role=image], [data-role=status] and [data-role=placeholder] inside.
  // ageMs(serverStampMs): age of a server time stamp on the browser's clock (live.js ServerClock).
  constructor(root, topic, label, {ageMs = (stamp) => Date.now() - stamp} = {}) {
    this.root = root;
    this.topic = topic;
    this.label = label;
    this.ageMs = ageMs;
    this.img = root.querySelector('[data-role="image"]');
    this.status = root.querySelector('[data-role="status"]');
    this.placeholder = root.querySelector('[data-role="placeholder"]');
    this.box = this.img.parentElement;
    this.held = false;
    this.shownStampMs = NaN;   // server time of the frame on screen
    this.shownFrame = 0;       // its number among the frames received
    this.zoom = 1;
    this.pan = {x: 0, y: 0};   // px, of the zoomed frame's centre from the box's centre
    this.buildTools(root.dataset.testid || `image-${label.toLowerCase()}`);
    this.frames = 0;
    this.lastFrameMs = 0;
    this.frameTimes = [];
    this.advertised = false;
    this.connected = false;
    this.pendingUrl = null;
    this.objectUrl = null;       // the blob URL on screen (released when the next replaces it)
    this.overlays = new Map();   // server stamp (ms) → overlay message, the last few
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

  // An overlay (tendril.ImageOverlay) for the frame of its time stamp: drawn now if that frame is on
  // screen, else kept for it (the two streams are published together, in either order).
  overlayMessage(msg) {
    const stamp = frameStampMs(msg, NaN);
    if (!Number.isFinite(stamp)) return;
    this.overlays.set(stamp, msg);
    while (this.overlays.size > 8) this.overlays.delete(this.overlays.keys().next().value);
    if (stamp === this.shownStampMs) this.setOverlay(msg);
  }

  frame(msg, streamStampMs = NaN) {
    const binary = msg?.data instanceof Uint8Array;
    if (!msg || !(binary || typeof msg.data === 'string') || !msg.data.length) return;
    const format = String(msg.format || 'jpeg').toLowerCase().replace(/^image\//, '');
    const mime = format === 'png' ? 'image/png' : format === 'webp' ? 'image/webp' : 'image/jpeg';
    const now = performance.now();
    this.frames++;
    // The image decodes off the main thread in the browser; only the newest frame is kept. While held
    // the frame on screen stays (and keeps its own age); the newest is counted, not shown.
    if (!this.held || !this.img.src) {
      if (binary) {
        // A blob URL of the bytes as they came (no base64 round trip); the previous one is released.
        const url = URL.createObjectURL(new Blob([msg.data], {type: mime}));
        if (this.objectUrl) URL.revokeObjectURL(this.objectUrl);
        this.objectUrl = url;
        this.img.src = url;
      } else {
        this.img.src = `data:${mime};base64,${msg.data}`;
      }
      this.shownStampMs = frameStampMs(msg, streamStampMs);
      // The JSON form carries its overlay inside; the binary one finds it by time stamp (until it
      // comes, the previous frame's stays rather than blinking out).
      const overlay = msg.overlay ?? this.overlays.get(this.shownStampMs);
      if (overlay || !binary) this.setOverlay(overlay);
      this.shownFrame = this.frames;
      this.root.dataset.shownFrame = String(this.frames);
    }
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
    if (this.held) text = `HOLD · ${text}`;
    this.root.dataset.state = state;
    this.renderHold();
    // The head line is short (the panel may be narrow); the placeholder carries the whole sentence.
    const short = {offline: 'no stream', absent: 'not available', waiting: 'waiting…', stale: 'stale'}[state];
    this.status.textContent = short ?? text;
    this.status.title = text;
    this.placeholder.textContent = state === 'live' || state === 'stale' ? '' : text;
    this.placeholder.hidden = state === 'live' || state === 'stale';
    this.img.hidden = !(state === 'live' || state === 'stale');
    if (this.overlay) this.overlay.style.visibility = this.img.hidden ? 'hidden' : '';
  }

  // Hold, zoom and the HOLD label, built here so both panels get the same tools and test ids.
  buildTools(id) {
    const tools = document.createElement('span');
    tools.className = 'image-tools';
    tools.setAttribute('role', 'group');
    tools.setAttribute('aria-label', `${this.label} image tools`);
    const button = (role, text, label, testid) => {
      const b = document.createElement('button');
      b.type = 'button';
      b.className = 'img-btn';
      b.dataset.role = role;
      b.dataset.testid = `${id}-${testid}`;
      b.textContent = text;
      b.setAttribute('aria-label', label);
      b.title = label;
      tools.appendChild(b);
      return b;
    };
    this.holdButton = button('hold', 'Hold', `Hold the last ${this.label} image (freeze it)`, 'hold-button');
    this.holdButton.setAttribute('aria-pressed', 'false');
    button('zoom-out', '−', `Zoom out the ${this.label} image`, 'zoom-out').addEventListener('click', () => this.zoomBy(0.5));
    button('zoom-in', '+', `Zoom in the ${this.label} image`, 'zoom-in').addEventListener('click', () => this.zoomBy(2));
    button('zoom-reset', '1×', `Whole ${this.label} image (no zoom)`, 'zoom-reset').addEventListener('click', () => this.setZoom(1, {x: 0, y: 0}));
    this.overlayButton = button('overlay', '◎', `Hide the model catheter and the plan drawn over the ${this.label} image`, 'overlay-button');
    this.overlayButton.setAttribute('aria-pressed', 'true');
    this.overlayButton.addEventListener('click', () => {
      const on = this.overlayButton.getAttribute('aria-pressed') !== 'true';
      this.overlayButton.setAttribute('aria-pressed', String(on));
      this.overlayButton.setAttribute('aria-label', `${on ? 'Hide' : 'Show'} the model catheter and the plan drawn over the ${this.label} image`);
      this.overlay.style.display = on ? '' : 'none';
    });
    // The overlay lies exactly on the image: same box, same letterboxing (viewBox in the frame's pixels,
    // "meet" = object-fit: contain), same zoom transform.
    this.overlay = document.createElementNS(SVG_NS, 'svg');
    this.overlay.setAttribute('class', 'image-overlay');
    this.overlay.setAttribute('preserveAspectRatio', 'xMidYMid meet');
    this.overlay.setAttribute('aria-hidden', 'true');
    this.overlay.dataset.testid = `${id}-overlay`;
    this.overlayLines = {};
    // Drawn only over the frame itself, not over the letterbox around it (a catheter base outside the
    // field of view projects there).
    const clip = document.createElementNS(SVG_NS, 'clipPath');
    clip.id = `${id}-overlay-clip`;
    this.overlayClip = document.createElementNS(SVG_NS, 'rect');
    clip.appendChild(this.overlayClip);
    this.overlay.appendChild(clip);
    // The catheter as segmented in this frame (the tracking) is drawn over the model's backbone.
    for (const [name, cls] of [['plan', 'overlay-plan'], ['robot', 'overlay-robot'], ['segmented', 'overlay-segmented']]) {
      const line = document.createElementNS(SVG_NS, 'polyline');
      line.setAttribute('clip-path', `url(#${clip.id})`);
      line.setAttribute('class', cls);
      line.setAttribute('fill', 'none');
      line.setAttribute('vector-effect', 'non-scaling-stroke');
      line.dataset.testid = `${id}-overlay-${name}`;
      this.overlay.appendChild(line);
      this.overlayLines[name] = line;
    }
    // The tracked (EKF-filtered) tip: a ring where the filter puts it.
    this.overlayTip = document.createElementNS(SVG_NS, 'circle');
    this.overlayTip.setAttribute('class', 'overlay-tip');
    this.overlayTip.setAttribute('fill', 'none');
    this.overlayTip.setAttribute('vector-effect', 'non-scaling-stroke');
    this.overlayTip.setAttribute('r', '0');
    this.overlayTip.dataset.testid = `${id}-overlay-tip`;
    this.overlay.appendChild(this.overlayTip);
    this.img.insertAdjacentElement('afterend', this.overlay);
    this.img.addEventListener('load', () => {
      if (!this.img.naturalWidth) return;
      this.overlay.setAttribute('viewBox', `0 0 ${this.img.naturalWidth} ${this.img.naturalHeight}`);
      this.overlayClip.setAttribute('width', String(this.img.naturalWidth));
      this.overlayClip.setAttribute('height', String(this.img.naturalHeight));
    });
    this.holdButton.addEventListener('click', () => this.setHeld(!this.held));
    this.status.insertAdjacentElement('afterend', tools);
    // The imaging's enlarge button (index.html) stays last in the head.
    const enlarge = this.status.parentElement.querySelector('.enlarge-btn');
    if (enlarge) tools.appendChild(enlarge);
    this.holdLabel = document.createElement('div');
    this.holdLabel.className = 'image-hold';
    this.holdLabel.dataset.testid = `${id}-hold`;
    this.holdLabel.setAttribute('role', 'status');
    this.holdLabel.hidden = true;
    this.box.appendChild(this.holdLabel);
    // Wheel zooms about the pointer; a drag pans while zoomed.
    this.box.addEventListener('wheel', (ev) => {
      if (this.img.hidden) return;
      ev.preventDefault();
      this.zoomBy(ev.deltaY < 0 ? 1.25 : 0.8, ev);
    }, {passive: false});
    let drag = null;
    this.box.addEventListener('pointerdown', (ev) => {
      if (this.zoom <= 1) return;
      drag = {x: ev.clientX - this.pan.x, y: ev.clientY - this.pan.y};
      this.box.setPointerCapture?.(ev.pointerId);
    });
    this.box.addEventListener('pointermove', (ev) => {
      if (drag) this.setZoom(this.zoom, {x: ev.clientX - drag.x, y: ev.clientY - drag.y});
    });
    for (const type of ['pointerup', 'pointercancel']) this.box.addEventListener(type, () => { drag = null; });
    this.setZoom(1, {x: 0, y: 0});
  }

  // The overlay of the frame on screen: polylines in its pixels (absent fields draw nothing).
  setOverlay(overlay) {
    for (const [name, line] of Object.entries(this.overlayLines)) {
      const points = Array.isArray(overlay?.[name]) ? overlay[name].filter((p) => Array.isArray(p) && p.length >= 2) : [];
      line.setAttribute('points', points.map((p) => `${Number(p[0])},${Number(p[1])}`).join(' '));
      line.dataset.points = String(points.length);
    }
    const tip = overlay?.tip;
    const shown = Array.isArray(tip) && tip.length >= 2 && Number.isFinite(Number(tip[0])) && Number.isFinite(Number(tip[1]));
    this.overlayTip.setAttribute('cx', shown ? String(Number(tip[0])) : '0');
    this.overlayTip.setAttribute('cy', shown ? String(Number(tip[1])) : '0');
    // A ring of 2 % of the frame's width, whatever its resolution.
    this.overlayTip.setAttribute('r', shown ? String(Math.max(3, (this.img.naturalWidth || 512) * 0.02)) : '0');
    this.overlayTip.dataset.shown = String(shown);
  }

  setHeld(held) {
    this.held = held;
    this.holdButton.setAttribute('aria-pressed', String(held));
    this.holdButton.textContent = held ? 'Live' : 'Hold';
    this.holdButton.setAttribute('aria-label', held ? `Back to the live ${this.label} image` : `Hold the last ${this.label} image (freeze it)`);
    this.root.dataset.hold = String(held);
    this.render();
  }

  renderHold() {
    const show = this.held && !this.img.hidden;
    this.holdLabel.hidden = !show;
    if (!show) return;
    const age = this.ageMs(this.shownStampMs);
    const ageText = Number.isFinite(age) ? (age < 60000 ? `${(age / 1000).toFixed(1)} s` : `${(age / 60000).toFixed(0)} min`) : 'age unknown';
    this.holdLabel.textContent = `HOLD · ${ageText} old`;
    this.holdLabel.dataset.ageMs = Number.isFinite(age) ? age.toFixed(0) : '';
    this.holdLabel.title = `Last-image hold: this ${this.label} frame is ${ageText} old; ${this.frames - this.shownFrame} newer frames not shown. Live shows them again.`;
  }

  // Zoom by `factor`, keeping the point under the pointer (or the box's centre) where it is.
  zoomBy(factor, at = null) {
    const z = Math.min(MAX_ZOOM, Math.max(1, this.zoom * factor));
    const r = this.box.getBoundingClientRect();
    const p = at ? {x: at.clientX - r.left - r.width / 2, y: at.clientY - r.top - r.height / 2} : {x: 0, y: 0};
    const k = z / this.zoom;
    this.setZoom(z, {x: p.x - k * (p.x - this.pan.x), y: p.y - k * (p.y - this.pan.y)});
  }

  setZoom(zoom, pan) {
    const r = this.box.getBoundingClientRect();
    // The zoomed frame always covers the box's centre: pan at most half the extra size.
    const lim = {x: ((zoom - 1) * r.width) / 2, y: ((zoom - 1) * r.height) / 2};
    this.zoom = zoom;
    this.pan = {x: Math.max(-lim.x, Math.min(lim.x, pan.x)), y: Math.max(-lim.y, Math.min(lim.y, pan.y))};
    this.img.style.transform = zoom === 1 ? '' : `translate(${this.pan.x}px, ${this.pan.y}px) scale(${zoom})`;
    if (this.overlay) this.overlay.style.transform = this.img.style.transform;
    this.root.dataset.zoom = zoom.toFixed(2).replace(/\.?0+$/, '');
    this.box.classList.toggle('zoomed', zoom > 1);
  }
}
