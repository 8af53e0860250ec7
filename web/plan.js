// Plan panel: load a vessel (CSV or STL, mm), show its centreline in 3D, compute a plan (a job on
// the server, polled with a progress bar), show the planned catheter shape per insertion step and the
// planned error per step, then hand the plan to the robot's path_following mode and step through it.
// Routes (contracts): POST/GET /vessels, GET /vessels/{id}?branch=k, POST /plans, GET/DELETE /jobs/{id},
// GET/POST /robots/{r}/path_following, POST /robots/{r}/path_following/step. A server without the
// planning routes (404) gets a plain "not available" message, never invented data.
// Moving along a plan (issue 31): the step buttons say what will move before it moves (the "will move"
// line under the path status); "Go" to a far step goes through every step between, along the plan, never
// one joint-space jump across the vessel's bends; "Next" on a plan not yet started goes to the step
// nearest the catheter's insertion, not to step 0 if that means withdrawing it far.
import {ApiError} from './api.js';
import {StepPlot} from './plot.js';
import {planVerdict, stepRoute, nearestStep, movePreview, targetReach} from './plan_verdict.js';

const $ = (sel) => document.querySelector(sel);
const JOB_POLL_MS = 400;
const commandableNow = (ctx) => (ctx.commandable ? ctx.commandable() : true);

export class PlanPanel {
  // ctx: {api, view(): CatheterView|null, robot(): robot description, status(text, kind), onPathLoaded()}
  constructor(ctx) {
    this.ctx = ctx;
    this.ui = {
      availability: $('[data-testid="plan-availability"]'),
      body: $('#plan-body'),
      file: $('[data-testid="vessel-file"]'),
      upload: $('[data-testid="vessel-upload-button"]'),
      vessel: $('[data-testid="vessel-select"]'),
      branch: $('[data-testid="branch-select"]'),
      vesselInfo: $('[data-testid="vessel-info"]'),
      ds: $('[data-testid="plan-ds"]'),
      dq1: $('[data-testid="plan-dq1"]'),
      design: $('[data-testid="plan-design"]'),
      plan: $('[data-testid="plan-button"]'),
      cancel: $('[data-testid="plan-cancel-button"]'),
      progress: $('[data-testid="plan-progress"]'),
      jobStatus: $('[data-testid="plan-job-status"]'),
      summary: $('[data-testid="plan-summary"]'),
      verdict: $('[data-testid="plan-verdict"]'),
      stepStrip: $('[data-testid="plan-steps"]'),
      stopReason: $('[data-testid="path-stop-reason"]'),
      load: $('[data-testid="plan-load-button"]'),
      pathStatus: $('[data-testid="path-status"]'),
      prev: $('[data-testid="step-prev-button"]'),
      next: $('[data-testid="step-next-button"]'),
      stepInput: $('[data-testid="step-input"]'),
      go: $('[data-testid="step-go-button"]'),
      // The tip's distance from the plan's target, in the Plan tab and beside the tip in the Joints tab.
      targets: [$('[data-testid="plan-target"]'), $('[data-testid="config-target"]')],
    };
    this.errorPlot = new StepPlot($('[data-testid="plan-error-plot"]'), {
      left: {label: 'mean position error', unit: 'mm', color: '#e3b341'},
      right: {label: 'mean orientation error', unit: '°', color: '#39c5cf'},
    });
    this.available = null;  // unknown until GET /vessels answered
    this.vessels = [];
    this.job = null;        // the plan job being computed or shown
    this.plan = null;       // result of a succeeded plan job
    this.path = null;       // GET path_following answer
    this.verdict = null;    // planVerdict() of the plan shown, with its job id
    this.fetchingPlan = null;
    this.pathAvailable = null;
    this.loadedResult = null;  // the job result of the plan loaded on the robot (its steps' q), when known
    this.measured = null;      // the robot's measured joint values (GET measured_js), for the previews
    this.walking = false;      // a multi-step "Go" under way
    // The "will move" preview of the step buttons, under the path status.
    this.ui.stepPreview = document.createElement('div');
    this.ui.stepPreview.className = 'path-status step-preview';
    this.ui.stepPreview.dataset.testid = 'step-preview';
    this.ui.stepPreview.setAttribute('data-testid', 'step-preview');
    this.ui.pathStatus?.after(this.ui.stepPreview);
    this.wire();
    this.updateButtons();
  }

