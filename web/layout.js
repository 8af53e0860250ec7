// Enlargeable panels (issue 12, the cockpit): a button on the 3D view, the imaging and the plots
// enlarges that panel to the main area (everything but the side panel) and restores it. Only the
// buttons do it: Escape is the E-STOP everywhere and is not bound here.
const NAMES = {view: '3D view', images: 'imaging (AP and lateral)', plots: 'plots'};

export function wireEnlarge(layout) {
  const buttons = [...layout.querySelectorAll('[data-enlarge]')];
  const set = (name) => {
    if (name) layout.dataset.enlarged = name;
    else delete layout.dataset.enlarged;
    for (const b of buttons) {
      const on = b.dataset.enlarge === name;
      b.setAttribute('aria-pressed', String(on));
      b.setAttribute('aria-label', on ? `Restore the layout (the ${NAMES[b.dataset.enlarge]} back to its place)` : `Enlarge the ${NAMES[b.dataset.enlarge]}`);
      b.title = b.getAttribute('aria-label');
      b.textContent = on ? '⤡' : '⤢';
    }
  };
  for (const b of buttons) b.addEventListener('click', () => set(layout.dataset.enlarged === b.dataset.enlarge ? null : b.dataset.enlarge));
  set(null);
}
