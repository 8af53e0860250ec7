// REST client for tendril's /api/v1 (server/openapi/openapi.json). Same-origin fetch: the session cookie set by the
// server when the page was opened with ?token= goes along, and the lease belongs to that session.
// If the server answers 401 (session lost, e.g. after a restart) and the page still holds the token
// from its URL, the client first opens a new cookie session with it; only if that fails does it switch
// to a Bearer header. Then the lease belongs to the lease token that POST /lease answered, sent as
// X-Tendril-Lease ("new" until the first lease), so it stays this page's and no other bearer client's.

export class ApiError extends Error {
  constructor(status, code, message, details = {}) {
    super(message);
    this.status = status;
    this.code = code;
    this.details = details;  // the whole error object (e.g. holder, takeover_token for lease_held)
  }
}

export class Api {
  constructor(base = '/api/v1') {
    this.base = base;
    this.token = null;          // from ?token=, kept in memory only
    this.useBearer = false;     // switched on after a 401 with the cookie
    this.clientName = `console-${Math.random().toString(36).slice(2, 10)}`;  // a label in lease messages
    this.leaseToken = null;     // from POST /lease, sent with Bearer requests
    this.onNetwork = null;      // (answered: bool) after every request: the page backs off while false
  }

  async request(method, path, body, options = {}) {
    try {
      return await this.send(method, path, body, options);
    } catch (err) {
      if (err.status !== 401 || !this.token || this.useBearer) throw err;
      // The session is gone (e.g. tendrild restarted): open a new one the way the page did, so the
      // WebSocket (which carries only the cookie) works again too. Bearer only if that fails.
      if (await this.renewSession()) {
        try {
          return await this.send(method, path, body, options);
        } catch (again) {
          if (again.status !== 401) throw again;
        }
      }
      this.useBearer = true;
      return this.send(method, path, body, options);
    }
  }

  // One renewal at a time, however many requests failed together.
  renewSession() {
    if (!this.renewing) {
      this.renewing = fetch(`/?token=${encodeURIComponent(this.token)}`, {credentials: 'same-origin', cache: 'no-store'})
        .then((r) => r.ok, () => false)
        .finally(() => setTimeout(() => { this.renewing = null; }, 2000));
    }
    return this.renewing;
  }

  // raw: {contentType, data} sends a file body as is (vessel upload); text: answer is not JSON;
  // absolute: path is not under /api/v1.
  async send(method, path, body, {raw = null, text: wantText = false, absolute = false} = {}) {
    const headers = {Accept: wantText ? 'text/plain' : 'application/json'};
    if (raw) headers['Content-Type'] = raw.contentType;
    else if (body !== undefined) headers['Content-Type'] = 'application/json';
    if (this.useBearer) {
      headers.Authorization = `Bearer ${this.token}`;
      headers['X-Tendril-Client'] = this.clientName;
      headers['X-Tendril-Lease'] = this.leaseToken || 'new';
    }
    let response;
    try {
      response = await fetch(absolute ? path : this.base + path, {
        method,
        headers,
        body: raw ? raw.data : body === undefined ? undefined : JSON.stringify(body),
        credentials: 'same-origin',
        cache: 'no-store',
      });
    } catch (err) {
      this.onNetwork?.(false);
      throw new ApiError(0, 'network', `server unreachable (${err.message})`);
    }
    this.onNetwork?.(true);
    const text = await response.text();
    if (wantText && response.ok) return text;
    let data = null;
    if (text) {
      try {
        data = JSON.parse(text);
      } catch {
        data = null;
      }
    }
    if (!response.ok) {
      const e = data && data.error ? data.error : {};
      throw new ApiError(response.status, e.code || `http_${response.status}`,
                         e.message || `${method} ${path} failed with HTTP ${response.status}`, e);
    }
    return data;
  }

  get(path) { return this.request('GET', path); }
  post(path, body = {}) { return this.request('POST', path, body); }
  del(path) { return this.request('DELETE', path); }

