// 3D view of the catheter: backbone as a tube along the polyline (mm), the tip frame as axes, a
// millimetre grid, and any other foxglove.SceneUpdate entities (lines, arrows, spheres, cubes,
// cylinders, triangles, texts) the server publishes, point clouds (foxglove.PointCloud), and frames
// from /tf (foxglove.FrameTransforms) for a view fixed to a moving frame. Z is up, as in Foxglove. Renders only when something changed, to leave the CPU
// to the control loop on small machines.
import * as THREE from 'three';
import {OrbitControls} from 'three/addons/controls/OrbitControls.js';

const BACKBONE_RADIUS_MM = 0.9;  // drawn thicker than the real 0.88 mm OD so it stays visible when zoomed out
const GRID_SIZE_MM = 200;
const GRID_STEP_MM = 10;
const MIN_ARROW_MM = 10;

function colorOf(c, fallback = 0xe3b341) {
  if (!c) return new THREE.Color(fallback);
  return new THREE.Color(c.r, c.g, c.b);
}

function toVec(p) {
  return Array.isArray(p) ? new THREE.Vector3(p[0], p[1], p[2]) : new THREE.Vector3(p.x, p.y, p.z);
}

// One world: the robot's frame. A plan and its vessel path come in the planner's insertion frame
// (vessel start at the origin, tangent +z); the robot's vessel_entry (GET /robots) is where that
// frame's origin sits, so they are drawn under it. A vessel as loaded (its own frame) is first moved
// into the insertion frame as the planner moves it: start to the origin, first tangent (over the first
// 0.5 mm, the planner's default spacing) to +z.
function placeEntry(object, entry) {
  if (!entry || !Array.isArray(entry.position)) return;
  object.position.set(entry.position[0], entry.position[1], entry.position[2]);
  const o = entry.orientation;
  if (Array.isArray(o) && o.length === 4) object.quaternion.set(o[0], o[1], o[2], o[3]);
}

function toInsertionFrame(vecs) {
  const start = vecs[0].clone();
  const ahead = vecs.find((v) => v.distanceTo(start) >= 0.5) || vecs[vecs.length - 1];
  const tangent = ahead.clone().sub(start).normalize();
  const turn = new THREE.Quaternion().setFromUnitVectors(tangent, new THREE.Vector3(0, 0, 1));
  return vecs.map((v) => v.clone().sub(start).applyQuaternion(turn));
}

// Beyond this many spheres in one entity they are drawn as points (see setEntity).
const MAX_SPHERE_MESHES = 64;

function colorAttribute(colors) {
  const a = new Float32Array(colors.length * 3);
  colors.forEach((c, i) => a.set([c?.r ?? 1, c?.g ?? 1, c?.b ?? 1], i * 3));
  return new THREE.BufferAttribute(a, 3);
}

function meanSize(spheres) {
  const sum = spheres.reduce((acc, sp) => acc + (sp.size?.x ?? 1), 0);
  return Math.max(0.3, sum / spheres.length);
}

function pointsObject(positions, colors, size) {
  const geometry = new THREE.BufferGeometry().setFromPoints(positions.map(toVec));
  geometry.setAttribute('color', colorAttribute(colors.map((c) => c || {r: 0.9, g: 0.9, b: 0.9})));
  return new THREE.Points(geometry, new THREE.PointsMaterial({size, vertexColors: true, sizeAttenuation: true}));
}

// foxglove.TextPrimitive as a sprite (always faces the camera, as billboard text does). font_size is
// in mm unless scale_invariant, then in pixels (drawn at a fixed share of the view's height).
function textSprite(text) {
  const canvas = document.createElement('canvas');
  const ctx = canvas.getContext('2d');
  const px = 32;
  ctx.font = `${px}px system-ui, sans-serif`;
  const lines = String(text.text).split('\n');
  const width = Math.ceil(Math.max(...lines.map((l) => ctx.measureText(l).width))) + 12;
  canvas.width = width;
  canvas.height = lines.length * (px + 6) + 6;
  ctx.font = `${px}px system-ui, sans-serif`;
  ctx.fillStyle = 'rgba(11,15,20,0.72)';
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  const c = text.color || {r: 1, g: 1, b: 1};
  ctx.fillStyle = `rgb(${Math.round(c.r * 255)},${Math.round(c.g * 255)},${Math.round(c.b * 255)})`;
  ctx.textBaseline = 'top';
  lines.forEach((l, i) => ctx.fillText(l, 6, 6 + i * (px + 6)));
  const texture = new THREE.CanvasTexture(canvas);
  texture.colorSpace = THREE.SRGBColorSpace;
  const invariant = !!text.scale_invariant;
  const material = new THREE.SpriteMaterial({map: texture, depthTest: false, sizeAttenuation: !invariant, toneMapped: false});
  const sprite = new THREE.Sprite(material);
  const height = invariant ? (text.font_size || 14) / 600 * lines.length : (text.font_size || 5) * lines.length;
  sprite.scale.set(height * canvas.width / canvas.height, height, 1);
  sprite.center.set(0, 0);
  sprite.renderOrder = 10;
  sprite.userData.text = String(text.text);
  applyPose(sprite, text.pose);
  return sprite;
}