  wire() {
    const {ui} = this;
    ui.upload.addEventListener('click', () => this.upload());
    ui.file.addEventListener('change', () => this.updateButtons());
    ui.vessel.addEventListener('change', () => this.selectVessel(ui.vessel.value));
    ui.branch.addEventListener('change', () => this.showBranch());
    ui.plan.addEventListener('click', () => this.startPlan());
    ui.cancel.addEventListener('click', () => this.cancelPlan());
    ui.load.addEventListener('click', () => this.loadPlan());
    ui.prev.addEventListener('click', () => this.step({advance: -1}));
    ui.next.addEventListener('click', () => this.next());
    ui.go.addEventListener('click', () => this.goTo(Number(ui.stepInput.value)));
    ui.stepInput.addEventListener('input', () => {
      const k = Number(ui.stepInput.value);
      if (Number.isInteger(k)) this.preview(k);
      this.renderStepPreview();
    });
  }

  setAvailability(available, text) {
    this.available = available;
    this.ui.availability.textContent = text;
    this.ui.availability.dataset.available = String(available);
    this.ui.availability.hidden = available;
    this.ui.body.hidden = !available;
  }

  async refresh() {
    let list;
    try {
      list = await this.ctx.api.vessels();
    } catch (err) {
      if (err instanceof ApiError && [404, 405, 503].includes(err.status)) {
        this.setAvailability(false, 'Planning is not available on this server (GET /api/v1/vessels answered ' +
                                    `${err.status}${err.status === 503 ? `: ${err.message}` : ''}). Joint control is unaffected.`);
      } else if (this.available === null) {
        this.setAvailability(false, `Cannot reach the planning service: ${err.message}`);
      }
      return;
    }
    this.setAvailability(true, '');
    this.vessels = Array.isArray(list) ? list : Array.isArray(list?.vessels) ? list.vessels : [];
    const selected = this.ui.vessel.value;
    this.ui.vessel.replaceChildren(new Option(this.vessels.length ? 'choose a vessel…' : 'no vessel loaded yet', ''),
                                   ...this.vessels.map((v) => new Option(`${v.name || v.id} (${v.source || '?'})`, v.id)));
    if (this.vessels.some((v) => v.id === selected)) this.ui.vessel.value = selected;
    this.updateButtons();
  }

  async refreshPath() {
    const robot = this.ctx.robot();
    if (!robot) return;
    try {
      this.path = await this.ctx.api.pathFollowing(robot.name);
      this.pathAvailable = true;
      if (this.path?.loaded) {
        try {
          this.measured = (await this.ctx.api.measuredJs(robot.name))?.position ?? null;
        } catch {
          this.measured = null;
        }
      }
    } catch (err) {
      this.path = null;
      this.pathAvailable = !(err instanceof ApiError && [404, 405, 503].includes(err.status));
    }
    this.renderPath();
  }

  renderPath() {
    const {ui, path} = this;
    if (this.pathAvailable === false) {
      ui.pathStatus.textContent = 'Path following is not available on this server.';
    } else if (!path || !path.loaded) {
      ui.pathStatus.textContent = 'No plan loaded on the robot.';
    } else {
      // Steps are numbered 0…n-1 as in the API (the step box and POST …/step take the same numbers).
      const step = path.step >= 0 ? `at step ${path.step} (steps 0–${path.steps - 1})` : `not started (steps 0–${path.steps - 1})`;
      const next = this.stepVerdict(path.step + 1);
      const nextText = next && next.verdict !== 'ok' && path.step + 1 < path.steps
        ? ` · next step ${path.step + 1}: ${next.reasons[0]}` : '';
      ui.pathStatus.textContent = `Plan ${path.plan ?? ''} loaded: ${step}${path.moving ? ', moving…' : ''}${nextText}`;
      if (path.plan && this.verdict?.planId !== path.plan) this.fetchVerdict(path.plan);
      ui.stepInput.max = String(Math.max(0, path.steps - 1));
      if (path.step >= 0) {
        this.errorPlot.setCurrent(path.step);
        this.ctx.view()?.setPlanStep(path.step);
        this.markStep(path.step);
      }
    }
    ui.pathStatus.dataset.step = path && path.loaded ? String(path.step) : '';
    this.renderStepPreview();
    this.updateButtons();
  }

  // The loaded plan's steps (q per step), when this page knows the plan's job result.
  loadedSteps() {
    const r = this.loadedResult;
    return r && this.path?.plan && r.planId === this.path.plan && Array.isArray(r.result?.steps) ? r.result.steps : null;
  }