  robots() { return this.get('/robots'); }
  measuredJs(robot) { return this.get(`/robots/${encodeURIComponent(robot)}/measured_js`); }
  setpointJs(robot) { return this.get(`/robots/${encodeURIComponent(robot)}/setpoint_js`); }
  measuredCp(robot) { return this.get(`/robots/${encodeURIComponent(robot)}/measured_cp`); }
  shape(robot) { return this.get(`/robots/${encodeURIComponent(robot)}/shape`); }
  operatingState(robot) { return this.get(`/robots/${encodeURIComponent(robot)}/operating_state`); }
  faults() { return this.get('/faults'); }
  // command: enable, disable, pause, resume; for a held catheter also relax, and withdraw (extra:
  // {distance_mm}).
  stateCommand(robot, command, extra = {}) {
    return this.post(`/robots/${encodeURIComponent(robot)}/state_command`, {command, ...extra});
  }
  moveJp(robot, goal) { return this.post(`/robots/${encodeURIComponent(robot)}/move_jp`, {goal}); }
  // The tip or tool in a Cartesian mode: a goal pose {position (mm), orientation [qx, qy, qz, qw]}, or a
  // velocity (linear mm/s, angular rad/s) that the robot holds for its command timeout.
  moveCp(robot, goal) { return this.post(`/robots/${encodeURIComponent(robot)}/move_cp`, {goal}); }
  servoCv(robot, linear, angular = [0, 0, 0]) { return this.post(`/robots/${encodeURIComponent(robot)}/servo_cv`, {linear, angular}); }
  estop() { return this.post('/estop', {}); }
  estopReset() { return this.post('/estop/reset', {}); }
  // Each robot has its own operator lease (/robots/{r}/lease); without a robot, every robot's (/lease).
  // The server gives one holder one token for all its leases.
  leasePath(robot) { return robot ? `/robots/${encodeURIComponent(robot)}/lease` : '/lease'; }
  lease(robot) { return this.get(this.leasePath(robot)); }
  async takeLease(robot, takeoverToken) {
    const granted = await this.post(this.leasePath(robot), takeoverToken ? {takeover_token: takeoverToken} : {});
    if (granted && granted.lease_token) this.leaseToken = granted.lease_token;
    return granted;
  }
  releaseLease(robot) { return this.del(this.leasePath(robot)); }
  setMode(robot, mode) { return this.post(`/robots/${encodeURIComponent(robot)}/mode`, {mode}); }
  moveConfiguration(robot, goal) { return this.post(`/robots/${encodeURIComponent(robot)}/move_configuration`, {goal}); }
  joystick(robot, axes, deadman) { return this.post(`/robots/${encodeURIComponent(robot)}/joystick`, {axes, deadman}); }
  health() { return this.get('/health'); }
  // Prometheus text of GET /metrics (outside /api/v1).
  metricsText() { return this.request('GET', '/metrics', undefined, {text: true, absolute: true}); }

  // Planning (vessels, plan jobs) and path following.
  vessels() { return this.get('/vessels'); }
  vessel(id, branch) { return this.get(`/vessels/${encodeURIComponent(id)}?branch=${branch}&ds=1`); }
  uploadVessel(file, name) {
    const contentType = /\.stl$/i.test(file.name) ? 'model/stl' : 'text/csv';
    return this.request('POST', `/vessels?name=${encodeURIComponent(name)}`, undefined, {raw: {contentType, data: file}});
  }
  deleteVessel(id) { return this.del(`/vessels/${encodeURIComponent(id)}`); }
  startPlan(body) { return this.post('/plans', body); }
  job(id) { return this.get(`/jobs/${encodeURIComponent(id)}`); }
  cancelJob(id) { return this.del(`/jobs/${encodeURIComponent(id)}`); }
  pathFollowing(robot) { return this.get(`/robots/${encodeURIComponent(robot)}/path_following`); }
  loadPlan(robot, planId) { return this.post(`/robots/${encodeURIComponent(robot)}/path_following`, {plan: planId}); }
  pathStep(robot, body) { return this.post(`/robots/${encodeURIComponent(robot)}/path_following/step`, body); }
}