function applyPose(object, pose) {
  if (!pose) return;
  if (pose.position) object.position.set(pose.position.x || 0, pose.position.y || 0, pose.position.z || 0);
  const o = pose.orientation;
  if (o) object.quaternion.set(o.x || 0, o.y || 0, o.z || 0, o.w === undefined ? 1 : o.w);
}

// Shared materials (CatheterView.material) are never disposed: three.js frees a shader program when
// its last material goes, and compiling it again takes seconds in a software renderer (SwiftShader),
// seconds in which the page handles no stream message. Entities that change with every message
// (tip frame, contact markers) would otherwise recompile their programs at the stream's rate.
function disposeTree(object) {
  object.traverse((child) => {
    child.geometry?.dispose();
    if (child.material) {
      [].concat(child.material).forEach((m) => {
        if (m.userData.shared) return;
        m.map?.dispose();  // a text sprite's canvas texture
        m.dispose();
      });
    }
  });
}

// Name of the WebGL renderer ("" when unknown), from a throwaway context.
function probeRenderer() {
  try {
    const gl = document.createElement('canvas').getContext('webgl2') || document.createElement('canvas').getContext('webgl');
    if (!gl) return '';
    const info = gl.getExtension('WEBGL_debug_renderer_info');
    const name = String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER));
    gl.getExtension('WEBGL_lose_context')?.loseContext();
    return name;
  } catch {
    return '';
  }
}

