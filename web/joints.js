// Joint panel, built from the robot description of GET /api/v1/robots: per joint the measured value
// and the setpoint with units, the limits, a range bar, and a goal (number input + slider kept within
// the limits). Goals follow the setpoint until the operator edits them; a move sends the edited goals
// and, for every joint nobody touched, the setpoint read when the command is sent (never a value the
// page saw earlier). The preview line says what will move before it moves.
// A revolute joint (the API's unit rad) is shown, typed and stepped in degrees, as everywhere else in the
// console (typing 3 for the roll meant 171.9° before); the conversion happens here, at the API boundary:
// the values the page receives and the goals it sends stay in the API's rad.

const DECIMALS = {mm: 2, rad: 3, deg: 1};
const RAD_TO_DEG = 180 / Math.PI;
// The unit a joint is shown in, and the factor from its API unit to it.
export function displayUnit(unit) { return unit === 'rad' ? {unit: 'deg', symbol: '°', scale: RAD_TO_DEG} : {unit, symbol: unit, scale: 1}; }
const STEP = {mm: 0.01, rad: 0.001, deg: 0.1};
// Step moves, as the cockpits of endovascular robots offer them: ±1 mm for a prismatic joint, ±5° for a
// revolute one (the label says it in the unit a surgeon reads; the command is in the joint's unit).
const STEP_MOVE = {mm: {delta: 1, label: '1 mm'}, rad: {delta: 5 * Math.PI / 180, label: '5°'},
                   deg: {delta: 5, label: '5°'}};

function prettyName(name) {
  const s = String(name).replace(/_/g, ' ');
  return s.charAt(0).toUpperCase() + s.slice(1);
}

function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === 'class') e.className = v;
    else if (k === 'text') e.textContent = v;
    else e.setAttribute(k, v);
  }
  e.append(...children);
  return e;
}

