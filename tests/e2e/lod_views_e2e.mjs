// Which tiles of a multi-LOD (REPLACE) tileset CesiumJS really draws, for a list of cameras: the citylod viewer
// page in headless Chromium (SwiftShader WebGL 2), offline, driven by playwright-core.
//
//   node tests/e2e/lod_views_e2e.mjs --url http://127.0.0.1:8765/ \
//        --cameras '[{"name":"far","lon":11.575,"lat":48.137,"height":8000,"heading":0,"pitch":-90,
//                     "screenshot":"build/screenshots/lod_far.png"}, ...]' [--max-sse 16]
//
// Loads the viewer, sets the tileset to the plain 3D Tiles traversal (maximumScreenSpaceError --max-sse; no
// dynamic or foveated screen-space error, no skipLevelOfDetail), then for each camera (heading and pitch in
// degrees, height above the ellipsoid in metres, no roll): Camera.setView, waits until every tile the view needs
// is loaded, records the tiles CesiumJS selects for rendering (tileset.tileVisible) over several frames, reads
// the `lod` property of every feature of their content, and saves a screenshot.
// Prints one JSON line {views: [{name, camera, drawingBufferHeight, fovyDeg, aspect, tiles: [...],
// frames, stable, nestedPairs, ...}], hosts, consoleErrors, failedRequests, seconds}; each tile is
// {uri, level, x, y, geometricError, children, leaf, sse, distance, lods: {lod: count}}.
// Exits 0 when every view loaded and was recorded (the caller judges the tiles); 1 with a message otherwise.
import fs from 'node:fs';
import path from 'node:path';
import { parseArgs } from 'node:util';
import { startDriver } from './browser.mjs';

const { values: opt } = parseArgs({
  options: {
    url: { type: 'string' },
    cameras: { type: 'string' },
    'max-sse': { type: 'string', default: '16' },
    frames: { type: 'string', default: '4' }, // frames recorded per view after it settled
    chromium: { type: 'string', default: process.env.CHROMIUM || '/usr/bin/chromium' },
    timeout: { type: 'string', default: '90000' }, // ms per wait; SwiftShader is slow
  },
});
const { note, timeout, WAIT, open, finish } = startDriver('lod_views_e2e', opt, ['url', 'cameras'],
  '--url URL --cameras JSON [--max-sse 16]');
const cameras = JSON.parse(opt.cameras);
const maxSse = Number(opt['max-sse']);
const nFrames = Number(opt.frames);
const result = { url: opt.url, maxSse, views: [] };
const problems = [];

