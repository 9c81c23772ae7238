// What one stream costs a CesiumJS client: the citylod viewer page in headless Chromium (SwiftShader WebGL 2),
// offline, driven by playwright-core (tests/e2e/browser.mjs). Used by benchmarks/stream_bench.py.
//
//   node benchmarks/stream_view.mjs --url http://127.0.0.1:8765/ --out build/bench/stream/x/compact \
//        --cameras '[{"name":"street","lon":9.52,"lat":47.14,"height":520,"heading":0,"pitch":-15,
//                     "fovDeg":91.5,"width":1920,"height_px":1080}, ...]'
//
// Loads the viewer (landmark exaggeration off, the clock stopped as the viewer keeps it), sets the plain 3D
// Tiles traversal (maximumScreenSpaceError --max-sse, no dynamic or foveated SSE, no skipLevelOfDetail, a cache
// large enough that CesiumJS never coarsens the view to save memory), then per camera: Camera.setView with the
// camera's horizontal field of view, waits until every tile the view needs is loaded, unloads every tile the
// view does not need (trimLoadedTiles) so the memory figures are this view's alone, waits again, reads
// tileset.statistics and saves the canvas's drawing buffer (the UI panels are not in it) as <out>/<name>.png.
// Prints one JSON line {gpu: {...}, views: [{name, loaded, texturesByteLength, geometryByteLength, ...,
// screenshot} | {name, error}], hosts, consoleErrors, failedRequests, seconds}. A view that fails is recorded
// with its error and the next one is still measured; exits 1 when any view failed or a tile failed to load.
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
    chromium: { type: 'string', default: process.env.CHROMIUM || '/usr/bin/chromium' },
    timeout: { type: 'string', default: '240000' }, // ms per wait; SwiftShader at 1080p is slow
  },
});
const { note, timeout, open, openViewer, savePng, finish } = startDriver('stream_view', opt, ['url', 'cameras', 'out'],
  '--url URL --cameras JSON --out DIR [--max-sse 16]');
const cameras = JSON.parse(opt.cameras);
const maxSse = Number(opt['max-sse']);
const result = { url: opt.url, maxSse, views: [] };
const problems = [];

// In the page: place the camera, load what it needs, drop what it does not, then read the memory statistics.
async function measureView([cam, timeoutMs]) {
  const { viewer, tileset } = window.citylod;
  const scene = viewer.scene;
  // What the session holds on arrival (the viewer's opening overview and earlier views included), for context;
  // then whatever this view does not use goes.
  let held;
  const view = await window.citylodCommon.viewCamera(viewer, tileset, cam, timeoutMs, () => {
    held = { texturesByteLength: tileset.statistics.texturesByteLength,
      geometryByteLength: tileset.statistics.geometryByteLength };
  });
  await window.citylodCommon.frames(scene, 3);
  const st = tileset.statistics;
  return {
    name: cam.name,
    ...view,
    texturesByteLength: st.texturesByteLength,
    geometryByteLength: st.geometryByteLength,
    batchTableByteLength: st.batchTableByteLength,
    tilesWithContent: st.numberOfTilesWithContentReady,
    trianglesSelected: st.numberOfTrianglesSelected,
    featuresSelected: st.numberOfFeaturesSelected,
    tilesSelected: st.selected,
    held,
    memoryAdjustedScreenSpaceError: tileset.memoryAdjustedScreenSpaceError,
    drawingBuffer: [scene.drawingBufferWidth, scene.drawingBufferHeight],
    fovyDeg: Cesium.Math.toDegrees(viewer.camera.frustum.fovy),
    // The drawing buffer itself (the viewer preserves it): the frame just measured, read without waiting for
    // the compositor, which a page screenshot does for tens of seconds while SwiftShader renders 1080p frames.
    png: scene.canvas.toDataURL('image/png'),
  };
}

let browser;
try {
  browser = await open('[citylod] all tiles');
  const page = browser.page;
  await openViewer(page, cameras[0].width, cameras[0].height_px);
  // Frames comparable between two streams: nothing scales or moves.
  result.tileset = await page.evaluate((sse) => {
    window.citylod.setExaggeration(false);
    window.citylod.viewer.clock.shouldAnimate = false;
    const ts = window.citylod.tileset;
    ts.maximumScreenSpaceError = sse;
    ts.dynamicScreenSpaceError = false;
    ts.foveatedScreenSpaceError = false;
    ts.skipLevelOfDetail = false;
    ts.cacheBytes = 8 * 1024 ** 3;
    ts.maximumCacheOverflowBytes = 8 * 1024 ** 3;
    return { maximumScreenSpaceError: ts.maximumScreenSpaceError, cacheBytes: ts.cacheBytes,
      exaggeration: window.citylod.exaggeration };
  }, maxSse);
  // The GPU texture formats the context exposes: what KTX2 (Basis) can transcode to here.
  result.gpu = await page.evaluate(() => {
    const ctx = window.citylod.viewer.scene.context;
    const gl = ctx._gl;
    const dbg = gl.getExtension('WEBGL_debug_renderer_info');
    return {
      webgl2: ctx.webgl2,
      renderer: dbg ? gl.getParameter(dbg.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER),
      compressedExtensions: (gl.getSupportedExtensions() || []).filter((e) => /compressed_texture/.test(e)).sort(),
      astc: ctx.astc, etc: ctx.etc, etc1: ctx.etc1, s3tc: ctx.s3tc, bc7: ctx.bc7, pvrtc: ctx.pvrtc,
      supportsBasis: ctx.supportsBasis,
    };
  });
  note('gpu', JSON.stringify(result.gpu));
  fs.mkdirSync(path.resolve(opt.out), { recursive: true });
  for (const cam of cameras) {
    try {
      const view = await page.evaluate(measureView, [cam, timeout]);
      const shot = path.join(opt.out, `${cam.name}.png`);
      savePng(view.png, shot);
      delete view.png;
      view.screenshot = shot;
      if (!view.loaded) problems.push(`${cam.name}: tiles still loading after ${view.ms} ms`);
      if (view.tileFailures) problems.push(`${cam.name}: ${view.tileFailures} tiles failed to load`);
      note(`view ${cam.name}`, JSON.stringify(view));
      result.views.push(view);
    } catch (e) {
      const msg = e.message.split('\n')[0];
      problems.push(`${cam.name}: ${msg}`);
      result.views.push({ name: cam.name, error: msg });
    }
  }
} catch (e) {
  problems.push(e.message.split('\n')[0]);
} finally {
  if (browser) await browser.close();
}
result.problems = problems;
finish(result, problems);
