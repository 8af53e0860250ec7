// Layout of the main area (issue 12, the cockpit):
// - Enlargeable panels: a button on the 3D view, the imaging and the plots enlarges that panel to the
//   main area (everything but the side panel) and restores it. Only the buttons do it: Escape is the
//   E-STOP everywhere and is not bound here.
// - The imaging's two planes side by side or stacked, whichever shows the frames larger; the other
//   arrangement must be 10 % larger before they swap, so a banner that grows by a line does not make
//   the images jump back and forth.
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

// Square frames: side by side each gets min(W/2, H - head), stacked min(W, H/2 - head).
export function arrangeImaging(panel) {
  const grid = panel.querySelector('.image-grid');
  const decide = () => {
    const w = panel.clientWidth;
    const h = panel.clientHeight;
    if (!w || !h) return;
    const head = panel.querySelector('.image-head')?.offsetHeight || 30;
    const margin = 16;  // the image box's margins
    const size = {row: Math.min(w / 2 - margin, h - head - margin), column: Math.min(w - margin, h / 2 - head - margin)};
    const better = size.row > size.column ? 'row' : 'column';
    const now = grid.dataset.arrangement;
    if (!now || (better !== now && size[better] > 1.1 * size[now])) grid.dataset.arrangement = better;
  };
  new ResizeObserver(decide).observe(panel);
  decide();
}
