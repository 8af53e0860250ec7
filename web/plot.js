// Small canvas plots for the console (no plotting library: two kinds of plot are all it needs).
// TimePlot: rolling time series (setpoint against measured, loop timing). StepPlot: a value per plan
// step (planned position and orientation error) with a marker on the current step.
// Both size themselves to their container, draw at the device pixel ratio, redraw at most ~10 times a
// second and only when something changed, and show a plain-text message instead of axes when their
// data source is absent (never an empty plot that looks like "all zero").

const FRAME_MS = 100;
// A page that cannot keep up (frames of 60 ms and more: software rendering on loaded cores) sheds its
// own work before its data goes stale: the plots redraw at 2 Hz instead of 10 (app.js decides).
const SHED_FRAME_MS = 500;
let plotFrameMs = FRAME_MS;
export function shedPlots(on) { plotFrameMs = on ? SHED_FRAME_MS : FRAME_MS; }

function cssVar(name, fallback) {
  const v = getComputedStyle(document.documentElement).getPropertyValue(name).trim();
  return v || fallback;
}

// "Nice" tick step for a range: 1, 2 or 5 times a power of ten.
function niceStep(range, ticks) {
  const raw = range / Math.max(1, ticks);
  const p = Math.pow(10, Math.floor(Math.log10(raw || 1)));
  const m = raw / p;
  return (m < 1.5 ? 1 : m < 3.5 ? 2 : m < 7.5 ? 5 : 10) * p;
}

function formatTick(v, step) {
  const decimals = Math.max(0, Math.min(4, -Math.floor(Math.log10(step || 1))));
  return v.toFixed(decimals);
}

class CanvasPlot {
  constructor(canvas) {
    this.canvas = canvas;
    this.ctx = canvas.getContext('2d');
    this.message = 'waiting for data…';
    this.dirty = true;
    this.lastDraw = 0;
    this.timer = null;
    this.resizeObserver = new ResizeObserver(() => { this.resize(); });
    this.resizeObserver.observe(canvas.parentElement);
    this.resize();
  }

  resize() {
    const box = this.canvas.parentElement;
    const w = Math.max(50, box.clientWidth);
    const h = Math.max(40, box.clientHeight);
    const dpr = window.devicePixelRatio || 1;
    this.width = w;
    this.height = h;
    this.canvas.width = Math.round(w * dpr);
    this.canvas.height = Math.round(h * dpr);
    this.canvas.style.width = `${w}px`;
    this.canvas.style.height = `${h}px`;
    this.ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    this.invalidate(true);
  }

  // Text instead of a plot (null: plot the data).
  setMessage(text) {
    if (text === this.message) return;
    this.message = text;
    this.canvas.dataset.available = text || !this.hasData() ? 'false' : 'true';
    this.invalidate();
  }

  hasData() { return true; }

  invalidate(now = false) {
    this.dirty = true;
    if (now) {
      this.render();
      return;
    }
    if (this.timer) return;
    const wait = Math.max(0, plotFrameMs - (performance.now() - this.lastDraw));
    this.timer = setTimeout(() => {
      this.timer = null;
      this.render();
    }, wait);
  }

  render() {
    if (!this.dirty) return;
    this.dirty = false;
    this.lastDraw = performance.now();
    const {ctx, width: w, height: h} = this;
    const font = parseFloat(getComputedStyle(document.documentElement).fontSize) || 16;
    this.fontPx = Math.round(font * 0.72);
    ctx.clearRect(0, 0, w, h);
    ctx.fillStyle = cssVar('--plot-bg', '#0b0f14');
    ctx.fillRect(0, 0, w, h);
    if (this.message) {
      ctx.fillStyle = cssVar('--muted', '#93a1b1');
      ctx.font = `${Math.round(font * 0.8)}px system-ui, sans-serif`;
      ctx.textAlign = 'center';
      ctx.textBaseline = 'middle';
      wrapText(ctx, this.message, w / 2, h / 2, w - 24, font * 1.1);
      return;
    }
    this.draw(ctx, w, h);
  }