export class CatheterView {
  constructor(container) {
    this.container = container;
    this.available = false;
    this.dirty = true;
    // Server time (ms) of the data in the scene graph, set by the page, and of the data on the canvas:
    // a render may wait (below), and until it runs the canvas shows the older state.
    this.contentStampMs = NaN;
    this.shownStampMs = NaN;
    this.hasFitted = false;
    this.entities = new Map();  // SceneUpdate entity id -> Object3D
    this.entityKeys = new Map();  // entity id -> content key of what is drawn
    this.lastBackbone = null;
    this.tipFromScene = false;
    this.materials = new Map();  // shared materials by kind and parameters (see disposeTree)
    this.frames = new Map();  // /tf: child frame -> {parent, matrix (parent <- child)}
    this.fixedFrame = null;  // null: objects drawn in the coordinates they come in (see setFrameTransforms)
    this.clouds = new Map();  // point clouds by key (setPointCloud)
    // Without a GPU (software rasteriser) draw cheaper: no multisampling, 1:1 pixels, fewer frames,
    // so the browser does not starve the server on the same small machine.
    this.software = /swiftshader|llvmpipe|software/i.test(probeRenderer());
    try {
      this.renderer = new THREE.WebGLRenderer({antialias: !this.software, preserveDrawingBuffer: true});
    } catch (err) {
      this.showMessage(`3D view unavailable: WebGL could not start (${err.message}). Joint control still works.`);
      return;
    }
    this.available = true;
    THREE.Object3D.DEFAULT_UP.set(0, 0, 1);
    this.renderer.setPixelRatio(this.software ? 1 : Math.min(window.devicePixelRatio || 1, 2));
    this.renderer.setClearColor(0x0b0f14);
    this.renderer.domElement.setAttribute('data-testid', 'scene-canvas');
    this.renderer.domElement.setAttribute('aria-label', '3D view of the catheter backbone and tip frame');
    this.renderer.domElement.setAttribute('role', 'img');
    container.appendChild(this.renderer.domElement);

    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(40, 1, 0.5, 5000);
    this.camera.up.set(0, 0, 1);
    this.camera.position.set(160, -200, 140);

    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.target.set(0, 0, 40);
    this.controls.enableDamping = false;
    this.controls.addEventListener('change', () => this.requestRender());
    // Once the operator has placed the camera, the view no longer re-frames itself.
    this.controls.addEventListener('start', () => { this.userCamera = true; });
    this.userCamera = false;
    this.fittedBox = null;

    this.scene.add(new THREE.HemisphereLight(0xdde8ff, 0x202830, 1.6));
    const sun = new THREE.DirectionalLight(0xffffff, 1.8);
    sun.position.set(100, -150, 250);
    this.scene.add(sun);

    const grid = new THREE.GridHelper(GRID_SIZE_MM, GRID_SIZE_MM / GRID_STEP_MM, 0x3d4b5c, 0x222b36);
    grid.rotation.x = Math.PI / 2;  // GridHelper lies in XZ; the floor here is XY (Z up)
    this.scene.add(grid);
    this.worldAxes = new THREE.AxesHelper(20);
    this.worldAxes.material.depthTest = false;
    this.scene.add(this.worldAxes);

    this.backboneGroup = new THREE.Group();
    this.scene.add(this.backboneGroup);
    this.backboneMaterial = new THREE.MeshStandardMaterial({color: 0xe3b341, roughness: 0.45, metalness: 0.2});

    this.tipAxes = new THREE.AxesHelper(12);
    this.tipAxes.material.linewidth = 2;
    this.tipAxes.visible = false;
    this.scene.add(this.tipAxes);
    this.tipMarker = new THREE.Mesh(new THREE.SphereGeometry(1.6, 20, 14),
                                    new THREE.MeshStandardMaterial({color: 0xffffff, emissive: 0x333333}));
    this.tipMarker.visible = false;
    this.scene.add(this.tipMarker);

    // A new drawing buffer costs tens of milliseconds to seconds in a software renderer: resize once the
    // panel's size has settled (meanwhile the canvas is stretched by CSS), never at every layout change.
    this.resizeObserver = new ResizeObserver(() => {
      clearTimeout(this.resizeTimer);
      this.resizeTimer = setTimeout(() => this.resize(), this.available && this.sized ? 300 : 0);
    });
    this.resizeObserver.observe(container);
    this.resize();
    // At most ~30 frames a second (10 in software), and none while nothing changes. A render's real
    // cost includes the GPU process (all of it with a software renderer, where a frame with the 3D
    // view took ~250 ms on two loaded cores) and shows as a long frame. After a frame longer than
    // SLOW_FRAME_MS the next render waits three times that frame, so the 3D view has at most about a
    // quarter of the page's time and the joint values and their ages stay current (issue 12: a page
    // that renders the 3D view at any cost shows STALE data much of the time). A GPU's frames are
    // shorter than the bound and keep the plain rate.
    const SLOW_FRAME_MS = 50;
    // Shedding (setShedding: the page's frames are slow): at most ~3 frames a second.
    const baseFrameMs = () => (this.shedding ? 300 : this.software ? 100 : 30);
    let minFrameMs = baseFrameMs();
    let lastFrame = 0;
    let previous = 0;
    let rendered = false;
    const loop = (now) => {
      if (rendered) {
        const frameMs = now - previous;
        // A slow render waits 3 times its cost before the next one (6 times, up to 2 s, while shedding).
        minFrameMs = frameMs > SLOW_FRAME_MS
          ? (this.shedding ? Math.min(2000, Math.max(baseFrameMs(), 6 * frameMs)) : Math.min(1000, Math.max(baseFrameMs(), 3 * frameMs)))
          : baseFrameMs();
      } else if (minFrameMs < baseFrameMs()) {
        minFrameMs = baseFrameMs();
      }
      rendered = false;
      previous = now;
      if (this.dirty && now - lastFrame >= minFrameMs) {
        lastFrame = now;
        this.dirty = false;
        this.renderer.render(this.scene, this.camera);
        this.shownStampMs = this.contentStampMs;
        rendered = true;
      }
      requestAnimationFrame(loop);
    };
    requestAnimationFrame(loop);
  }

  showMessage(text) {
    const div = document.createElement('div');
    div.className = 'scene-message';
    div.textContent = text;
    this.container.appendChild(div);
  }

  requestRender() { this.dirty = true; }

  // The page is behind (app.js): render the 3D view at most ~3 times a second until it catches up.
  setShedding(on) { this.shedding = !!on; }

  // Server time of what the canvas shows: the scene graph's when nothing waits to be drawn, else the
  // last drawn one's (NaN before the first frame or without WebGL).
  shownAtMs() {
    if (!this.available) return NaN;
    return this.dirty ? this.shownStampMs : this.contentStampMs;
  }

  resize() {
    const w = Math.max(1, this.container.clientWidth);
    const h = Math.max(1, this.container.clientHeight);
    if (this.sized && this.sized.w === w && this.sized.h === h) return;
    this.sized = {w, h};
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.requestRender();
  }

