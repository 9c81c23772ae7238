// A tileset in three.js + 3DTilesRendererJS (tests/e2e/three/client.js) in headless Chromium, offline.
//
//   node tests/e2e/three_e2e.mjs --url http://127.0.0.1:8765/ [--tileset tiles/tileset.json] [--load-all]
//        [--cameras '[{"name":"far","lon":..,"lat":..,"height":..,"heading":..,"pitch":..,"fovyDeg":..,
//                      "widthPx":..,"heightPx":..}]'] [--max-sse 16] [--pick '{"lon":..,"lat":..,"top":..}']
//
// The page and the client's modules (three, 3d-tiles-renderer from node_modules) are answered by the driver under
// /__three/ of the tile server's origin; the tiles come from the server. --load-all draws every depth of the tree
// in turn and then the leaves (error target 0, the whole tileset in view); --cameras draws each CesiumJS camera at
// error target --max-sse; --pick raycasts straight down after the views. Prints one JSON line {loadAll, views,
// pick, loadErrors, loaded, containment, warnings, hosts, consoleErrors, failedRequests, seconds}; exits 0 when
// the page ran (the caller judges what it drew), 1 with a message otherwise.
import fs from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { parseArgs } from 'node:util';
import { startDriver } from './browser.mjs';

const { values: opt } = parseArgs({
  options: {
    url: { type: 'string' },
    tileset: { type: 'string', default: 'tiles/tileset.json' },
    'load-all': { type: 'boolean', default: false },
    cameras: { type: 'string', default: '[]' },
    'max-sse': { type: 'string', default: '16' },
    pick: { type: 'string' },
    chromium: { type: 'string', default: process.env.CHROMIUM || '/usr/bin/chromium' },
    timeout: { type: 'string', default: '120000' },
  },
});
const { note, timeout, open, finish } = startDriver('three_e2e', opt, ['url'],
  '--url URL [--tileset PATH] [--load-all] [--cameras JSON] [--pick JSON]');
const HERE = path.dirname(fileURLToPath(import.meta.url));
const REPO = path.resolve(HERE, '..', '..');
// what /__three/ answers: the client's page and module, and the two packages it imports
const ROOTS = {
  'node_modules/three/': path.join(REPO, 'node_modules', 'three'),
  'node_modules/3d-tiles-renderer/': path.join(REPO, 'node_modules', '3d-tiles-renderer'),
  '': path.join(HERE, 'three'),
};
const TYPES = { '.js': 'text/javascript', '.html': 'text/html', '.wasm': 'application/wasm',
  '.json': 'application/json' };

function local(rel) {
  for (const [prefix, dir] of Object.entries(ROOTS)) {
    if (!rel.startsWith(prefix)) continue;
    const file = path.resolve(dir, rel.slice(prefix.length));
    if (file.startsWith(dir + path.sep) && fs.existsSync(file) && fs.statSync(file).isFile()) return file;
  }
  return null;
}

const result = { url: opt.url, tileset: opt.tileset, views: [] };
const problems = [];
const warnings = [];
let browser;
try {
  browser = await open('[three]');
  const { page } = browser;
  page.on('console', (m) => {
    if (m.type() === 'warning') warnings.push(m.text());
  });
  const base = new URL(opt.url);
  await page.route(`${base.origin}/__three/**`, (route) => {
    const rel = new URL(route.request().url()).pathname.replace(/^\/__three\//, '');
    const file = local(rel);
    if (!file) return route.fulfill({ status: 404, body: 'not found' });
    return route.fulfill({ status: 200, contentType: TYPES[path.extname(file)] || 'application/octet-stream',
      body: fs.readFileSync(file) });
  });
  await page.setViewportSize({ width: 1280, height: 800 });
  await page.goto(`${base.origin}/__three/index.html`, { waitUntil: 'load', timeout });
  await page.waitForFunction(() => window.t3 && window.t3.ready, null, { timeout, polling: 200 });
  const tileset = new URL(opt.tileset, opt.url).href;
  await page.evaluate(([t]) => window.t3.open({ tileset: t, width: 1280, height: 800 }), [tileset]);
  note('client open');

  if (opt['load-all']) {
    result.loadAll = await page.evaluate((ms) => window.t3.loadEverything(ms), timeout);
    note(`load-all: ${result.loadAll.depths.length} depths, ${result.loadAll.leaves.length} leaves`);
    if (!result.loadAll.settled.loaded) problems.push('load-all: tiles still loading');
  }
  for (const cam of JSON.parse(opt.cameras)) {
    const v = await page.evaluate(([c, sse, ms]) => window.t3.view(c, sse, ms), [cam, Number(opt['max-sse']), timeout]);
    note(`view ${cam.name}: ${v.tiles.length} tiles, ${v.renderedTriangles} triangles`);
    if (!v.settled.loaded) problems.push(`${cam.name}: tiles still loading`);
    result.views.push(v);
  }
  if (opt.pick) {
    const p = JSON.parse(opt.pick);
    result.pick = await page.evaluate(([q]) => window.t3.pick(q.lon, q.lat, q.top), [p]);
    note(`pick: ${JSON.stringify(result.pick)}`);
  }
  Object.assign(result, await page.evaluate(() => window.t3.report()));
  result.warnings = warnings;
} catch (e) {
  problems.push(e.message.split('\n')[0]);
} finally {
  if (browser) await browser.close();
}

finish(result, problems);