  // Axes frame with y ticks on the left (and optionally a second scale on the right).
  frame(ctx, w, h, y, yRight) {
    const f = this.fontPx;
    const pad = {l: f * 4.2, r: yRight ? f * 4.2 : f * 0.8, t: f * 0.8, b: f * 1.9};
    const plot = {x: pad.l, y: pad.t, w: Math.max(10, w - pad.l - pad.r), h: Math.max(10, h - pad.t - pad.b)};
    ctx.font = `${f}px ui-monospace, "DejaVu Sans Mono", monospace`;
    ctx.lineWidth = 1;
    const step = niceStep(y.max - y.min, Math.max(2, Math.floor(plot.h / (f * 2.6))));
    ctx.textAlign = 'right';
    ctx.textBaseline = 'middle';
    for (let v = Math.ceil(y.min / step) * step; v <= y.max + step * 1e-6; v += step) {
      const py = plot.y + plot.h - (v - y.min) / (y.max - y.min) * plot.h;
      ctx.strokeStyle = '#1f2833';
      ctx.beginPath();
      ctx.moveTo(plot.x, py);
      ctx.lineTo(plot.x + plot.w, py);
      ctx.stroke();
      ctx.fillStyle = '#8b98a8';
      ctx.fillText(formatTick(v, step), plot.x - f * 0.4, py);
    }
    if (yRight) {
      const stepR = niceStep(yRight.max - yRight.min, Math.max(2, Math.floor(plot.h / (f * 2.6))));
      ctx.textAlign = 'left';
      for (let v = Math.ceil(yRight.min / stepR) * stepR; v <= yRight.max + stepR * 1e-6; v += stepR) {
        const py = plot.y + plot.h - (v - yRight.min) / (yRight.max - yRight.min) * plot.h;
        ctx.fillStyle = yRight.color || '#8b98a8';
        ctx.fillText(formatTick(v, stepR), plot.x + plot.w + f * 0.4, py);
      }
    }
    ctx.strokeStyle = '#3d4b5c';
    ctx.strokeRect(plot.x + 0.5, plot.y + 0.5, plot.w, plot.h);
    return plot;
  }
}

function wrapText(ctx, text, x, y, maxWidth, lineHeight) {
  const words = String(text).split(/\s+/);
  const lines = [];
  let line = '';
  for (const word of words) {
    const next = line ? `${line} ${word}` : word;
    if (ctx.measureText(next).width > maxWidth && line) {
      lines.push(line);
      line = word;
    } else {
      line = next;
    }
  }
  if (line) lines.push(line);
  const top = y - (lines.length - 1) * lineHeight / 2;
  lines.forEach((l, i) => ctx.fillText(l, x, top + i * lineHeight));
}

function yRange(values, minSpan) {
  let lo = Infinity;
  let hi = -Infinity;
  for (const v of values) {
    if (!Number.isFinite(v)) continue;
    if (v < lo) lo = v;
    if (v > hi) hi = v;
  }
  if (!Number.isFinite(lo)) return {min: 0, max: 1};
  const span = Math.max(hi - lo, minSpan);
  const mid = (hi + lo) / 2;
  return {min: mid - span * 0.55, max: mid + span * 0.55};
}

// Rolling time series. series: [{label, color, dash?}]; push(index, tSeconds, value).
export class TimePlot extends CanvasPlot {
  // series: [{label, color, dash?, format?(v)}]: the legend, drawn inside the plot, shows each label and,
  // when format is given, the latest value.
  constructor(canvas, {series, windowS = 10, unit = '', minSpan = 1e-3, floorZero = false}) {
    super(canvas);
    this.series = series.map((s) => ({...s, t: [], v: []}));
    this.windowS = windowS;
    this.unit = unit;
    this.minSpan = minSpan;
    this.floorZero = floorZero;
    this.setMessage(null);
  }

  configure({unit, minSpan}) {
    if (unit !== undefined) this.unit = unit;
    if (minSpan !== undefined) this.minSpan = minSpan;
    this.clear();
  }

