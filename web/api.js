// REST client for tendril's /api/v1 (see API.md). Same-origin fetch: the session cookie set by the
// server when the page was opened with ?token= goes along, and the lease belongs to that session.
// Only if the server answers 401 (cookie blocked or lost) and the page still holds the token from its
// URL does the client switch to a Bearer header, naming itself with X-Tendril-Client so the lease has
// a stable owner across connections.

export class ApiError extends Error {
  constructor(status, code, message) {
    super(message);
    this.status = status;
    this.code = code;
  }
}

export class Api {
  constructor(base = '/api/v1') {
    this.base = base;
    this.token = null;          // from ?token=, kept in memory only
    this.useBearer = false;     // switched on after a 401 with the cookie
    this.clientName = `console-${Math.random().toString(36).slice(2, 10)}`;
  }

  async request(method, path, body) {
    try {
      return await this.send(method, path, body);
    } catch (err) {
      if (err.status === 401 && this.token && !this.useBearer) {
        this.useBearer = true;
        return this.send(method, path, body);
      }
      throw err;
    }
  }

  async send(method, path, body) {
    const headers = {Accept: 'application/json'};
    if (body !== undefined) headers['Content-Type'] = 'application/json';
    if (this.useBearer) {
      headers.Authorization = `Bearer ${this.token}`;
      headers['X-Tendril-Client'] = this.clientName;
    }
    let response;
    try {
      response = await fetch(this.base + path, {
        method,
        headers,
        body: body === undefined ? undefined : JSON.stringify(body),
        credentials: 'same-origin',
        cache: 'no-store',
      });
    } catch (err) {
      throw new ApiError(0, 'network', `server unreachable (${err.message})`);
    }
    const text = await response.text();
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
                         e.message || `${method} ${path} failed with HTTP ${response.status}`);
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
  stateCommand(robot, command) {
    return this.post(`/robots/${encodeURIComponent(robot)}/state_command`, {command});
  }
  moveJp(robot, goal) { return this.post(`/robots/${encodeURIComponent(robot)}/move_jp`, {goal}); }
  estop() { return this.post('/estop', {}); }
  estopReset() { return this.post('/estop/reset', {}); }
  lease() { return this.get('/lease'); }
  takeLease() { return this.post('/lease', {}); }
  releaseLease() { return this.del('/lease'); }
}