  // Backbone polyline in mm, [[x,y,z],...] or [{x,y,z},...].
  setBackbone(points) {
    if (!this.available || !points || points.length < 2) return;
    const vecs = points.map(toVec);
    // Skip rebuilding the tube when nothing moved (at rest the stream repeats the same shape).
    const key = vecs.map((v) => `${v.x.toFixed(2)},${v.y.toFixed(2)},${v.z.toFixed(2)}`).join(';');
    if (key === this.lastBackbone) return;
    this.lastBackbone = key;
    this.backboneGroup.children.forEach((c) => c.geometry.dispose());
    this.backboneGroup.clear();
    // Consecutive duplicate points would give the tube a zero-length tangent.
    const clean = vecs.filter((v, i) => i === 0 || v.distanceToSquared(vecs[i - 1]) > 1e-8);
    if (clean.length >= 2) {
      const path = new THREE.CatmullRomCurve3(clean, false, 'centripetal');
      const tube = new THREE.TubeGeometry(path, Math.max(16, clean.length * 4), BACKBONE_RADIUS_MM, 10, false);
      this.backboneGroup.add(new THREE.Mesh(tube, this.backboneMaterial));
    }
    const tip = clean[clean.length - 1];
    this.tipMarker.position.copy(tip);
    this.tipMarker.visible = true;
    if (!this.tipFromCp && clean.length >= 2) {
      // Without a measured tip pose, align the tip frame's z with the backbone tangent.
      const tangent = tip.clone().sub(clean[clean.length - 2]).normalize();
      this.tipAxes.position.copy(tip);
      this.tipAxes.quaternion.setFromUnitVectors(new THREE.Vector3(0, 0, 1), tangent);
      this.tipAxes.visible = !this.tipFromScene;
    }
    // Re-frame when the catheter grows out of the framed region (unless the operator moved the camera).
    const shapeBox = new THREE.Box3().setFromPoints(clean);
    if (!this.hasFitted ||
        (!this.userCamera && !this.focus && this.fittedBox && !this.fittedBox.containsBox(shapeBox))) this.fit(false);
    this.requestRender();
  }

  // Measured tip pose (mm, quaternion [qx,qy,qz,qw]) from GET measured_cp.
  setTipPose(position, orientation) {
    if (!this.available || !position) return;
    this.tipFromCp = true;
    this.tipAxes.position.set(position[0], position[1], position[2]);
    if (orientation && orientation.length === 4) {
      this.tipAxes.quaternion.set(orientation[0], orientation[1], orientation[2], orientation[3]).normalize();
    }
    this.tipAxes.visible = !this.tipFromScene;
    this.requestRender();
  }

  // foxglove.SceneUpdate (JSON). The entity "backbone" (or any entity whose first line is the
  // backbone) becomes the tube; other primitives (e.g. the tip frame's arrows) are drawn as they come.
  applySceneUpdate(update) {
    if (!this.available || !update) return;
    for (const del of update.deletions || []) {
      if (del.type === 1) {
        for (const id of [...this.entities.keys()]) this.removeEntity(id);
        this.entityKeys.clear();
      } else {
        this.removeEntity(del.id);
        this.entityKeys.delete(del.id);
      }
    }
    for (const entity of update.entities || []) {
      // tendril names it "<robot>/backbone"; plain "backbone" is accepted too.
      if (/(^|\/)backbone$/.test(entity.id || '') && entity.lines && entity.lines.length) {
        this.setBackbone(entity.lines[0].points);
        const rest = {...entity, lines: entity.lines.slice(1)};
        this.setEntity(`${entity.id}#extra`, rest);
      } else {
        if (/tip/.test(entity.id || '')) this.tipFromScene = true;
        this.setEntity(entity.id, entity);
      }
    }
    if (this.tipFromScene) this.tipAxes.visible = false;
    // setBackbone and setEntity ask for a frame when they changed something; an update that repeats
    // the scene (the stream sends one with every new time stamp) draws nothing.
  }

  removeEntity(id) {
    const obj = this.entities.get(id);
    if (!obj) return;
    this.scene.remove(obj);
    disposeTree(obj);
    this.entities.delete(id);
    this.entityKeys.delete(id);
    this.requestRender();
  }

  // One material per kind, colour and opacity for the whole view.
  material(kind, color, opacity = 1, extra = {}) {
    const c = color instanceof THREE.Color ? color : new THREE.Color(color);
    const key = `${kind}|${c.getHexString()}|${opacity}|${JSON.stringify(extra)}`;
    let m = this.materials.get(key);
    if (!m) {
      m = new THREE[kind]({color: c, transparent: opacity < 1, opacity, ...extra});
      m.userData.shared = true;
      this.materials.set(key, m);
    }
    return m;
  }