  clear() {
    for (const s of this.series) {
      s.t.length = 0;
      s.v.length = 0;
    }
    this.canvas.dataset.available = 'false';
    this.invalidate();
  }

  hasData() { return !!this.series && this.series.some((s) => s.v.length > 0); }

  push(index, t, value) {
    const s = this.series[index];
    if (!s || !Number.isFinite(value)) return;
    s.t.push(t);
    s.v.push(value);
    if (!this.message) this.canvas.dataset.available = 'true';
    // Drop what scrolled out of the window (with one point of margin for the left edge).
    let drop = 0;
    while (drop < s.t.length - 1 && s.t[drop + 1] < t - this.windowS) drop++;
    if (drop > 0) {
      s.t.splice(0, drop);
      s.v.splice(0, drop);
    }
    this.invalidate();
  }

  latest(index) {
    const s = this.series[index];
    return s && s.v.length ? s.v[s.v.length - 1] : NaN;
  }

  draw(ctx, w, h) {
    const tEnd = Math.max(...this.series.map((s) => (s.t.length ? s.t[s.t.length - 1] : -Infinity)));
    if (!Number.isFinite(tEnd)) {
      ctx.fillStyle = cssVar('--muted', '#93a1b1');
      ctx.font = `${Math.round(this.fontPx * 1.1)}px system-ui, sans-serif`;
      ctx.textAlign = 'center';
      ctx.textBaseline = 'middle';
      ctx.fillText('waiting for data…', w / 2, h / 2);
      return;
    }
    const tStart = tEnd - this.windowS;
    let y = yRange(this.series.flatMap((s) => s.v), this.minSpan);
    if (this.floorZero) y = {min: 0, max: Math.max(y.max, this.minSpan)};
    const plot = this.frame(ctx, w, h, y);
    const f = this.fontPx;
    // x axis: seconds before now
    ctx.fillStyle = '#8b98a8';
    ctx.textAlign = 'center';
    ctx.textBaseline = 'top';
    for (let s = 0; s <= this.windowS; s += this.windowS / 5) {
      const px = plot.x + plot.w - s / this.windowS * plot.w;
      ctx.fillText(s === 0 ? 'now' : `-${s.toFixed(0)} s`, px, plot.y + plot.h + f * 0.35);
    }
    ctx.save();
    ctx.beginPath();
    ctx.rect(plot.x, plot.y, plot.w, plot.h);
    ctx.clip();
    // Reverse order: the first series (e.g. the dashed setpoint) is drawn on top and stays visible.
    for (const s of [...this.series].reverse()) {
      if (s.t.length < 1) continue;
      ctx.strokeStyle = s.color;
      ctx.lineWidth = s.width || 2;
      ctx.setLineDash(s.dash ? [f * 0.5, f * 0.35] : []);
      ctx.beginPath();
      s.t.forEach((t, i) => {
        const px = plot.x + (t - tStart) / this.windowS * plot.w;
        const py = plot.y + plot.h - (s.v[i] - y.min) / (y.max - y.min) * plot.h;
        if (i === 0) ctx.moveTo(px, py);
        else ctx.lineTo(px, py);
      });
      ctx.stroke();
    }
    ctx.restore();
    ctx.setLineDash([]);
    // Legend along the top edge of the plot area, right-aligned, wrapping onto more lines when narrow.
    ctx.font = `${f}px system-ui, sans-serif`;
    ctx.textAlign = 'left';
    ctx.textBaseline = 'top';
    const entries = this.series.filter((s) => s.label).map((s) => {
      const v = s.v.length ? s.v[s.v.length - 1] : NaN;
      const text = s.format ? `${s.label} ${Number.isFinite(v) ? s.format(v) : '—'}` : s.label;
      return {s, text, width: f * 1.5 + ctx.measureText(text).width};
    });
    const lines = [[]];
    let used = 0;
    for (const e of entries) {
      if (used + e.width > plot.w - f && lines[lines.length - 1].length) {
        lines.push([]);
        used = 0;
      }
      lines[lines.length - 1].push(e);
      used += e.width + f;
    }
    lines.forEach((line, row) => {
      const width = line.reduce((n, e) => n + e.width + f, -f);
      let x = plot.x + plot.w - f * 0.5 - width;
      const y = plot.y + f * 0.3 + row * f * 1.3;
      ctx.fillStyle = 'rgba(11, 15, 20, .75)';
      ctx.fillRect(x - f * 0.3, y - f * 0.15, width + f * 0.6, f * 1.3);
      for (const e of line) {
        ctx.fillStyle = e.s.color;
        if (e.s.dash) {
          ctx.fillRect(x, y + f * 0.45, f * 0.45, Math.max(2, f * 0.2));
          ctx.fillRect(x + f * 0.7, y + f * 0.45, f * 0.45, Math.max(2, f * 0.2));
        } else {
          ctx.fillRect(x, y + f * 0.45, f * 1.15, Math.max(2, f * 0.2));
        }
        ctx.fillStyle = '#c9d1d9';
        ctx.fillText(e.text, x + f * 1.5, y);
        x += e.width + f;
      }
    });
  }
}

