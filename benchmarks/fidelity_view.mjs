// What a client streaming a tileset draws against the city at full detail (issue 18): the citylod viewer page in
// headless Chromium (SwiftShader WebGL 2), offline, driven by playwright-core (tests/e2e/browser.mjs). Used by
// benchmarks/fidelity_bench.py and tests/e2e/test_bench_fidelity.py.
//
//   node benchmarks/fidelity_view.mjs --url http://127.0.0.1:8765/ --out build/bench/fidelity/x \
//        --cameras '[{"name":"overview","lon":9.52,"lat":47.14,"height":21000,"heading":0,"pitch":-90,
//                     "fovDeg":91.5,"width":1920,"height_px":1080}, ...]' [--max-sse 16] [--full-sse 0]
//
// The tileset is drawn as a building mask: every fragment of every building pure white and unlit (a CustomShader
// with LightingModel.UNLIT), on pure black (no globe, sky, atmosphere, sun, moon or fog), without FXAA or MSAA, so
// every pixel is 0 or 255; landmark exaggeration off, the clock stopped. The traversal is the plain one the stream
// bench uses (no dynamic or foveated SSE, no skipLevelOfDetail, a cache large enough that CesiumJS never coarsens
// the view to save memory). Per camera, two passes: *streamed* (maximumScreenSpaceError --max-sse, what a client
// draws) and *full* (--full-sse, 0 by default: every tile with an error refines, so only leaves are drawn). A pass
// places the camera (the camera's horizontal field of view, as stream_view.mjs), waits until the view's tiles are
// loaded, unloads what it does not need (trimLoadedTiles, so the statistics are the view's alone), waits again,
// records the tiles selected over one frame (how many, how many leaves, how many inner tiles drawn only because
// none of their children is in view, their levels) and tileset.statistics, and
// saves the canvas's drawing buffer as <out>/<camera>-<pass>.png.
// Prints one JSON line {views: [{name, camera, loaded, ms, tileFailures, passes: {streamed: {...}, full: {...}}}
// | {name, error}], mask, hosts,
// consoleErrors, failedRequests, seconds}. A camera that fails is recorded with its error and the next one is still
// measured; exits 1 when any camera failed or a tile failed to load.
import fs from 'node:fs';
import path from 'node:path';
import { parseArgs } from 'node:util';
import { startDriver } from '../tests/e2e/browser.mjs';

const { values: opt } = parseArgs({
  options: {
    url: { type: 'string' },
    cameras: { type: 'string' },
    out: { type: 'string' },
    'max-sse': { type: 'string', default: '16' },
    'full-sse': { type: 'string', default: '0' },
    chromium: { type: 'string', default: process.env.CHROMIUM || '/usr/bin/chromium' },
    timeout: { type: 'string', default: '600000' }, // ms per wait; a full-detail overview loads every leaf
  },
});
const { note, timeout, open, openViewer, savePng, finish } = startDriver('fidelity_view', opt, ['url', 'cameras', 'out'],
  '--url URL --cameras JSON --out DIR [--max-sse 16] [--full-sse 0]');
const cameras = JSON.parse(opt.cameras);
const PASSES = [['streamed', Number(opt['max-sse'])], ['full', Number(opt['full-sse'])]];
const result = { url: opt.url, passes: Object.fromEntries(PASSES), views: [] };
const problems = [];

// In the page: the scene as a binary building mask.
function maskScene() {
  const { viewer, tileset } = window.citylod;
  const scene = viewer.scene;
  window.citylod.setExaggeration(false); // before the mask shader: it resets customShader
  viewer.clock.shouldAnimate = false;
  tileset.customShader = new Cesium.CustomShader({
    lightingModel: Cesium.LightingModel.UNLIT,
    fragmentShaderText: `
      void fragmentMain(FragmentInput fsInput, inout czm_modelMaterial material) {
        material.diffuse = vec3(1.0);
        material.alpha = 1.0;
      }`,
  });
  tileset.shadows = Cesium.ShadowMode.DISABLED;
  scene.globe.show = false;
  scene.backgroundColor = Cesium.Color.BLACK;
  if (scene.skyBox) scene.skyBox.show = false;
  if (scene.skyAtmosphere) scene.skyAtmosphere.show = false;
  if (scene.sun) scene.sun.show = false;
  if (scene.moon) scene.moon.show = false;
  scene.fog.enabled = false;
  scene.highDynamicRange = false;
  scene.postProcessStages.fxaa.enabled = false;
  scene.msaaSamples = 1;
  tileset.dynamicScreenSpaceError = false;
  tileset.foveatedScreenSpaceError = false;
  tileset.skipLevelOfDetail = false;
  tileset.cacheBytes = 8 * 1024 ** 3;
  tileset.maximumCacheOverflowBytes = 8 * 1024 ** 3;
  return {
    unlit: tileset.customShader.lightingModel === Cesium.LightingModel.UNLIT,
    globe: scene.globe.show, fog: scene.fog.enabled, fxaa: scene.postProcessStages.fxaa.enabled,
    msaaSamples: scene.msaaSamples, highDynamicRange: scene.highDynamicRange,
    exaggeration: window.citylod.exaggeration, cacheBytes: tileset.cacheBytes,
    dynamicScreenSpaceError: tileset.dynamicScreenSpaceError,
    foveatedScreenSpaceError: tileset.foveatedScreenSpaceError, skipLevelOfDetail: tileset.skipLevelOfDetail,
  };
}