  // Where "Next" goes: the next step, or on a plan not started the step nearest the insertion.
  nextTarget() {
    const {path} = this;
    if (!path?.loaded) return null;
    if (path.step >= 0) return path.step + 1 < path.steps ? path.step + 1 : null;
    const steps = this.loadedSteps();
    return steps && Number.isFinite(Number(this.measured?.[0])) ? nearestStep(steps, this.measured[0]) : 0;
  }

  // "Next will move: …" and "Go to step k will move: …, through steps a–b" before anything moves.
  renderStepPreview() {
    const {ui, path} = this;
    if (!ui.stepPreview) return;
    const steps = this.loadedSteps();
    const joints = this.ctx.robot()?.joints || [];
    const lines = [];
    if (path?.loaded && steps && this.measured) {
      const n = this.nextTarget();
      if (n !== null && steps[n]) {
        lines.push(`Next → step ${n}: ${movePreview(this.measured, steps[n].q, joints)}`);
      }
      const k = Number(ui.stepInput.value);
      if (Number.isInteger(k) && steps[k]) {
        const route = stepRoute(steps, path.step, k, this.measured[0]);
        const via = route.length > 1 ? ` (along the plan through steps ${route[0]}–${route[route.length - 1]}, ${route.length} moves)` : '';
        lines.push(`Go → step ${k}: ${movePreview(this.measured, steps[k].q, joints)}${via}`);
      }
    }
    ui.stepPreview.textContent = lines.join('\n');
    ui.stepPreview.hidden = !lines.length;
  }

  // The verdict of step k of the plan loaded on the robot (null when unknown).
  stepVerdict(k) {
    if (!this.verdict || (this.path?.plan && this.verdict.planId !== this.path.plan)) return null;
    return this.verdict.v.steps[k] || null;
  }

  // A plan loaded on the robot but computed elsewhere (another page, a script): its verdict too.
  async fetchVerdict(planId) {
    if (this.fetchingPlan === planId) return;
    this.fetchingPlan = planId;
    try {
      const job = await this.ctx.api.job(planId);
      if (job?.result) {
        this.loadedResult = {planId, result: job.result};
        this.setVerdict(planId, job.result);
        this.renderStepPreview();
      }
    } catch {
      // the job may have expired on the server: no verdict
    }
  }

  setVerdict(planId, result) {
    const v = planVerdict(result, this.ctx.robot(), this.branchRadius);
    this.verdict = {planId, v};
    const {ui} = this;
    const words = {ok: 'Followable', contact: 'Expect wall contact', 'cannot-follow': 'Cannot be followed', unknown: 'Not judged',
                   'other-catheter': 'Made for another catheter'};
    ui.verdict.dataset.verdict = v.verdict;
    ui.verdict.textContent = `${v.verdict === 'ok' ? '✓' : '⚠'} ${words[v.verdict]}` +
        (v.reasons.length ? `: ${v.reasons.join('; ')}` : ': every step within the vessel and the joint limits');
    ui.stepStrip.replaceChildren(...v.steps.map((st) => {
      const cell = document.createElement('span');
      cell.className = 'plan-step';
      cell.dataset.step = String(st.step);
      cell.dataset.verdict = st.verdict;
      cell.title = `step ${st.step}: ${Number.isFinite(st.positionMm) ? st.positionMm.toFixed(1) : '?'} mm / ` +
          `${Number.isFinite(st.orientationDeg) ? st.orientationDeg.toFixed(0) : '?'}° worst error` +
          (st.reasons.length ? ` — ${st.reasons.join('; ')}` : ' — ok');
      return cell;
    }));
    this.markStep(this.path?.step ?? -1);
  }

  markStep(k) {
    for (const c of this.ui.stepStrip.children) c.classList.toggle('current', Number(c.dataset.step) === k);
  }