// In the page: place the camera, wait until the view's tiles are loaded, then record what is drawn.
async function recordView([cam, nFrames, timeoutMs]) {
  const { viewer, tileset } = window.citylod;
  const scene = viewer.scene;
  const camera = viewer.camera;
  const R = Cesium.Math.toRadians;
  const D = Cesium.Math.toDegrees;
  camera.setView({
    destination: Cesium.Cartesian3.fromDegrees(cam.lon, cam.lat, cam.height),
    orientation: { heading: R(cam.heading), pitch: R(cam.pitch), roll: 0 },
  });
  window.citylod.allTilesLoaded = false;
  const settled = await window.citylodCommon.settle(scene, () => tileset, timeoutMs);

  // tileVisible fires once per frame for every tile selected for rendering; a frame ends at postRender.
  const frames = [];
  let current = new Set();
  const info = (tile) => {
    const uri = tile.content && tile.content.url ? new URL(tile.content.url, location.href).pathname : '';
    const m = /content\/(\d+)\/(\d+)\/(\d+)\.glb$/.exec(uri);
    const lods = {};
    const content = tile.content;
    for (let i = 0; i < (content ? content.featuresLength : 0); ++i) {
      const lod = content.getFeature(i).getProperty('lod');
      lods[lod] = (lods[lod] || 0) + 1;
    }
    // The ancestors' content, so the caller can see REPLACE never draws two versions of one place.
    const ancestors = [];
    for (let p = tile.parent; p; p = p.parent) {
      if (p.content && p.content.url) ancestors.push(new URL(p.content.url, location.href).pathname);
    }
    return {
      uri: m ? `content/${m[1]}/${m[2]}/${m[3]}.glb` : uri,
      level: m ? Number(m[1]) : null,
      x: m ? Number(m[2]) : null,
      y: m ? Number(m[3]) : null,
      geometricError: tile.geometricError,
      children: tile.children.length,
      leaf: tile.children.length === 0,
      refine: tile.refine === Cesium.Cesium3DTileRefine.REPLACE ? 'REPLACE' : 'ADD',
      // what CesiumJS computed this frame (private fields, for diagnostics only)
      sse: tile._screenSpaceError,
      distance: tile._distanceToCamera,
      features: content ? content.featuresLength : 0,
      lods,
      ancestors: ancestors.map((a) => a.replace(/^.*?(content\/)/, '$1')),
    };
  };
  const onVisible = (tile) => current.add(tile);
  tileset.tileVisible.addEventListener(onVisible);
  await new Promise((resolve) => {
    const remove = scene.postRender.addEventListener(() => {
      frames.push([...current]);
      current = new Set();
      if (frames.length >= nFrames + 1) {
        remove();
        resolve();
      }
    });
  });
  tileset.tileVisible.removeEventListener(onVisible);
  frames.shift(); // the first frame may have started before the listener was added
  const key = (tiles) => tiles.map((t) => (t.content ? t.content.url : '')).sort().join('|');
  const stable = frames.every((f) => key(f) === key(frames[0]));
  const tiles = frames[frames.length - 1].map(info).sort((a, b) => a.level - b.level || a.x - b.x || a.y - b.y);
  const drawn = new Set(tiles.map((t) => t.uri));
  const nestedPairs = [];
  for (const t of tiles) for (const a of t.ancestors) if (drawn.has(a)) nestedPairs.push([a, t.uri]);
  for (const t of tiles) delete t.ancestors;

  const c = camera.positionCartographic;
  const st = tileset.statistics;
  return {
    name: cam.name,
    settled,
    stable,
    frames: frames.map((f) => f.length),
    // the camera as CesiumJS holds it, and the numbers its screen-space error uses
    camera: { lon: D(c.longitude), lat: D(c.latitude), height: c.height, heading: D(camera.heading),
      pitch: D(camera.pitch), roll: D(camera.roll) },
    drawingBufferHeight: scene.drawingBufferHeight,
    drawingBufferWidth: scene.drawingBufferWidth,
    pixelRatio: scene.pixelRatio,
    fovyDeg: D(camera.frustum.fovy),
    aspect: camera.frustum.aspectRatio,
    sseDenominator: camera.frustum.sseDenominator,
    maximumScreenSpaceError: tileset.maximumScreenSpaceError,
    memoryAdjustedScreenSpaceError: tileset.memoryAdjustedScreenSpaceError,
    tilesLoaded: tileset.tilesLoaded,
    trianglesSelected: st.numberOfTrianglesSelected,
    featuresSelected: st.numberOfFeaturesSelected,
    tiles,
    nestedPairs,
  };
}

let browser;
try {
  browser = await open('[citylod] all tiles');
  const page = browser.page;

  await page.goto(opt.url, { waitUntil: 'load', timeout });
  await page.waitForFunction(() => window.citylod && (window.citylod.ready || window.citylod.error),
    null, WAIT);
  const err = await page.evaluate(() => window.citylod.error);
  if (err) throw new Error(`viewer error: ${err}`);
  note('viewer ready');

  // The plain traversal of the 3D Tiles specification, which api.lod_for_view mirrors.
  result.tileset = await page.evaluate((sse) => {
    const ts = window.citylod.tileset;
    ts.maximumScreenSpaceError = sse;
    ts.dynamicScreenSpaceError = false;
    ts.foveatedScreenSpaceError = false;
    ts.skipLevelOfDetail = false;
    return { maximumScreenSpaceError: ts.maximumScreenSpaceError, dynamicScreenSpaceError: ts.dynamicScreenSpaceError,
      foveatedScreenSpaceError: ts.foveatedScreenSpaceError, skipLevelOfDetail: ts.skipLevelOfDetail };
  }, maxSse);

  for (const cam of cameras) {
    const view = await page.evaluate(recordView, [cam, nFrames, timeout]);
    note(`view ${cam.name}: ${view.tiles.length} tiles drawn, settled ${JSON.stringify(view.settled)}, ` +
      `frames ${view.frames.join(',')}`);
    if (!view.settled.loaded) problems.push(`${cam.name}: tiles still loading ${view.settled.ms} ms after setView`);
    if (!view.stable) problems.push(`${cam.name}: the drawn tiles changed between frames (${view.frames})`);
    if (cam.screenshot) {
      fs.mkdirSync(path.dirname(path.resolve(cam.screenshot)), { recursive: true });
      await page.screenshot({ path: cam.screenshot });
      view.screenshot = cam.screenshot;
    }
    result.views.push(view);
  }
} catch (e) {
  problems.push(e.message.split('\n')[0]);
} finally {
  if (browser) await browser.close();
}

finish(result, problems);
