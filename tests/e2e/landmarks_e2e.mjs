// Landmark exaggeration in a real CesiumJS client: the citylod viewer page in headless Chromium (SwiftShader
// WebGL 2), offline, driven by playwright-core; the viewer's "Exaggerate landmarks" toggle (window.citylod.
// setExaggeration) switched off, on and off again for one camera.
//
//   node tests/e2e/landmarks_e2e.mjs --url http://127.0.0.1:8765/ --out-dir build/test/landmarks \
//        --landmark '{"osmId":"123","lon":24.93,"lat":60.16,"ground":0}' \
//        --camera '{"heading":90,"pitch":-30,"range":2500,"fov":20}' --pick-height 110 \
//        [--neighbour '{"osmId":"456","from":{"lon":..,"lat":..,"height":..},"to":{...}}'] [--max-sse 1]
//
// The camera looks at the landmark's footprint centre at ground level (lon, lat, ground: metres above the
// ellipsoid) from `range` metres, heading, pitch and (horizontal) field of view in degrees, on an 800×500 canvas;
// --max-sse sets the tileset's maximumScreenSpaceError. Measures, on the canvas pixels (not the page, whose panel
// covers part of it):
// * scene: the whole view with the panel's checkbox off, on, and off again (off.png, on.png, off_again.png): how
//   many pixels differ between them;
// * pick: what scene.pick hits at the point halfway between the unscaled and the scaled roof (pickHeight metres
//   above the centre, the caller's), toggle off and on;
// * landmark: the globe hidden and every feature but the landmark's (building_osm_id) hidden: the bounding box and
//   pixel count of what differs from the background, off and on (landmark_off.png, landmark_on.png);
// * neighbour: the same for one building the landmark pushes away, plus where the points `from` and `to` (its
//   centre before and after the expected push) project on the canvas (neighbour_off.png, neighbour_on.png).
// Prints one JSON line {camera, distance, scene, pick, landmark, neighbour, warnings, hosts, consoleErrors, ...}.
// Exits 0 when every step ran (the caller judges the numbers); 1 with a message on stderr otherwise.
import fs from 'node:fs';
import path from 'node:path';
import { parseArgs } from 'node:util';
import { startDriver } from './browser.mjs';

const { values: opt } = parseArgs({
  options: {
    url: { type: 'string' },
    'out-dir': { type: 'string' },
    landmark: { type: 'string' },
    camera: { type: 'string' },
    neighbour: { type: 'string' },
    'pick-height': { type: 'string' },
    'max-sse': { type: 'string', default: '16' },
    chromium: { type: 'string', default: process.env.CHROMIUM || '/usr/bin/chromium' },
    timeout: { type: 'string', default: '90000' }, // ms per wait; SwiftShader is slow
  },
});
const { note, timeout, WAIT, open, finish } = startDriver('landmarks_e2e', opt,
  ['url', 'out-dir', 'landmark', 'camera', 'pick-height'],
  '--url URL --out-dir DIR --landmark JSON --camera JSON --pick-height M [--neighbour JSON] [--max-sse N]');
const landmark = JSON.parse(opt.landmark);
const camera = JSON.parse(opt.camera);
const neighbour = opt.neighbour ? JSON.parse(opt.neighbour) : null;
const outDir = opt['out-dir'];

const result = { url: opt.url, warnings: [] };
const problems = [];