// onStep(index, delta, label): a step button was pressed (the caller commands it from the live setpoint).
export function buildJointPanel(form, jointDescriptions, onChange, {onStep} = {}) {
  form.replaceChildren();
  const rows = jointDescriptions.map((j, index) => {
    const apiUnit = j.unit || '';
    // Shown (and typed) in `unit`: degrees for a revolute joint; `scale` takes an API value to it.
    const {unit: shownAs, symbol: unit, scale} = displayUnit(apiUnit);
    const decimals = DECIMALS[shownAs] ?? 3;
    const step = STEP[shownAs] ?? 0.001;
    const lower = Number(j.lower) * scale;
    const upper = Number(j.upper) * scale;
    const id = `joint-${index}`;
    const fmt = (v) => (Number.isFinite(v) ? v.toFixed(decimals) : '—');

    const measuredValue = el('span', {'data-testid': `joint-measured-${j.name}`, text: '—'});
    const setpointValue = el('span', {'data-testid': `joint-setpoint-${j.name}`, text: '—'});
    const measuredDeg = el('span', {class: 'readout-sub'});
    const fill = el('span', {class: 'fill'});
    const spMark = el('span', {class: 'sp'});
    const bar = el('div', {class: 'range-bar', 'aria-hidden': 'true'}, fill, spMark);
    const number = el('input', {
      type: 'number', id: `${id}-goal`, min: String(lower), max: String(upper), step: String(step),
      inputmode: 'decimal', 'data-testid': `joint-goal-${j.name}`,
      'aria-label': `${prettyName(j.name)} goal in ${shownAs === 'deg' ? 'degrees' : unit}`,
    });
    const slider = el('input', {
      type: 'range', min: String(lower), max: String(upper), step: String(step),
      'data-testid': `joint-slider-${j.name}`, 'aria-label': `${prettyName(j.name)} goal slider in ${shownAs === 'deg' ? 'degrees' : unit}`,
    });
    const stepMove = STEP_MOVE[apiUnit];
    const stepButton = (sign) => {
      const b = el('button', {
        type: 'button', class: 'btn btn-small btn-step', 'data-testid': `joint-step-${sign > 0 ? 'plus' : 'minus'}-${j.name}`,
        'aria-label': `Step ${prettyName(j.name).toLowerCase()} ${sign > 0 ? '+' : '−'}${stepMove.label}`,
        text: `${sign > 0 ? '+' : '−'}${stepMove.label}`,
      });
      b.addEventListener('click', () => onStep?.(index, sign * stepMove.delta, `${sign > 0 ? '+' : '−'}${stepMove.label}`));
      return b;
    };
    const steps = stepMove ? [stepButton(-1), stepButton(1)] : [];
    const limitsText = `${fmt(lower)} … ${fmt(upper)}${shownAs === 'deg' ? '°' : ` ${unit}`}`;
    const row = el('fieldset', {class: 'joint', 'data-testid': `joint-row-${j.name}`, 'aria-label': prettyName(j.name)},
      el('div', {class: 'joint-head'},
        el('span', {class: 'joint-name', text: prettyName(j.name)}),
        el('span', {class: 'joint-limits', 'data-testid': `joint-limits-${j.name}`, text: `limits ${limitsText}`,
                    title: Number.isFinite(Number(j.max_velocity)) ? `max velocity ${fmt(Number(j.max_velocity) * scale)} ${unit}/s` : ''})),
      el('div', {class: 'joint-values'},
        el('div', {class: 'readout'}, el('span', {class: 'readout-label', text: 'measured'}),
          el('span', {class: 'readout-value'}, measuredValue, el('span', {class: 'unit', text: unit}), measuredDeg)),
        el('div', {class: 'readout readout-setpoint'}, el('span', {class: 'readout-label', text: 'setpoint'}),
          el('span', {class: 'readout-value'}, setpointValue, el('span', {class: 'unit', text: unit}))),
        el('div', {class: 'readout readout-goal'}, el('label', {class: 'readout-label', for: `${id}-goal`, text: 'goal'}),
          el('span', {class: 'goal-input-wrap'}, number, el('span', {class: 'goal-unit', text: unit})))),
      bar,
      el('div', {class: 'joint-goal-line'}, slider,
        el('span', {class: 'joint-steps', role: 'group', 'aria-label': `${prettyName(j.name)} step moves`}, ...steps)));
    form.appendChild(row);

    const r = {
      name: j.name, unit, scale, lower, upper, decimals, row, number, slider, fill, spMark, measuredValue, measuredDeg,
      setpointValue, fmt, steps, edited: false, measured: NaN, setpoint: NaN,
    };
    const fraction = (v) => Math.min(1, Math.max(0, (v - lower) / (upper - lower || 1)));
    r.fraction = fraction;
    const validate = () => {
      const v = Number(number.value);
      const ok = number.value.trim() !== '' && Number.isFinite(v) && v >= lower && v <= upper;
      number.setAttribute('aria-invalid', ok ? 'false' : 'true');
      number.title = ok ? '' : `Enter a value between ${fmt(lower)} and ${fmt(upper)} ${unit}`;
      return ok;
    };
    r.validate = validate;
    number.addEventListener('input', () => {
      r.edited = true;
      number.classList.add('edited');
      if (validate()) slider.value = number.value;
      onChange();
    });
    slider.addEventListener('input', () => {
      r.edited = true;
      number.classList.add('edited');
      number.value = Number(slider.value).toFixed(decimals);
      validate();
      onChange();
    });
    r.setGoal = (v) => {
      if (!Number.isFinite(v)) return;
      const clamped = Math.min(upper, Math.max(lower, v));
      number.value = clamped.toFixed(decimals);
      slider.value = String(clamped);
      validate();
    };
    return r;
  });

  const byName = new Map(rows.map((r) => [r.name, r]));
  const forEachValue = (js, values, fn) => {
    if (!js || !Array.isArray(values)) return;
    values.forEach((v, i) => {
      const r = Array.isArray(js.name) ? byName.get(js.name[i]) : rows[i];
      if (r) fn(r, Number(v));
    });
  };

  return {
    updateMeasured(js) {
      forEachValue(js, js.position, (r, apiValue) => {
        const v = apiValue * r.scale;
        r.measured = v;
        r.measuredValue.textContent = r.fmt(v);
        r.measuredValue.parentElement.parentElement.dataset.value = String(v);
        r.fill.style.width = `${(r.fraction(v) * 100).toFixed(2)}%`;
        const margin = (r.upper - r.lower) * 0.03;
        r.row.classList.toggle('near-limit', v <= r.lower + margin || v >= r.upper - margin);
      });
    },
    updateSetpoint(js) {
      if (!js) return;
      forEachValue(js, js.position, (r, apiValue) => {
        const v = apiValue * r.scale;
        r.setpoint = v;
        r.setpointValue.textContent = r.fmt(v);
        r.spMark.style.left = `calc(${(r.fraction(v) * 100).toFixed(2)}% - 1px)`;
        // A field with focus is being typed into: a live value written now would land in the middle
        // of the operator's typing (the selection is lost and the keys are appended to it).
        if (!r.edited && document.activeElement !== r.number && document.activeElement !== r.slider) r.setGoal(v);
      });
      onChange();
    },
    // The move_jp goal: edited joints as typed, the others at `setpoint` (positions in joint order,
    // read from the server just before sending).
    goals(setpoint) {
      return rows.map((r, i) => (r.edited ? Number(r.number.value) / r.scale : Number(setpoint?.[i] ?? r.setpoint / r.scale)));
    },
    edited() { return rows.some((r) => r.edited); },
    // Step buttons are live only while a move could be commanded; `why` is their tooltip otherwise.
    setStepsEnabled(enabled, why = '') {
      rows.forEach((r) => r.steps.forEach((b) => {
        b.disabled = !enabled;
        b.title = enabled ? '' : why;
      }));
    },
    // A step's goal: `setpoint` (the server's, read just before sending) with joint `index` moved by
    // `delta` and kept within its limits; null when the joint is already at the limit it steps toward.
    stepGoal(setpoint, index, delta) {
      const r = rows[index];
      if (!r || !Array.isArray(setpoint)) return null;
      const goal = setpoint.map(Number);
      const target = Math.min(r.upper / r.scale, Math.max(r.lower / r.scale, goal[index] + delta));
      if (Math.abs(target - goal[index]) < 1e-9) return null;
      goal[index] = target;
      return goal;
    },
    jointName(index) { return rows[index] ? prettyName(rows[index].name).toLowerCase() : ''; },
    // A value in the API's unit, as the panel shows it ("30.0°", "12.00 mm").
    format(index, v) {
      const r = rows[index];
      return r ? `${r.fmt(Number(v) * r.scale)}${r.unit === '°' ? '°' : ` ${r.unit}`}` : String(v);
    },
    invalidJoints() { return rows.filter((r) => r.edited && !r.validate()).map((r) => prettyName(r.name)); },
    // "will move: insertion 10.00 → 30.00 mm · unchanged: roll, proximal bend, distal bend"
    preview() {
      const moving = rows.filter((r) => r.edited);
      if (!moving.length) return '';
      const still = rows.filter((r) => !r.edited).map((r) => prettyName(r.name).toLowerCase());
      const parts = moving.map((r) => {
        const u = r.unit === '°' ? '°' : ` ${r.unit}`;
        return `${prettyName(r.name).toLowerCase()} ${r.fmt(r.setpoint)} → ${r.fmt(Number(r.number.value))}${u}`;
      });
      return `will move: ${parts.join(', ')}${still.length ? ` · unchanged: ${still.join(', ')}` : ''}`;
    },
    // After a move is accepted (or on "Clear goals") every goal follows the setpoint again.
    clearEdits() {
      rows.forEach((r) => {
        r.edited = false;
        r.number.classList.remove('edited');
        r.setGoal(Number.isFinite(r.setpoint) ? r.setpoint : r.measured);
      });
      onChange();
    },
  };
}
