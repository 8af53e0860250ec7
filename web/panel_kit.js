// Small DOM helpers shared by the kind-specific panels (continuum.js, ultrasound.js, tip_control.js).

// el('div', {className: 'x', 'data-testid': 'y'}, child, 'text', …)
export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (v === undefined || v === null || v === false) continue;
    if (k === 'className') node.className = v;
    else if (k === 'text') node.textContent = v;
    else if (k.startsWith('on') && typeof v === 'function') node.addEventListener(k.slice(2), v);
    else node.setAttribute(k, v === true ? '' : String(v));
  }
  for (const c of children.flat()) if (c !== null && c !== undefined) node.append(c);
  return node;
}

export function group(title, note, ...children) {
  return el('div', {className: 'cath-group rp-group', role: 'group', 'aria-label': title},
            el('h3', {}, title, note ? el('span', {className: 'cath-note', text: ` ${note}`}) : null), ...children);
}

export function fmt(value, digits = 1, unit = '') {
  return Number.isFinite(value) ? `${value.toFixed(digits)}${unit ? ` ${unit}` : ''}` : '—';
}

// A person reads the server's error (ApiError carries the server's message).
export function describe(err) {
  if (!err) return 'unknown error';
  return err.message || String(err);
}

// POST /api/v1/robots/{robot}/{name} with the page's session and lease (api.js).
export function robotCommand(api, robot, name, body) {
  return api.post(`/robots/${encodeURIComponent(robot)}/${name}`, body);
}

// rgb in 0..1 from red (t = 0) through amber to green (t = 1).
export function rampColor(t) {
  const x = Math.min(1, Math.max(0, t));
  return x < 0.5 ? {r: 0.97, g: 0.32 + 0.9 * x, b: 0.29, a: 1} : {r: 0.97 - 1.6 * (x - 0.5), g: 0.77 - 0.1 * (x - 0.5), b: 0.29, a: 1};
}

// Press and hold (the continuum robot's Roll, the Tip tab's jog): start() on a pointer press or on
// Enter / Space held on the focused button, stop() on release, on leaving the button, when it loses
// focus, and when the page loses focus or is hidden (a release the page never sees must not leave a
// motion streaming). The key is the button's own: it does not reach the catheter's Space deadman.
const heldStops = new Set();
const stopAllHeld = () => { for (const stop of [...heldStops]) stop(); };
window.addEventListener('blur', stopAllHeld);
document.addEventListener('visibilitychange', () => { if (document.hidden) stopAllHeld(); });

export function holdToRun(button, {start, stop}) {
  const end = () => {
    if (!heldStops.delete(end)) return;
    stop();
  };
  const begin = () => {
    end();
    heldStops.add(end);
    start();
  };
  button.setAttribute('aria-keyshortcuts', 'Enter Space');
  button.addEventListener('pointerdown', begin);
  for (const ev of ['pointerup', 'pointerleave', 'pointercancel', 'blur']) button.addEventListener(ev, end);
  button.addEventListener('keydown', (ev) => {
    if (ev.key !== 'Enter' && ev.code !== 'Space') return;
    ev.preventDefault();
    ev.stopPropagation();
    if (!ev.repeat) begin();
  });
  button.addEventListener('keyup', (ev) => {
    if (ev.key !== 'Enter' && ev.code !== 'Space') return;
    ev.preventDefault();
    ev.stopPropagation();
    end();
  });
}