  // Why following stopped, whenever a plan is under way and the robot is not ENABLED in path following.
  renderStopReason() {
    const {ui, path} = this;
    const os = this.ctx.operating?.();
    let reason = '';
    if (path && path.loaded && path.step >= 0 && os) {
      const where = `Following stopped at step ${path.step} (steps 0–${path.steps - 1})`;
      const hold = this.ctx.hold?.();
      if (os.estop) reason = `${where}: the e-stop is latched. Reset, Enable, switch to Path following, then step on.`;
      else if (os.state === 'FAULT') reason = `${where}: fault — ${os.fault?.message || 'see the banner and the events'}. Reset, then Enable.`;
      else if (hold) {
        reason = `${where}: held — ${hold.message || String(hold.cause).replace(/_/g, ' ')}. ${hold.next || 'Resume when clear.'}`;
      } else if (os.state === 'DISABLED') reason = `${where}: the robot is disabled. Enable it, then step on.`;
      else if (os.mode !== 'path_following') reason = `${where}: the robot left Path following mode (now ${String(os.mode).replace(/_/g, ' ')}).`;
      const v = this.stepVerdict(path.step + 1);
      if (reason && v && v.verdict !== 'ok') reason += ` The plan warned: step ${path.step + 1} ${v.reasons[0]}.`;
    }
    ui.stopReason.textContent = reason;
    ui.stopReason.hidden = !reason;
    ui.stopReason.dataset.stopped = String(!!reason);
  }

  updateButtons() {
    const {ui} = this;
    this.renderStopReason();
    const running = this.job && ['queued', 'running'].includes(this.job.state);
    const os = this.ctx.operating?.();
    const inPathMode = os && os.mode === 'path_following';
    ui.upload.disabled = !ui.file.files?.length;
    ui.plan.disabled = !ui.vessel.value || running;
    ui.cancel.disabled = !running;
    // A plan made for another catheter is not offered for loading (the server refuses it as well).
    const otherCatheter = this.verdict?.planId === this.job?.id && this.verdict?.v.verdict === 'other-catheter';
    ui.load.disabled = !this.plan || !this.job || !commandableNow(this.ctx) || otherCatheter;
    ui.load.title = otherCatheter ? `Not loadable: ${this.verdict.v.otherCatheter}` : '';
    const commandable = this.ctx.commandable ? this.ctx.commandable() : true;
    const canStep = !!(this.path && this.path.loaded && inPathMode && os.state === 'ENABLED') && commandable;
    ui.prev.disabled = !canStep || this.walking || this.path.step <= 0;
    ui.next.disabled = !canStep || this.walking || this.path.step >= this.path.steps - 1;
    ui.go.disabled = !canStep || this.walking;
    let hint = '';
    if (this.path && this.path.loaded && !inPathMode) hint = 'Switch to Path following mode to step.';
    else if (this.path && this.path.loaded && os && os.state !== 'ENABLED') hint = 'Enable the robot to step.';
    ui.go.title = hint;
    ui.next.title = hint;
    ui.prev.title = hint;
  }

  async upload() {
    const file = this.ui.file.files?.[0];
    if (!file) return;
    const name = file.name.replace(/\.(csv|stl)$/i, '');
    try {
      const vessel = await this.ctx.api.uploadVessel(file, name);
      this.ctx.status(`Vessel ${vessel.name || vessel.id} loaded: ${vessel.branches?.length ?? 0} branch(es)`, 'ok');
      await this.refresh();
      this.ui.vessel.value = vessel.id;
      await this.selectVessel(vessel.id);
    } catch (err) {
      this.ctx.status(`Vessel refused: ${err.message}`, 'error');
    }
  }

  async selectVessel(id) {
    const vessel = this.vessels.find((v) => v.id === id);
    const branches = vessel?.branches || [];
    this.ui.branch.replaceChildren(...branches.map((b) => new Option(
        `branch ${b.index} · ${Number(b.length_mm).toFixed(0)} mm`, String(b.index))));
    this.ui.vesselInfo.textContent = vessel
      ? `${branches.length} branch(es), ${branches.reduce((n, b) => n + (b.points || 0), 0)} points`
      : '';
    this.updateButtons();
    if (vessel) await this.showBranch();
    else this.ctx.view()?.setVessel(null);
  }

  async showBranch() {
    const id = this.ui.vessel.value;
    if (!id) return;
    try {
      const branch = await this.ctx.api.vessel(id, Number(this.ui.branch.value || 0));
      this.branchRadius = branch.radius;
      this.ctx.view()?.setVessel(branch.points, branch.radius, {entry: this.ctx.robot()?.vessel_entry, asLoaded: true});
    } catch (err) {
      this.ctx.status(`Cannot load the vessel branch: ${err.message}`, 'error');
    }
  }