  setEntity(id, entity) {
    // The stream repeats unchanged entities with new timestamps; rebuild only what changed.
    const key = JSON.stringify([entity.frame_id, entity.lines, entity.arrows, entity.spheres, entity.cubes,
                                entity.cylinders, entity.triangles, entity.texts]);
    if (this.entityKeys.get(id) === key) return;
    this.entityKeys.set(id, key);
    this.removeEntity(id);
    this.requestRender();
    const group = new THREE.Group();
    for (const line of entity.lines || []) {
      const pts = (line.points || []).map(toVec);
      if (pts.length < 2) continue;
      const geometry = new THREE.BufferGeometry().setFromPoints(pts);
      // Per-point colours (e.g. a strip coloured by curvature) when given for every point.
      const perPoint = Array.isArray(line.colors) && line.colors.length === pts.length;
      if (perPoint) geometry.setAttribute('color', colorAttribute(line.colors));
      const material = perPoint ? this.material('LineBasicMaterial', 0xffffff, 1, {vertexColors: true})
                                : this.material('LineBasicMaterial', colorOf(line.color), line.color?.a ?? 1);
      // type 0 line strip, 1 line loop, 2 line list
      const obj = line.type === 2 ? new THREE.LineSegments(geometry, material)
                : line.type === 1 ? new THREE.LineLoop(geometry, material)
                : new THREE.Line(geometry, material);
      applyPose(obj, line.pose);
      group.add(obj);
    }
    for (const arrow of entity.arrows || []) {
      // Arrows shorter than MIN_ARROW_MM (e.g. a tip frame sized for the 0.88 mm catheter) are drawn
      // scaled up so they stay readable at the usual zoom; direction and origin are unchanged.
      const given = (arrow.shaft_length || 0) + (arrow.head_length || 0) || MIN_ARROW_MM;
      const k = Math.max(1, MIN_ARROW_MM / given);
      const length = given * k;
      const helper = new THREE.ArrowHelper(new THREE.Vector3(1, 0, 0), new THREE.Vector3(), length,
                                           colorOf(arrow.color), (arrow.head_length || given * 0.25) * k,
                                           (arrow.head_diameter || given * 0.15) * k);
      // ArrowHelper makes its own materials; the shared ones keep the programs alive.
      helper.line.material.dispose();
      helper.cone.material.dispose();
      helper.line.material = this.material('LineBasicMaterial', colorOf(arrow.color), 1, {toneMapped: false});
      helper.cone.material = this.material('MeshBasicMaterial', colorOf(arrow.color), 1, {toneMapped: false});
      applyPose(helper, arrow.pose);
      group.add(helper);
    }
    const spheres = entity.spheres || [];
    if (spheres.length > MAX_SPHERE_MESHES) {
      // Many small spheres (a sampled surface) as one point set: thousands of meshes would take seconds
      // per frame in a software renderer. Drawn at the spheres' mean diameter.
      group.add(pointsObject(spheres.map((sp) => sp.pose?.position || {x: 0, y: 0, z: 0}),
                             spheres.map((sp) => sp.color), meanSize(spheres)));
    }
    for (const sphere of spheres.length > MAX_SPHERE_MESHES ? [] : spheres) {
      const s = sphere.size || {x: 1, y: 1, z: 1};
      const mesh = new THREE.Mesh(new THREE.SphereGeometry(0.5, 20, 14),
                                  this.material(this.software ? 'MeshLambertMaterial' : 'MeshStandardMaterial',
                                                colorOf(sphere.color), sphere.color?.a ?? 1));
      mesh.scale.set(s.x, s.y, s.z);
      applyPose(mesh, sphere.pose);
      group.add(mesh);
    }
    for (const cube of entity.cubes || []) {
      const s = cube.size || {x: 1, y: 1, z: 1};
      const mesh = new THREE.Mesh(new THREE.BoxGeometry(s.x, s.y, s.z),
                                  this.material(this.software ? 'MeshLambertMaterial' : 'MeshStandardMaterial',
                                                colorOf(cube.color), cube.color?.a ?? 1));
      applyPose(mesh, cube.pose);
      group.add(mesh);
    }
    for (const cyl of entity.cylinders || []) {
      const s = cyl.size || {x: 1, y: 1, z: 1};
      // Foxglove's cylinder stands on z; three.js's on y.
      const geometry = new THREE.CylinderGeometry((cyl.top_scale ?? 1) * 0.5, (cyl.bottom_scale ?? 1) * 0.5, 1, 24);
      geometry.rotateX(Math.PI / 2);
      const mesh = new THREE.Mesh(geometry, this.material(this.software ? 'MeshLambertMaterial' : 'MeshStandardMaterial',
                                                          colorOf(cyl.color), cyl.color?.a ?? 1));
      mesh.scale.set(s.x, s.y, s.z);
      applyPose(mesh, cyl.pose);
      group.add(mesh);
    }
    for (const tri of entity.triangles || []) {
      const mesh = this.triangleMesh(tri);
      if (mesh) group.add(mesh);
    }
    for (const text of entity.texts || []) {
      if (text.text) group.add(textSprite(text));
    }
    if (group.children.length === 0) return;
    this.entities.set(id, group);
    this.placeInFrame(group, entity.frame_id);
    this.scene.add(group);
  }