// Installed in the page once: canvas captures kept in the page (only numbers and PNGs cross to Node).
function pageHelpers() {
  const { viewer } = window.citylod;
  const scene = viewer.scene;
  const shots = {};
  const bg = scene.backgroundColor;
  const BG = [bg.red, bg.green, bg.blue].map((c) => Math.round(c * 255));

  const frames = (n) => new Promise((resolve) => {
    let k = 0;
    const remove = scene.postRender.addEventListener(() => {
      if (++k >= n) { remove(); resolve(); }
    });
  });

  // The drawing buffer right after a frame (preserveDrawingBuffer keeps it readable).
  async function grab() {
    await frames(1);
    const c = document.createElement('canvas');
    c.width = scene.canvas.width;
    c.height = scene.canvas.height;
    const ctx = c.getContext('2d', { willReadFrequently: true });
    ctx.drawImage(scene.canvas, 0, 0);
    return { canvas: c, data: ctx.getImageData(0, 0, c.width, c.height).data };
  }

  const differing = (a, b, tol = 0) => {
    let n = 0;
    for (let i = 0; i < a.length; i += 4) {
      const d = Math.max(Math.abs(a[i] - b[i]), Math.abs(a[i + 1] - b[i + 1]), Math.abs(a[i + 2] - b[i + 2]));
      if (d > tol) n++;
    }
    return n;
  };

  // After a change (toggle, feature visibility): the tiles loaded and two captures in a row identical, so the
  // rebuilt draw commands are on screen. Keeps the last capture under `name`; returns its PNG as a data URL.
  async function capture(name, timeoutMs) {
    const t0 = performance.now();
    await frames(2);
    let prev = await grab();
    for (;;) {
      await frames(1);
      const cur = await grab();
      // the globe's own tiles refine too (its colour shifts a little while they do)
      const loaded = window.citylod.tileset.tilesLoaded && (!scene.globe.show || scene.globe.tilesLoaded);
      const same = differing(prev.data, cur.data) === 0;
      if ((same && loaded) || performance.now() - t0 > timeoutMs) {
        shots[name] = cur;
        return { png: cur.canvas.toDataURL('image/png'), stable: same, ms: Math.round(performance.now() - t0) };
      }
      prev = cur;
    }
  }

  // Pixels that are not the background: count, bounding box, centroid (canvas pixels, y down).
  function silhouette(name, tol = 6) {
    const { canvas, data } = shots[name];
    let n = 0, sx = 0, sy = 0, x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
    for (let y = 0; y < canvas.height; y++) {
      for (let x = 0; x < canvas.width; x++) {
        const i = 4 * (y * canvas.width + x);
        if (Math.abs(data[i] - BG[0]) <= tol && Math.abs(data[i + 1] - BG[1]) <= tol &&
            Math.abs(data[i + 2] - BG[2]) <= tol) continue;
        n++; sx += x; sy += y;
        x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y);
      }
    }
    return n ? { pixels: n, cx: sx / n, cy: sy / n, width: x1 - x0 + 1, height: y1 - y0 + 1,
      bbox: [x0, y0, x1, y1] } : { pixels: 0 };
  }

  const diff = (a, b) => differing(shots[a].data, shots[b].data);

  // Every loaded feature shown, or only those of one building (building_osm_id; INT64 arrives as BigInt).
  function isolate(osmId) {
    let shown = 0;
    const walk = (tile) => {
      const content = tile.contentReady ? tile.content : null;
      for (let i = 0; content && i < content.featuresLength; i++) {
        const f = content.getFeature(i);
        f.show = osmId === null || String(f.getProperty('building_osm_id')) === String(osmId);
        if (f.show) shown++;
      }
      for (const c of tile.children) walk(c);
    };
    walk(window.citylod.tileset.root);
    scene.globe.show = osmId === null;
    return shown;
  }

  // Canvas pixel of a point (degrees, metres above the ellipsoid); the canvas is the whole viewport here.
  function project(p) {
    const w = Cesium.SceneTransforms.worldToWindowCoordinates(scene,
      Cesium.Cartesian3.fromDegrees(p.lon, p.lat, p.height));
    return w ? { x: w.x, y: w.y } : null;
  }

  function pickAt(p) {
    const w = project(p);
    if (!w) return { at: null, osmId: null };
    const f = scene.pick(new Cesium.Cartesian2(w.x, w.y));
    const id = f instanceof Cesium.Cesium3DTileFeature ? f.getProperty('building_osm_id') : null;
    return { at: w, osmId: id === null || id === undefined ? null : String(id) };
  }

  window.__landmarks = { capture, silhouette, diff, isolate, project, pickAt };
}

function savePng(name, dataUrl) {
  const file = path.join(outDir, name);
  fs.writeFileSync(file, Buffer.from(dataUrl.replace(/^data:image\/png;base64,/, ''), 'base64'));
  return file;
}

