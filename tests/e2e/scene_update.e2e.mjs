// Browser test of the 3D view's generic pieces the plug-in panels use (web/scene.js): foxglove.PointCloud
// (base64, stride, float32 x y z; a non-finite point is not drawn; several clouds side by side),
// foxglove.SceneUpdate primitives (triangles with indices, texts, cylinders; a broken triangle list is
// not drawn) and frames from foxglove.FrameTransforms (/tf) with a fixed frame: an entity in "world"
// drawn in a view fixed to "tissue" sits at tissue <- world, one in an unknown frame is hidden. Also:
// the catheter (a kind without a panel of its own) shows no Robot tab.
// Env: TENDRIL_URL, TENDRIL_TOKEN (tests/e2e/run.sh starts the server).
import {test, before, after} from 'node:test';
import assert from 'node:assert/strict';
import {WAIT, openBrowser, serverUnderTest} from './browser.mjs';

const {BASE_URL, TOKEN} = serverUnderTest();

let context;
let page;
let closeBrowser;
const pageErrors = [];

before(async () => {
  ({context, page, close: closeBrowser} = await openBrowser('scene'));
  page.on('pageerror', (err) => pageErrors.push(err.message));
  await page.goto(`${BASE_URL}/?token=${encodeURIComponent(TOKEN)}`);
  await page.waitForFunction(() => window.tendrilLive?.view()?.available, null, WAIT);
});

after(async () => {
  await closeBrowser?.();
});

test('the catheter has no kind-specific panel: the Robot tab stays hidden', async () => {
  await page.waitForSelector('[data-testid="joint-row-insertion"]', WAIT);
  assert.equal(await page.locator('[data-testid="tab-robot"]').isHidden(), true);
});

test('point clouds: base64 float32 x y z at the stated stride, non-finite points skipped, one cloud per key', async () => {
  const result = await page.evaluate(() => {
    const view = window.tendrilLive.view();
    // 16-byte stride: x, y, z float32 and 4 bytes of something else.
    const pts = [[1, 2, 3], [4, 5, 6], [NaN, 0, 0], [7, 8, 9]];
    const buf = new ArrayBuffer(pts.length * 16);
    const dv = new DataView(buf);
    pts.forEach((p, i) => p.forEach((v, k) => dv.setFloat32(i * 16 + 4 * k, v, true)));
    const data = btoa(String.fromCharCode(...new Uint8Array(buf)));
    const fields = [{name: 'x', offset: 0, type: 7}, {name: 'y', offset: 4, type: 7}, {name: 'z', offset: 8, type: 7}];
    const cloud = {frame_id: '', point_stride: 16, fields, data};
    const a = view.setPointCloud(cloud, 'test/a');
    const b = view.setPointCloud({...cloud, data: btoa(String.fromCharCode(...new Uint8Array(buf.slice(0, 32))))}, 'test/b');
    const bad = view.setPointCloud({...cloud, fields: [{name: 'x', offset: 14, type: 7}, fields[1], fields[2]]}, 'test/c');
    const positions = [...view.clouds.get('test/a').children[0].geometry.getAttribute('position').array];
    const keys = [...view.clouds.keys()];
    view.removePointCloud('test/a');
    view.removePointCloud('test/b');
    return {a, b, bad, positions, keys, after: [...view.clouds.keys()]};
  });
  assert.equal(result.a, 3, 'the NaN point is not drawn');
  assert.deepEqual(result.positions, [1, 2, 3, 4, 5, 6, 7, 8, 9]);
  assert.equal(result.b, 2);
  assert.equal(result.bad, -1, 'a field beyond the stride is refused');
  assert.ok(result.keys.includes('test/a') && result.keys.includes('test/b'));
  assert.ok(!result.after.includes('test/a') && !result.after.includes('test/b'));
});