  // foxglove.TriangleListPrimitive: points taken three at a time, or through indices; one colour or
  // one per point. Both faces are drawn (a mesh from slices has no consistent winding).
  triangleMesh(tri) {
    const pts = (tri.points || []).map(toVec);
    if (pts.length < 3) return null;
    const geometry = new THREE.BufferGeometry().setFromPoints(pts);
    if (Array.isArray(tri.indices) && tri.indices.length >= 3) {
      if (tri.indices.some((i) => !(i >= 0 && i < pts.length))) return null;  // a broken mesh is not drawn
      geometry.setIndex(tri.indices.slice(0, tri.indices.length - (tri.indices.length % 3)));
    } else if (pts.length % 3) {
      return null;
    }
    geometry.computeVertexNormals();
    const perPoint = Array.isArray(tri.colors) && tri.colors.length === pts.length;
    if (perPoint) geometry.setAttribute('color', colorAttribute(tri.colors));
    const opacity = tri.color?.a ?? 1;
    const material = new THREE.MeshLambertMaterial({
      color: perPoint ? 0xffffff : colorOf(tri.color), vertexColors: perPoint, side: THREE.DoubleSide,
      transparent: opacity < 1, opacity, depthWrite: opacity >= 1});
    const mesh = new THREE.Mesh(geometry, material);
    applyPose(mesh, tri.pose);
    return mesh;
  }

  // ---- frames (foxglove.FrameTransforms on /tf)
  // The view draws everything in one fixed frame. By default (no fixed frame) objects are drawn in the
  // coordinates they come in, as before /tf existed. With a fixed frame set (e.g. "tissue", the frame
  // that moves with the limb) every object whose frame_id is known through /tf is drawn at
  // fixed <- frame, so the camera stays with that frame: the limb stands still on screen and the arm
  // moves about it. An object whose frame cannot be reached from the fixed frame is hidden rather than
  // drawn at a wrong place.
  setFrameTransforms(msg) {
    if (!msg || !Array.isArray(msg.transforms)) return;
    let changed = false;
    for (const t of msg.transforms) {
      if (!t.child_frame_id || !t.parent_frame_id || t.child_frame_id === t.parent_frame_id) continue;
      const p = t.translation || {};
      const r = t.rotation || {};
      const q = new THREE.Quaternion(r.x || 0, r.y || 0, r.z || 0, r.w === undefined ? 1 : r.w);
      if (![p.x || 0, p.y || 0, p.z || 0, q.x, q.y, q.z, q.w].every(Number.isFinite) || q.lengthSq() < 1e-12) continue;
      const m = new THREE.Matrix4().compose(new THREE.Vector3(p.x || 0, p.y || 0, p.z || 0), q.normalize(),
                                            new THREE.Vector3(1, 1, 1));
      const old = this.frames.get(t.child_frame_id);
      if (old && old.parent === t.parent_frame_id && old.matrix.equals(m)) continue;
      this.frames.set(t.child_frame_id, {parent: t.parent_frame_id, matrix: m});
      changed = true;
    }
    if (changed) this.placeAll();
  }

  setFixedFrame(name) {
    const next = name || null;
    if (next === this.fixedFrame) return;
    this.fixedFrame = next;
    this.placeAll();
  }

  // root <- frame as {root, matrix}; null for a cycle.
  chainToRoot(frame) {
    const matrix = new THREE.Matrix4();
    let f = frame;
    for (let depth = 0; depth < 64; depth++) {
      const link = this.frames.get(f);
      if (!link) return {root: f, matrix};
      matrix.premultiply(link.matrix);
      f = link.parent;
    }
    return null;
  }

  // fixed <- frame, or null when /tf does not connect them (yet).
  fixedFromFrame(frame) {
    if (!this.fixedFrame || !frame || frame === this.fixedFrame) return new THREE.Matrix4();
    const a = this.chainToRoot(frame);
    const b = this.chainToRoot(this.fixedFrame);
    if (!a || !b || a.root !== b.root) return null;
    return b.matrix.clone().invert().multiply(a.matrix);
  }

  placeInFrame(object, frame) {
    object.userData.frameId = frame || '';
    object.matrixAutoUpdate = false;
    const m = this.fixedFromFrame(frame);
    object.visible = m !== null;
    if (m) object.matrix.copy(m);
    object.matrixWorldNeedsUpdate = true;
  }

  placeAll() {
    for (const obj of this.entities.values()) this.placeInFrame(obj, obj.userData.frameId);
    for (const group of this.clouds.values()) this.placeInFrame(group, group.userData.frameId);
    this.requestRender();
  }

  // Where a frame is in the fixed frame (for tests and read-outs): [x, y, z] or null.
  frameOrigin(frame) {
    const m = this.fixedFromFrame(frame);
    if (!m) return null;
    const v = new THREE.Vector3().setFromMatrixPosition(m);
    return [v.x, v.y, v.z];
  }