let browser;
try {
  fs.mkdirSync(outDir, { recursive: true });
  browser = await open('[citylod]');
  const page = browser.page;
  // SwiftShader draws a frame in time proportional to its pixels; a small canvas keeps the many captures quick.
  await page.setViewportSize({ width: 800, height: 500 });
  // CesiumJS reports a custom shader it disables (e.g. missing metadata) with console.warn, not an error.
  page.on('console', (m) => { if (m.type() === 'warning') result.warnings.push(m.text()); });

  await page.goto(opt.url, { waitUntil: 'load', timeout });
  await page.waitForFunction(() => window.citylod && (window.citylod.ready || window.citylod.error), null, WAIT);
  const err = await page.evaluate(() => window.citylod.error);
  if (err) throw new Error(`viewer error: ${err}`);
  await page.waitForFunction(() => window.citylod.allTilesLoaded || window.citylod.error, null, WAIT);
  note('viewer ready');
  result.toggleInitially = await page.evaluate(() => ({
    exaggeration: window.citylod.exaggeration, checked: document.getElementById('exaggerate').checked }));
  await page.evaluate(pageHelpers);

  // The camera on the landmark's ground centre; the distance the shader measures is then exactly the range.
  result.camera = await page.evaluate(async ([lm, cam, maxSse, t]) => {
    const { viewer, tileset } = window.citylod;
    const R = Cesium.Math.toRadians;
    tileset.maximumScreenSpaceError = maxSse;
    viewer.camera.frustum.fov = R(cam.fov);
    const centre = Cesium.Cartesian3.fromDegrees(lm.lon, lm.lat, lm.ground);
    viewer.camera.lookAt(centre, new Cesium.HeadingPitchRange(R(cam.heading), R(cam.pitch), cam.range));
    viewer.camera.lookAtTransform(Cesium.Matrix4.IDENTITY);
    const settled = await window.citylodCommon.settle(viewer.scene, () => tileset, t);
    const c = viewer.camera.positionCartographic;
    return { lon: Cesium.Math.toDegrees(c.longitude), lat: Cesium.Math.toDegrees(c.latitude), height: c.height,
      distance: Cesium.Cartesian3.distance(viewer.camera.positionWC, centre), settled };
  }, [landmark, camera, Number(opt['max-sse']), timeout]);
  note('camera', JSON.stringify(result.camera));
  if (!result.camera.settled.loaded) {
    problems.push(`tiles still loading ${result.camera.settled.ms} ms after the camera move`);
  }

  const capture = async (name, file) => {
    const c = await page.evaluate(([n, t]) => window.__landmarks.capture(n, t), [name, timeout]);
    if (!c.stable) problems.push(`${name}: the picture did not settle in ${c.ms} ms`);
    if (file) savePng(file, c.png);
    note('captured', name, `${c.ms} ms`);
  };
  const pickHeight = Number(opt['pick-height']);
  const above = { lon: landmark.lon, lat: landmark.lat, height: landmark.ground + pickHeight };

  // The whole scene: off, on, off again, switched with the panel's checkbox as a user would.
  await capture('off', 'off.png');
  const pickOff = await page.evaluate((p) => window.__landmarks.pickAt(p), above);
  await page.check('#exaggerate');
  result.toggleOn = await page.evaluate(() => window.citylod.exaggeration);
  await capture('on', 'on.png');
  const pickOn = await page.evaluate((p) => window.__landmarks.pickAt(p), above);
  await page.uncheck('#exaggerate');
  result.toggleOff = await page.evaluate(() => window.citylod.exaggeration);
  await capture('off_again', 'off_again.png');
  result.scene = await page.evaluate(() => ({
    pixels: window.citylod.viewer.scene.canvas.width * window.citylod.viewer.scene.canvas.height,
    offVsOn: window.__landmarks.diff('off', 'on'),
    offVsOffAgain: window.__landmarks.diff('off', 'off_again'),
  }));
  result.pick = { height: pickHeight, off: pickOff, on: pickOn };

  // One building alone on the background, off and on (citylod.setExaggeration).
  const toggle = (on) => page.evaluate((v) => window.citylod.setExaggeration(v), on);
  const alone = async (key, who) => {
    const shown = await page.evaluate((id) => window.__landmarks.isolate(id), who.osmId);
    const out = { shown };
    for (const state of ['off', 'on']) {
      await toggle(state === 'on');
      await capture(`${key}_${state}`, `${key}_${state}.png`);
      out[state] = await page.evaluate((n) => window.__landmarks.silhouette(n), `${key}_${state}`);
    }
    await toggle(false);
    return out;
  };
  result.landmark = await alone('landmark', landmark);
  if (neighbour) {
    result.neighbour = await alone('neighbour', neighbour);
    result.neighbour.from = await page.evaluate((p) => window.__landmarks.project(p), neighbour.from);
    result.neighbour.to = await page.evaluate((p) => window.__landmarks.project(p), neighbour.to);
  }
  await page.evaluate(() => window.__landmarks.isolate(null));
  result.error = await page.evaluate(() => window.citylod.error);
} catch (e) {
  problems.push(e.message.split('\n')[0]);
} finally {
  if (browser) await browser.close();
}

finish(result, problems);