  async startPlan() {
    const robot = this.ctx.robot();
    const body = {
      robot: robot.name,
      vessel: this.ui.vessel.value,
      branch: Number(this.ui.branch.value || 0),
      ds: Number(this.ui.ds.value),
      dq1: Number(this.ui.dq1.value),
      design: this.ui.design.value,
    };
    this.plan = null;
    this.errorPlot.setData([], []);
    this.errorPlot.setMessage('Computing the plan…');
    this.ctx.view()?.setPlan(null);
    try {
      this.job = await this.ctx.api.startPlan(body);
    } catch (err) {
      this.ctx.status(`Plan refused: ${err.message}`, 'error');
      this.errorPlot.setMessage('No plan yet.');
      return;
    }
    this.showJob();
    this.pollJob(this.job.id);
  }

  async pollJob(id) {
    while (this.job && this.job.id === id && ['queued', 'running'].includes(this.job.state)) {
      await new Promise((r) => setTimeout(r, JOB_POLL_MS));
      try {
        this.job = await this.ctx.api.job(id);
      } catch (err) {
        this.ui.jobStatus.textContent = `Lost track of job ${id}: ${err.message}`;
        return;
      }
      this.showJob();
    }
    if (this.job?.id === id && this.job.state === 'succeeded') this.showPlan(this.job.result);
    else if (this.job?.id === id) this.errorPlot.setMessage(`No plan: the job ${this.job.state}.`);
  }

  showJob() {
    const job = this.job;
    const progress = Math.min(1, Math.max(0, Number(job.progress) || 0));
    this.ui.progress.value = job.state === 'succeeded' ? 1 : progress;
    this.ui.progress.setAttribute('aria-valuetext', `${(progress * 100).toFixed(0)} %`);
    this.ui.progress.dataset.state = job.state;
    const message = job.message ? `: ${job.message}` : '';
    this.ui.jobStatus.textContent = `Plan job ${job.id} ${job.state} (${(progress * 100).toFixed(0)} %)${message}`;
    this.ui.jobStatus.className = `job-status ${job.state === 'failed' ? 'error' : ''}`;
    this.updateButtons();
  }

  showPlan(result) {
    this.plan = result;
    const steps = Array.isArray(result?.steps) ? result.steps : [];
    this.errorPlot.setData(steps.map((s) => Number(s.position_error_mm)), steps.map((s) => Number(s.orientation_error_deg)));
    // The plan lives in its insertion frame (vessel start at the origin, tangent +z); the vessel path
    // the planner used is in that same frame, and the robot's vessel_entry puts both where the robot is.
    const entry = this.ctx.robot()?.vessel_entry;
    if (Array.isArray(result?.vessel_path) && result.vessel_path.length >= 2) {
      const r = Array.isArray(this.branchRadius) ? this.branchRadius : null;
      this.ctx.view()?.setVessel(result.vessel_path, r, {entry});
    }
    this.ctx.view()?.setPlan(steps.map((s) => s.backbone), {entry});
    const sm = result?.summary || {};
    const f = (v, d = 2) => (Number.isFinite(Number(v)) ? Number(v).toFixed(d) : '—');
    const design = result?.design ? ` · design L1 ${f(result.design.L1, 1)} mm, L2 ${f(result.design.L2, 1)} mm` : '';
    this.setVerdict(this.job?.id, result);
    this.ui.summary.textContent = `${steps.length} steps (0–${steps.length - 1}) · position error mean ${f(sm.mean_position_error_mm)} / ` +
      `max ${f(sm.max_position_error_mm)} mm · orientation error mean ${f(sm.mean_orientation_error_deg, 1)} / ` +
      `max ${f(sm.max_orientation_error_deg, 1)}° · computed in ${f(sm.compute_s, 1)} s${design}` +
      (result?.truncated_to_insertion_range ? ' · ⚠ truncated to the insertion range' : '') +
      (result?.within_joint_limits === false
        ? ` · ⚠ outside joint limits${result.limit_violation ? `: ${JSON.stringify(result.limit_violation).slice(0, 160)}` : ''}` : '');
    this.ui.stepInput.max = String(Math.max(0, steps.length - 1));
    this.preview(0);
    this.updateButtons();
  }