// In the page: one pass of one camera (see the header).
async function measurePass([cam, sse, timeoutMs]) {
  const { viewer, tileset } = window.citylod;
  const scene = viewer.scene;
  const frames = (n) => window.citylodCommon.frames(scene, n);
  tileset.maximumScreenSpaceError = sse;
  const view = await window.citylodCommon.viewCamera(viewer, tileset, cam, timeoutMs);
  // The tiles selected for rendering in one whole frame (tileVisible fires once per drawn tile per frame).
  let current = new Set();
  const onVisible = (tile) => current.add(tile);
  await frames(1);
  tileset.tileVisible.addEventListener(onVisible);
  current = new Set();
  await frames(1);
  tileset.tileVisible.removeEventListener(onVisible);
  const drawn = [...current];
  // CesiumJS refines a tile only into children it sees; one whose error asks for refinement but none of whose
  // children is in view (at the frustum's edge: its volume is, theirs are not) is drawn itself, however small the
  // maximum error. Its children were judged this frame, as it was traversed. (_screenSpaceError is private.)
  const edge = (t) => t.children.length > 0 && t._screenSpaceError > tileset.memoryAdjustedScreenSpaceError &&
    !t.children.some((c) => c.isVisible);
  const levels = {};
  const keys = [];
  for (const t of drawn) {
    const m = /content\/(\d+)\/(\d+)\/(\d+)\.glb/.exec(t.content && t.content.url ? t.content.url : '');
    const level = m ? m[1] : '?';
    levels[level] = (levels[level] || 0) + 1;
    keys.push(m ? `${m[1]}/${m[2]}/${m[3]}` : '?');
  }
  const st = tileset.statistics;
  return {
    maximumScreenSpaceError: tileset.maximumScreenSpaceError,
    memoryAdjustedScreenSpaceError: tileset.memoryAdjustedScreenSpaceError,
    ...view,
    trianglesSelected: st.numberOfTrianglesSelected,
    featuresSelected: st.numberOfFeaturesSelected,
    tilesSelected: st.selected,
    tilesWithContent: st.numberOfTilesWithContentReady,
    tilesDrawn: drawn.length,
    leavesDrawn: drawn.filter((t) => t.children.length === 0).length,
    edgeDrawn: drawn.filter(edge).length,
    levels,
    drawnTiles: keys.sort(), // level/x/y
    geometryByteLength: st.geometryByteLength,
    drawingBuffer: [scene.drawingBufferWidth, scene.drawingBufferHeight],
    fovyDeg: Cesium.Math.toDegrees(viewer.camera.frustum.fovy),
    // the drawing buffer the viewer preserves: the frame just measured
    png: scene.canvas.toDataURL('image/png'),
  };
}

let browser;
try {
  browser = await open('[citylod] all tiles');
  const page = browser.page;
  await openViewer(page, cameras[0].width, cameras[0].height_px);
  result.mask = await page.evaluate(maskScene);
  fs.mkdirSync(path.resolve(opt.out), { recursive: true });
  for (const cam of cameras) {
    const view = { name: cam.name, camera: cam, passes: {} };
    try {
      for (const [pass, sse] of PASSES) {
        const p = await page.evaluate(measurePass, [cam, sse, timeout]);
        const shot = path.join(opt.out, `${cam.name}-${pass}.png`);
        savePng(p.png, shot);
        delete p.png;
        p.mask = shot;
        if (!p.loaded) problems.push(`${cam.name} ${pass}: tiles still loading after ${p.ms} ms`);
        if (p.tileFailures) problems.push(`${cam.name} ${pass}: ${p.tileFailures} tiles failed to load`);
        note(`view ${cam.name} ${pass}`, JSON.stringify(p));
        view.passes[pass] = p;
      }
      // what benchmarks/stream_bench.py browse() reads of a view
      const ps = Object.values(view.passes);
      view.loaded = ps.every((p) => p.loaded);
      view.ms = ps.reduce((a, p) => a + p.ms, 0);
      view.tileFailures = ps.reduce((a, p) => a + p.tileFailures, 0);
    } catch (e) {
      const msg = e.message.split('\n')[0];
      problems.push(`${cam.name}: ${msg}`);
      view.error = msg;
    }
    result.views.push(view);
  }
} catch (e) {
  problems.push(e.message.split('\n')[0]);
} finally {
  if (browser) await browser.close();
}
result.problems = problems;
finish(result, problems);