test('SceneUpdate triangles, texts and cylinders are drawn; a triangle list with a bad index is not', async () => {
  const result = await page.evaluate(() => {
    const view = window.tendrilLive.view();
    const pose = {position: {x: 0, y: 0, z: 0}, orientation: {x: 0, y: 0, z: 0, w: 1}};
    view.applySceneUpdate({entities: [
      {id: 'test/mesh', frame_id: '', triangles: [{pose, points: [{x: 0, y: 0, z: 0}, {x: 10, y: 0, z: 0}, {x: 0, y: 10, z: 0}, {x: 10, y: 10, z: 0}],
                                                  indices: [0, 1, 2, 1, 3, 2], color: {r: 1, g: 0, b: 0, a: 0.5}}]},
      {id: 'test/text', frame_id: '', texts: [{pose, text: 'bracing: admissible', font_size: 6, color: {r: 0, g: 1, b: 0, a: 1}}]},
      {id: 'test/cyl', frame_id: '', cylinders: [{pose, size: {x: 20, y: 20, z: 80}, color: {r: 1, g: 0.8, b: 0.6, a: 1}}]},
      {id: 'test/broken', frame_id: '', triangles: [{pose, points: [{x: 0, y: 0, z: 0}, {x: 1, y: 0, z: 0}, {x: 0, y: 1, z: 0}], indices: [0, 1, 7]}]},
    ]});
    const mesh = view.entities.get('test/mesh').children[0];
    const sprite = view.entities.get('test/text').children[0];
    const cyl = view.entities.get('test/cyl').children[0];
    const out = {
      meshTriangles: mesh.geometry.index.count / 3, meshOpacity: mesh.material.opacity,
      spriteType: sprite.type, spriteText: sprite.userData.text, cylScale: [cyl.scale.x, cyl.scale.y, cyl.scale.z],
      broken: view.entities.has('test/broken'),
    };
    view.removeEntities('test/');
    out.left = [...view.entities.keys()].filter((k) => k.startsWith('test/'));
    return out;
  });
  assert.equal(result.meshTriangles, 2);
  assert.equal(result.meshOpacity, 0.5);
  assert.equal(result.spriteType, 'Sprite');
  assert.equal(result.spriteText, 'bracing: admissible');
  assert.deepEqual(result.cylScale, [20, 20, 80]);
  assert.equal(result.broken, false, 'a triangle index beyond the points draws nothing');
  assert.deepEqual(result.left, []);
});

test('frames from /tf: a view fixed to "tissue" draws a world entity at tissue <- world, an unknown frame hidden', async () => {
  const result = await page.evaluate(() => {
    const view = window.tendrilLive.view();
    const pose = {position: {x: 0, y: 0, z: 0}, orientation: {x: 0, y: 0, z: 0, w: 1}};
    const sphere = {pose, size: {x: 2, y: 2, z: 2}, color: {r: 1, g: 1, b: 1, a: 1}};
    view.applySceneUpdate({entities: [
      {id: 'test/in-world', frame_id: 'world', spheres: [sphere]},
      {id: 'test/in-tissue', frame_id: 'tissue', spheres: [sphere]},
      {id: 'test/in-nowhere', frame_id: 'no_such_frame', spheres: [sphere]},
    ]});
    const at = (id) => {
      const o = view.entities.get(id);
      o.updateMatrixWorld(true);
      const e = o.matrixWorld.elements;
      return {visible: o.visible, p: [e[12], e[13], e[14]].map((v) => Math.round(v * 1000) / 1000)};
    };
    // world -> tissue: 10 mm along x and a quarter turn about z (the limb has moved and turned).
    const s = Math.SQRT1_2;
    view.setFrameTransforms({transforms: [{parent_frame_id: 'world', child_frame_id: 'tissue',
                                           translation: {x: 10, y: 0, z: 0}, rotation: {x: 0, y: 0, z: s, w: s}}]});
    view.setFixedFrame('tissue');
    const fixedTissue = {world: at('test/in-world'), tissue: at('test/in-tissue'), nowhere: at('test/in-nowhere'),
                         worldOrigin: view.frameOrigin('world').map((v) => Math.round(v * 1000) / 1000)};
    // The limb moves 5 mm in y: the world origin moves in the tissue-fixed view, the tissue does not.
    view.setFrameTransforms({transforms: [{parent_frame_id: 'world', child_frame_id: 'tissue',
                                           translation: {x: 10, y: 5, z: 0}, rotation: {x: 0, y: 0, z: s, w: s}}]});
    const moved = {world: at('test/in-world'), tissue: at('test/in-tissue')};
    view.setFixedFrame('world');
    const fixedWorld = {world: at('test/in-world'), tissue: at('test/in-tissue')};
    view.setFixedFrame(null);
    view.removeEntities('test/');
    return {fixedTissue, moved, fixedWorld};
  });
  // tissue <- world = inverse(translate(10,0,0) * rotz(90°)): the world origin at (0, 10, 0) in tissue.
  assert.deepEqual(result.fixedTissue.world, {visible: true, p: [0, 10, 0]});
  assert.deepEqual(result.fixedTissue.tissue, {visible: true, p: [0, 0, 0]});
  assert.equal(result.fixedTissue.nowhere.visible, false, 'an object whose frame /tf does not give is hidden');
  assert.deepEqual(result.fixedTissue.worldOrigin, [0, 10, 0]);
  assert.deepEqual(result.moved.tissue.p, [0, 0, 0], 'the tissue stands still in its own view');
  assert.deepEqual(result.moved.world.p, [-5, 10, 0]);
  assert.deepEqual(result.fixedWorld.tissue.p, [10, 5, 0]);
  assert.deepEqual(result.fixedWorld.world.p, [0, 0, 0]);
  assert.deepEqual(pageErrors, []);
});
