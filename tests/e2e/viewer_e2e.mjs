// End-to-end check of the citylod viewer in a real CesiumJS client: headless Chromium (SwiftShader WebGL 2),
// offline, driven by playwright-core.
//
//   node tests/e2e/viewer_e2e.mjs --url http://127.0.0.1:8765/ --lon 11.57 --lat 48.13 --height 25 \
//        --screenshot build/screenshots/viewer.png [--expect-osm-id 123] [--range 300]
//
// Loads the viewer, waits for the tileset, looks straight down at lon/lat from --range metres, clicks the
// point lon/lat/height (a roof) and reads the picked feature's properties. Prints one JSON line:
// {tilesLoaded, tilesWithContent, triangles, features, picked, hosts, consoleErrors, webgl, ...}.
// Exits 0 on success; 1 with a message on stderr otherwise (the JSON line is still printed when possible).
import fs from 'node:fs';
import path from 'node:path';
import { parseArgs } from 'node:util';
import { startDriver } from './browser.mjs';

const { values: opt } = parseArgs({
  options: {
    url: { type: 'string' },
    lon: { type: 'string' },
    lat: { type: 'string' },
    height: { type: 'string', default: '0' },
    range: { type: 'string', default: '300' },
    screenshot: { type: 'string' },
    'expect-osm-id': { type: 'string' },
    chromium: { type: 'string', default: process.env.CHROMIUM || '/usr/bin/chromium' },
    timeout: { type: 'string', default: '90000' }, // ms per wait; SwiftShader is slow
  },
});
const { note, timeout, WAIT, open, finish } = startDriver('viewer_e2e', opt, ['url', 'lon', 'lat', 'screenshot'],
  '--url URL --lon X --lat Y --height H --screenshot PATH [--expect-osm-id N] [--range M]');
const lon = Number(opt.lon);
const lat = Number(opt.lat);
const height = Number(opt.height);
const range = Number(opt.range);

const result = { url: opt.url };
const problems = [];

let browser;
try {
  browser = await open('[citylod]');
  const page = browser.page;

  await page.goto(opt.url, { waitUntil: 'load', timeout });
  await page.waitForFunction(() => window.citylod && (window.citylod.ready || window.citylod.error),
    null, WAIT);
  const err = await page.evaluate(() => window.citylod.error);
  if (err) throw new Error(`viewer error: ${err}`);
  note('viewer ready');

  await page.waitForFunction(() => window.citylod.allTilesLoaded || window.citylod.error, null, WAIT);
  note('first allTilesLoaded', JSON.stringify(await page.evaluate(() => window.citylod.stats())));
  // The status line and the counts behind it, at the overview and from far away (where far tiles draw blocks).
  // The line is refreshed at most every 500 ms: wait for the line of the counts taken.
  const statusNow = () => page.evaluate(async () => {
    for (;;) {
      const s = window.citylod.stats();
      await new Promise((resolve) => setTimeout(resolve, 600));
      const again = window.citylod.stats();
      if (JSON.stringify(s.kinds) === JSON.stringify(again.kinds)) {
        return { ...again, status: document.getElementById('status').textContent };
      }
    }
  });
  result.overview = await statusNow();
  const far = await page.evaluate(([a, b, t]) => window.citylod.lookAt(a, b, 0, 25000, t), [lon, lat, timeout]);
  if (!far.loaded) problems.push(`tiles still loading ${far.ms} ms after the far lookAt`);
  result.far = await statusNow();

  // The renderer string from a scratch canvas (same GPU process as CesiumJS's context).
  result.webgl = await page.evaluate(() => {
    const gl = document.createElement('canvas').getContext('webgl2');
    if (!gl) return { version: null, renderer: null };
    const ext = gl.getExtension('WEBGL_debug_renderer_info');
    return { version: gl.getParameter(gl.VERSION),
      renderer: ext ? gl.getParameter(ext.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER) };
  });

  const look = await page.evaluate(([a, b, h, r, t]) => window.citylod.lookAt(a, b, h, r, t),
    [lon, lat, height, range, timeout]);
  note('lookAt', JSON.stringify(look));
  if (!look.loaded) problems.push(`tiles still loading ${look.ms} ms after lookAt`);

  // Page coordinates of the roof point: window coordinates are relative to the canvas (CSS pixels).
  const at = await page.evaluate(([a, b, h]) => {
    const scene = window.citylod.viewer.scene;
    const p = Cesium.SceneTransforms.worldToWindowCoordinates(scene, Cesium.Cartesian3.fromDegrees(a, b, h));
    if (!p) return null;
    const r = scene.canvas.getBoundingClientRect();
    return { x: r.left + p.x, y: r.top + p.y };
  }, [lon, lat, height]);
  if (!at) throw new Error(`lon/lat ${lon},${lat} is not on screen`);
  result.click = { x: Math.round(at.x), y: Math.round(at.y) };

  const picksBefore = await page.evaluate(() => window.citylod.picks);
  await page.mouse.click(at.x, at.y);
  await page.waitForFunction((n) => window.citylod.picks > n, picksBefore, WAIT);
  const picked = await page.evaluate(() => window.citylod.lastPicked);
  if (picked) {
    await page.waitForFunction(() => document.querySelectorAll('#props tr').length > 0, null, WAIT);
    // BigInt never crosses evaluate() as JSON; the viewer already stringifies, this is belt and braces.
    for (const [k, v] of Object.entries(picked)) if (typeof v === 'bigint') picked[k] = v.toString();
  } else {
    problems.push(`nothing picked at ${result.click.x},${result.click.y}`);
  }
  result.picked = picked;
  result.panelRows = await page.evaluate(() => document.querySelectorAll('#props tr').length);
  result.attribution = await page.evaluate(() => document.getElementById('attribution')?.innerText ?? null);

  // Two rendered frames so the highlight colour is in the drawing buffer before the screenshot.
  await page.evaluate(() => new Promise((resolve) => {
    let n = 0;
    const remove = window.citylod.viewer.scene.postRender.addEventListener(() => {
      if (++n >= 2) { remove(); resolve(); }
    });
  }));
  fs.mkdirSync(path.dirname(path.resolve(opt.screenshot)), { recursive: true });
  await page.screenshot({ path: opt.screenshot });
  result.screenshot = opt.screenshot;

  Object.assign(result, await page.evaluate(() => window.citylod.stats()));
} catch (e) {
  problems.push(e.message.split('\n')[0]);
} finally {
  if (browser) await browser.close();
}

if (!(result.tilesWithContent > 0)) problems.push('no tile with content loaded');
if (!(result.triangles > 0)) problems.push('no triangles rendered');
const want = opt['expect-osm-id'];
if (want !== undefined && result.picked && String(result.picked.osm_id) !== String(want)) {
  problems.push(`picked osm_id ${result.picked.osm_id}, expected ${want}`);
}

finish(result, problems);