  // Vessel centreline of the selected branch (mm) and, when radii are known, its wall as a
  // translucent tube; null removes it.
  // entry: the robot's vessel_entry (the insertion frame's pose in the robot's frame); asLoaded: the
  // points are in the vessel file's own frame (else in the insertion frame, as a plan's vessel path).
  setVessel(points, radius, {entry = null, asLoaded = false} = {}) {
    if (!this.available) return;
    this.clearGroup('vesselGroup');
    if (!points || points.length < 2) return;
    const group = this.ensureGroup('vesselGroup');
    placeEntry(group, entry);
    const vecs = asLoaded && entry ? toInsertionFrame(points.map(toVec)) : points.map(toVec);
    group.add(new THREE.Line(new THREE.BufferGeometry().setFromPoints(vecs),
                             new THREE.LineBasicMaterial({color: 0xd2555a})));
    const r = Array.isArray(radius) && radius.length ? radius.reduce((a, b) => a + b, 0) / radius.length : 0;
    if (r > 0) {
      const clean = vecs.filter((v, i) => i === 0 || v.distanceToSquared(vecs[i - 1]) > 1e-8);
      if (clean.length >= 2) {
        // Mean radius: the wall is a guide for the eye; the planner uses the real radii.
        const tube = new THREE.TubeGeometry(new THREE.CatmullRomCurve3(clean, false, 'centripetal'),
                                            Math.min(2000, clean.length * 2), r, 16, false);
        group.add(new THREE.Mesh(tube, new THREE.MeshStandardMaterial({
          color: 0xd2555a, transparent: true, opacity: 0.16, depthWrite: false, side: THREE.DoubleSide})));
      }
    }
    this.fitTo(group);
  }

  // Planned backbones, one per insertion step; the current step is drawn bright, the others faint.
  setPlan(backbones, {entry = null} = {}) {
    if (!this.available) return;
    this.clearGroup('planGroup');
    this.planLines = [];
    if (!backbones || !backbones.length) return;
    const group = this.ensureGroup('planGroup');
    placeEntry(group, entry);
    for (const points of backbones) {
      if (!Array.isArray(points) || points.length < 2) {
        this.planLines.push(null);
        continue;
      }
      const line = new THREE.Line(new THREE.BufferGeometry().setFromPoints(points.map(toVec)),
                                  new THREE.LineBasicMaterial({color: 0x39c5cf, transparent: true, opacity: 0.28}));
      this.planLines.push(line);
      group.add(line);
    }
    this.planStep = -1;
    this.requestRender();
  }

  setPlanStep(step) {
    if (!this.available || !this.planLines || step === this.planStep) return;
    this.planStep = step;
    this.planLines.forEach((line, i) => {
      if (!line) return;
      line.material.opacity = i === step ? 1 : 0.28;
      line.material.color.set(i === step ? 0x7ee8f0 : 0x39c5cf);
    });
    this.requestRender();
  }

