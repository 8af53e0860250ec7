// Operator words for server sentences. The server's messages are written for API users too: a refusal
// or a hold's way out names the request to send ("switch to tip mode (POST /api/v1/robots/sdu/mode
// {"mode": "tip"})", "roll along it: POST /api/v1/robots/sdu/roll") and, in older sentences, a requirement id
// in parentheses. The console shows what to press instead; the server's own sentence stays in the
// element's title for whoever needs it.

const prettyMode = (mode) => {
  const s = String(mode).replace(/_/g, ' ');
  return s.charAt(0).toUpperCase() + s.slice(1);
};

// The request's path (after /api/v1) and body -> what the console offers for it, or '' (dropped).
function buttonFor(route, body) {
  if (/^\/estop\/reset$/.test(route)) return 'Reset';
  if (/^\/estop$/.test(route)) return 'E-STOP';
  if (/\/roll$/.test(route)) return 'the ◀ Roll / Roll ▶ buttons in the Robot tab';
  if (/\/unbias$/.test(route)) return 'Unbias Hall in the Robot tab';
  if (/\/mode$/.test(route)) {
    const mode = /"mode"\s*:\s*"([^"]+)"/.exec(body || '')?.[1];
    return mode ? `the ${prettyMode(mode)} mode button` : 'the mode bar';
  }
  if (/\/path_following$/.test(route)) return 'Load plan in the Plan tab';
  if (/\/calibrate$/.test(route)) return 'Calibrate in the Robot tab';
  if (/\/lease$/.test(route)) return 'Take lease';
  if (/\/sweep$/.test(route)) {
    const action = /"action"\s*:\s*"([^"]+)"/.exec(body || '')?.[1];
    return action ? `${prettyMode(action)} in the Robot tab` : 'the sweep buttons in the Robot tab';
  }
  if (/\/(enable|disable|pause|resume|relax|withdraw)$/.test(route)) return prettyMode(/\/(\w+)$/.exec(route)[1]);
  return '';
}

// A request named in a sentence: METHOD /api/v1/… with an optional JSON body, in parentheses or not.
const REQUEST = /(\(\s*)?(?:POST|GET|PUT|DELETE|PATCH) \/api\/v1(\/[^\s)]*)((?:\s*\{[^}]*\})?)(?:\s+or\s+(?:POST|GET|PUT|DELETE) \/api\/v1\/[^\s)]*)?(\s*\))?/g;

export function operatorWords(text) {
  if (typeof text !== 'string' || !text) return text;
  return text
    .replace(REQUEST, (whole, open, route, body, close) => {
      const button = buttonFor(route, body);
      const tail = close && !open ? ')' : '';  // a parenthesis the request did not open stays
      if (!button) return tail;
      return open && close ? `(press ${button})` : `press ${button}${tail}`;
    })
    .replace(/\b(?:run|send|use) press /g, 'press ')
    // A robot's own short form: "POST sweep {"action":"plan"}" -> "press Plan".
    .replace(/\b(?:POST|PUT) [a-z_]+ \{\s*"action"\s*:\s*"([a-z_]+)"\s*\}/g, (whole, action) => `press ${prettyMode(action)}`)
    .replace(/\s*\(REQ-[A-Z]+-\d+\)/g, '')
    .replace(/\s{2,}/g, ' ')
    .replace(/\s+([,.;:)])/g, '$1')
    .replace(/\(\s*\)/g, '');
}