  // The tip (robot frame, mm) against the target of the plan loaded on the robot, else of the plan shown:
  // "Tip 1.7 mm from the vessel's end · reached (within 3.0 mm, the lumen radius there)".
  showTip(tip) {
    const loaded = this.path?.loaded && this.loadedResult?.planId === this.path.plan ? this.loadedResult.result : null;
    const plan = loaded || this.plan;
    // The lumen radius is the selected branch's: a plan of another vessel or branch gets no verdict.
    const sameBranch = plan && String(plan.vessel) === this.ui.vessel.value && String(plan.branch ?? 0) === String(this.ui.branch.value || 0);
    const r = sameBranch ? targetReach(plan, this.ctx.robot()?.vessel_entry, this.branchRadius, tip) : null;
    const where = r?.truncated ? "the plan's end (truncated: the vessel goes on)" : "the vessel's end";
    const verdict = r ? `${r.reached ? 'reached' : 'not reached'} (within ${r.toleranceMm.toFixed(1)} mm` : '';
    const texts = [r ? `Tip ${r.distanceMm.toFixed(1)} mm from ${where} · ${verdict}, the lumen radius there)` : '',
                   r ? `${r.distanceMm.toFixed(1)} mm · ${verdict})` : '—'];
    this.ui.targets.forEach((el, k) => {
      el.textContent = texts[k];
      el.hidden = k === 0 && !r;
      el.dataset.reached = r ? String(r.reached) : '';
      el.dataset.distanceMm = r ? r.distanceMm.toFixed(2) : '';
      el.dataset.toleranceMm = r ? r.toleranceMm.toFixed(2) : '';
    });
  }

  // Highlights a step in the 3D view and the error plot without moving the robot.
  preview(step) {
    this.errorPlot.setCurrent(step);
    this.ctx.view()?.setPlanStep(step);
  }

  async cancelPlan() {
    if (!this.job) return;
    try {
      this.job = await this.ctx.api.cancelJob(this.job.id);
      this.showJob();
    } catch (err) {
      this.ctx.status(`Cancel refused: ${err.message}`, 'error');
    }
  }

  async loadPlan() {
    const robot = this.ctx.robot();
    try {
      const answer = await this.ctx.api.loadPlan(robot.name, this.job.id);
      this.loadedResult = {planId: this.job.id, result: this.plan};
      this.ctx.status(`Plan loaded on ${robot.name}: ${answer.steps} steps. Switch to Path following mode, then step.`, 'ok');
    } catch (err) {
      this.ctx.status(`Loading the plan refused: ${err.message}`, 'error');
    }
    await this.refreshPath();
    this.ctx.onPathLoaded?.();
  }

  async step(body) {
    const robot = this.ctx.robot();
    let ok = false;
    try {
      const answer = await this.ctx.api.pathStep(robot.name, body);
      this.preview(answer.step);
      const d = Number.isFinite(answer.duration_s) ? ` (about ${answer.duration_s.toFixed(1)} s)` : '';
      this.ctx.status(`Moving to plan step ${answer.step}${d}`, 'ok');
      ok = true;
    } catch (err) {
      this.ctx.status(`Step refused: ${err.message}`, 'error');
    }
    await this.refreshPath();
    return ok;
  }

  // "Next": the next step; on a plan not started, the step nearest the insertion.
  async next() {
    if (this.path?.loaded && this.path.step < 0) {
      const k = this.nextTarget();
      return this.step(k !== null && k > 0 ? {step: k} : {advance: 1});
    }
    return this.step({advance: 1});
  }

  // "Go": through every step between here and step k, one at a time along the plan.
  async goTo(k) {
    const steps = this.loadedSteps();
    const from = this.path?.step ?? -1;
    // Without the plan's joint values (a plan loaded elsewhere whose job expired) the walk starts at step 0.
    const route = stepRoute(steps || Array.from({length: this.path?.steps ?? 0}, () => ({})), from, k, this.measured?.[0]);
    if (!route.length) return this.step({step: k});  // the server names what is wrong with k
    this.walking = true;
    this.updateButtons();
    try {
      for (const j of route) {
        if (this.path?.step === j && !this.path.moving) continue;
        if (!(await this.step({step: j}))) return;
        // Wait until the robot holds at step j before the next one; stop if it holds for a reason.
        for (;;) {
          await new Promise((r) => setTimeout(r, 150));
          await this.refreshPath();
          const os = this.ctx.operating?.();
          if (!this.path?.loaded || (os && (os.state !== 'ENABLED' || os.mode !== 'path_following'))) return;
          if (!this.path.moving) break;
        }
        if (this.path.step !== j) return;
      }
    } finally {
      this.walking = false;
      this.updateButtons();
    }
  }
}