  // foxglove.PointCloud (JSON, base64 data): the float32 (or float64) x, y, z fields become points,
  // coloured by the rgba fields when the cloud has them (uint8, NumericType 1). One cloud per key (the
  // core's /maps/vessel is "map"; a plug-in's map has its own), each in its message's frame_id.
  // Returns the number of points drawn (0 for an empty cloud), or -1 when the message is not a cloud.
  setPointCloud(msg, key = 'map', color = 0xb07aa1) {
    if (!this.available || !msg || typeof msg.data !== 'string') return -1;
    const fields = Object.fromEntries((msg.fields || []).map((f) => [f.name, f]));
    const stride = Number(msg.point_stride);
    if (!fields.x || !fields.y || !fields.z || !(stride > 0)) return -1;
    const cloudKey = `${msg.frame_id}:${msg.data.length}:${msg.data.slice(0, 64)}:${msg.data.slice(-64)}`;
    const known = this.clouds.get(key);
    if (known && known.userData.cloudKey === cloudKey) return known.userData.count;  // republished unchanged
    let bytes;
    try {
      bytes = Uint8Array.from(atob(msg.data), (c) => c.charCodeAt(0));
    } catch {
      return -1;  // not base64
    }
    const view = new DataView(bytes.buffer);
    const n = Math.floor(bytes.length / stride);
    const sizes = {1: 1, 2: 1, 3: 2, 4: 2, 5: 4, 6: 4, 7: 4, 8: 8};
    const fits = (f) => f && f.offset >= 0 && f.offset + (sizes[f.type] || 4) <= stride;
    if (![fields.x, fields.y, fields.z].every(fits)) return -1;
    const positions = new Float32Array(n * 3);
    // foxglove NumericType 7 = FLOAT32, 8 = FLOAT64
    const read = (f, at) => (f.type === 8 ? view.getFloat64(at + f.offset, true) : view.getFloat32(at + f.offset, true));
    let kept = 0;
    for (let i = 0; i < n; i++) {
      const x = read(fields.x, i * stride);
      const y = read(fields.y, i * stride);
      const z = read(fields.z, i * stride);
      if (!Number.isFinite(x) || !Number.isFinite(y) || !Number.isFinite(z)) continue;  // never a point at NaN
      positions.set([x, y, z], kept * 3);
      kept++;
    }
    const group = this.cloudGroup(key);
    for (const child of [...group.children]) {
      disposeTree(child);
      group.remove(child);
    }
    group.userData.cloudKey = cloudKey;
    group.userData.count = kept;
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(positions.subarray(0, kept * 3), 3));
    const points = new THREE.Points(geometry, new THREE.PointsMaterial({color, size: 1.2, sizeAttenuation: true}));
    applyPose(points, msg.pose);
    group.add(points);
    this.placeInFrame(group, msg.frame_id);
    this.requestRender();
    return kept;
  }

  cloudGroup(key) {
    let group = this.clouds.get(key);
    if (!group) {
      group = new THREE.Group();
      group.name = `cloud:${key}`;
      this.clouds.set(key, group);
      this.scene.add(group);
    }
    return group;
  }

  removePointCloud(key) {
    const group = this.clouds.get(key);
    if (!group) return;
    disposeTree(group);
    this.scene.remove(group);
    this.clouds.delete(key);
    this.requestRender();
  }

  // Entities whose id starts with `prefix` (a panel's own, when the robot changes).
  removeEntities(prefix) {
    for (const id of [...this.entities.keys()]) if (id.startsWith(prefix)) this.removeEntity(id);
  }

  // The tip as the bi-plane images see it (world mm, tendril.TipTracking's tip_mm), drawn as a magenta
  // wire sphere (the colour of the tracked tip's ring on the images) larger than the model's white tip marker, so that both stay visible where they agree
  // (within a millimetre, usually); null hides it (tracking off or nothing tracked).
  setTrackedTip(position) {
    if (!this.available) return;
    if (!this.trackedTip) {
      this.trackedTip = new THREE.Mesh(new THREE.SphereGeometry(3, 14, 10),
                                       new THREE.MeshBasicMaterial({color: 0xff6ad5, wireframe: true}));
      this.trackedTip.name = 'tracked-tip';
      this.scene.add(this.trackedTip);
    }
    const shown = Array.isArray(position) && position.length === 3 && position.every(Number.isFinite);
    if (shown) this.trackedTip.position.set(position[0], position[1], position[2]);
    if (shown || this.trackedTip.visible) this.requestRender();
    this.trackedTip.visible = shown;
  }

  ensureGroup(name) {
    if (!this[name]) {
      this[name] = new THREE.Group();
      this.scene.add(this[name]);
    }
    return this[name];
  }

  clearGroup(name) {
    const group = this[name];
    if (!group) return;
    for (const child of [...group.children]) {
      disposeTree(child);
      group.remove(child);
    }
    this.requestRender();
  }

  // Frame the camera on one object (e.g. a newly loaded vessel), with the grid origin unless withOrigin
  // is false.
  fitTo(object, {withOrigin = true} = {}) {
    const box = new THREE.Box3().setFromObject(object);
    if (box.isEmpty()) return;
    if (withOrigin) box.expandByPoint(new THREE.Vector3(0, 0, 0));
    this.frameBox(box);
  }

  // Keep the camera on `object` (a panel's subject, e.g. an ultrasound arm's reconstruction half a metre
  // from the arm's base) instead of re-framing on the robot's shape whenever it moves; null gives framing
  // back to the robot. The Fit view button frames the whole robot again and ends the focus.
  setFocus(object) {
    this.focus = object || null;
    if (this.focus && this.available && !this.userCamera) this.fitTo(this.focus, {withOrigin: false});
  }

  // Frame the camera on the backbone (and the grid origin), or on the focus while one is set. The Fit
  // view button (byUser) also hands framing back to the console.
  fit(byUser = true) {
    if (byUser) {
      this.userCamera = false;
      this.focus = null;
    }
    if (!this.available) return;
    if (this.focus) {
      this.fitTo(this.focus, {withOrigin: false});
      return;
    }
    const box = new THREE.Box3().setFromObject(this.backboneGroup);
    if (box.isEmpty()) box.set(new THREE.Vector3(-20, -20, 0), new THREE.Vector3(20, 20, 60));
    box.expandByPoint(new THREE.Vector3(0, 0, 0));
    if (this.vesselGroup && this.vesselGroup.children.length) box.union(new THREE.Box3().setFromObject(this.vesselGroup));
    this.frameBox(box);
  }

  frameBox(box) {
    this.fittedBox = box.clone().expandByScalar(Math.max(5, box.getSize(new THREE.Vector3()).length() * 0.1));
    const center = box.getCenter(new THREE.Vector3());
    const radius = Math.max(30, box.getSize(new THREE.Vector3()).length() / 2);
    const distance = radius / Math.sin(THREE.MathUtils.degToRad(this.camera.fov / 2)) * 1.25;
    const dir = new THREE.Vector3(0.55, -0.75, 0.45).normalize();
    this.camera.position.copy(center).addScaledVector(dir, distance);
    this.controls.target.copy(center);
    this.controls.update();
    this.hasFitted = true;
    this.requestRender();
  }
}