// One value per plan step: bars for the left series, a line for the right one, current step marked.
export class StepPlot extends CanvasPlot {
  constructor(canvas, {left, right}) {
    super(canvas);
    this.left = left;    // {label, unit, color}
    this.right = right;  // {label, unit, color}
    this.values = null;  // {left: [], right: []}
    this.current = -1;
    this.setMessage('No plan yet.');
  }

  setData(leftValues, rightValues) {
    this.values = {left: leftValues, right: rightValues};
    this.setMessage(leftValues.length ? null : 'The plan has no steps.');
    this.invalidate();
  }

  setCurrent(step) {
    if (step === this.current) return;
    this.current = step;
    this.invalidate();
  }

  draw(ctx, w, h) {
    const {left, right} = this.values;
    const n = left.length;
    const yl = {min: 0, max: Math.max(...left.filter(Number.isFinite), 1e-3) * 1.15};
    const yr = {min: 0, max: Math.max(...right.filter(Number.isFinite), 1e-3) * 1.15, color: this.right.color};
    const plot = this.frame(ctx, w, h, yl, yr);
    const f = this.fontPx;
    const bw = plot.w / n;
    if (this.current >= 0 && this.current < n) {
      ctx.fillStyle = 'rgba(78, 161, 255, .22)';
      ctx.fillRect(plot.x + this.current * bw, plot.y, bw, plot.h);
    }
    ctx.fillStyle = this.left.color;
    left.forEach((v, i) => {
      if (!Number.isFinite(v)) return;
      const bh = v / yl.max * plot.h;
      ctx.fillRect(plot.x + i * bw + bw * 0.15, plot.y + plot.h - bh, Math.max(1, bw * 0.7), bh);
    });
    ctx.strokeStyle = this.right.color;
    ctx.lineWidth = 2;
    ctx.beginPath();
    right.forEach((v, i) => {
      const px = plot.x + (i + 0.5) * bw;
      const py = plot.y + plot.h - v / yr.max * plot.h;
      if (i === 0) ctx.moveTo(px, py);
      else ctx.lineTo(px, py);
    });
    ctx.stroke();
    ctx.fillStyle = '#8b98a8';
    ctx.textAlign = 'center';
    ctx.textBaseline = 'top';
    const every = Math.max(1, Math.ceil(n / Math.max(1, plot.w / (f * 3))));
    for (let i = 0; i < n; i += every) ctx.fillText(String(i), plot.x + (i + 0.5) * bw, plot.y + plot.h + f * 0.35);
    ctx.textAlign = 'left';
    ctx.fillStyle = this.left.color;
    ctx.fillText(`${this.left.label} (${this.left.unit})`, plot.x + f * 0.4, plot.y + f * 0.3);
    ctx.textAlign = 'right';
    ctx.fillStyle = this.right.color;
    ctx.fillText(`${this.right.label} (${this.right.unit})`, plot.x + plot.w - f * 0.4, plot.y + f * 0.3);
  }
}
