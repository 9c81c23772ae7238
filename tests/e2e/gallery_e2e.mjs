// End-to-end check of the citylod roof gallery (exporter/viewer/gallery.html) in headless Chromium
// (SwiftShader WebGL 2), offline, driven by playwright-core.
//
//   node tests/e2e/gallery_e2e.mjs --url http://127.0.0.1:8765/ --screenshot build/screenshots/roof_gallery.png \
//        [--highlight gabled] [--highlight-screenshot build/screenshots/roof_gallery_gabled.png] [--pick-shape hipped]
//
// Opens URL + viewer/gallery.html, waits until window.citylodGallery.ready (tileset framed, every tile of the
// view loaded, legend built), takes the screenshot, then:
//  * clicks the legend entry --highlight and reads back which features CesiumJS now colours with the highlight;
//  * audits visibility: gives every feature a binary code, renders one unlit black/white pass per bit and
//    decodes the canvas pixels that no overlay (panel, credits, attribution) covers, which yields the features
//    that really show on screen in the gallery's framing (and a point on each);
//  * clicks the largest visible building of --pick-shape and reads what the gallery says about it.
// Prints one JSON line {featureCount, shapes, legend, visible, highlight, pick, hosts, consoleErrors, ...}.
// Exits 0 when the page worked (the caller judges the numbers); 1 with a message on stderr otherwise.
import fs from 'node:fs';
import path from 'node:path';
import { parseArgs } from 'node:util';
import { startDriver } from './browser.mjs';

const { values: opt } = parseArgs({
  options: {
    url: { type: 'string' },
    screenshot: { type: 'string' },
    highlight: { type: 'string', default: 'gabled' },
    'pick-shape': { type: 'string', default: 'hipped' },
    'highlight-screenshot': { type: 'string' },
    chromium: { type: 'string', default: process.env.CHROMIUM || '/usr/bin/chromium' },
    timeout: { type: 'string', default: '120000' }, // ms per wait; SwiftShader is slow
  },
});
const { note, timeout, WAIT, open, finish } = startDriver('gallery_e2e', opt, ['url', 'screenshot'],
  '--url URL --screenshot PATH [--highlight SHAPE]');

const pageUrl = new URL('viewer/gallery.html', opt.url).href;
const result = { url: pageUrl };
const problems = [];

// Resolves after n rendered frames of the gallery's scene.
const frames = (page, n = 2) => page.evaluate((k) => new Promise((resolve) => {
  let i = 0;
  const scene = window.citylodGallery.viewer.scene;
  const remove = scene.postRender.addEventListener(() => {
    if (++i >= k) { remove(); resolve(); }
  });
  scene.requestRender();
}), n);

let browser;
try {
  browser = await open('[gallery]');
  const page = browser.page;

  await page.goto(pageUrl, { waitUntil: 'load', timeout });
  await page.waitForFunction(
    () => window.citylodGallery && (window.citylodGallery.ready || window.citylodGallery.error), null, WAIT);
  const err = await page.evaluate(() => window.citylodGallery.error);
  if (err) throw new Error(`gallery error: ${err}`);
  note('gallery ready');

  Object.assign(result, await page.evaluate(() => {
    const g = window.citylodGallery;
    const legend = {};
    let all = null;
    for (const li of document.querySelectorAll('#legend li')) {
      const n = Number(li.querySelector('.count').textContent);
      if (li.classList.contains('all')) all = n;
      else legend[li.dataset.shape] = n;
    }
    return {
      featureCount: g.featureCount, shapes: g.shapes, tilesWithContent: g.tilesWithContent,
      legend, legendAll: all, frame: g.frame, tilesLoaded: g.tileset.tilesLoaded,
    };
  }));

  await frames(page);
  fs.mkdirSync(path.dirname(path.resolve(opt.screenshot)), { recursive: true });
  await page.screenshot({ path: opt.screenshot });
  result.screenshot = opt.screenshot;
  note('screenshot', opt.screenshot);

  // --- the legend highlights one shape ---------------------------------------------------------------------
  const shape = opt.highlight;
  const item = page.locator(`#legend li[data-shape="${shape}"]`);
  if ((await item.count()) !== 1) {
    problems.push(`no legend entry for ${shape}`);
  } else {
    await item.click();
    await frames(page, 3);
    // Read back, independently of the gallery's bookkeeping, which features CesiumJS colours orange.
    result.highlight = await page.evaluate((want) => {
      const ts = window.citylodGallery.tileset;
      const out = { shape: want, highlighted: {}, selectedItems: [] };
      const stack = [ts.root];
      while (stack.length) {
        const tile = stack.pop();
        if (tile.contentReady && tile.content) {
          const c = tile.content;
          for (let i = 0; i < c.featuresLength; i++) {
            const f = c.getFeature(i);
            const col = f.color;
            if (col.red > 0.99 && col.green > 0.3 && col.green < 0.5 && col.blue < 0.01 && col.alpha > 0.99) {
              const s = String(f.getProperty('roof_shape'));
              out.highlighted[s] = (out.highlighted[s] || 0) + 1;
            }
          }
        }
        for (const ch of tile.children || []) stack.push(ch);
      }
      out.selectedItems = [...document.querySelectorAll('#legend li.selected')].map((li) => li.dataset.shape);
      return out;
    }, shape);
    note('highlight', JSON.stringify(result.highlight));
    if (opt['highlight-screenshot']) {
      await page.screenshot({ path: opt['highlight-screenshot'] });
      result.highlightScreenshot = opt['highlight-screenshot'];
    }
    await item.click(); // the same entry again clears the highlight
    await frames(page, 3);
    result.selectedAfterToggle = await page.evaluate(
      () => [...document.querySelectorAll('#legend li.selected')].map((li) => li.dataset.shape));
  }

  // --- visibility audit ------------------------------------------------------------------------------------
  // Feature k gets code k+1 (0 would be "black in every pass", indistinguishable from a fully black pixel of
  // nothing; the ground and sky are magenta, so they are neither black nor white). One pass per bit: unlit,
  // feature colour replaces the material, white where the bit is set, black where not. "White" is 0.97 grey:
  // CesiumJS takes a pure white feature colour for "not styled" and keeps the material colour.
  result.visible = await page.evaluate(async () => {
    const g = window.citylodGallery;
    const scene = g.viewer.scene;
    const ts = g.tileset;
    ts.style = undefined;
    const feats = [];
    const seen = new Set();
    const stack = [ts.root];
    while (stack.length) {
      const tile = stack.pop();
      if (tile.contentReady && tile.content) {
        for (let i = 0; i < tile.content.featuresLength; i++) {
          const f = tile.content.getFeature(i);
          feats.push(f);
          seen.add(`${f.getProperty('osm_type')}/${f.getProperty('osm_id')}`);
        }
      }
      for (const ch of tile.children || []) stack.push(ch);
    }
    const render = (n = 3) => new Promise((resolve) => {
      let i = 0;
      const remove = scene.postRender.addEventListener(() => {
        if (++i >= n) { remove(); resolve(); }
      });
    });
    await render();
    const MAGENTA = Cesium.Color.MAGENTA;
    scene.backgroundColor = MAGENTA;
    scene.globe.baseColor = MAGENTA;
    scene.highDynamicRange = false;
    ts.colorBlendMode = Cesium.Cesium3DTileColorBlendMode.REPLACE;
    ts.customShader = new Cesium.CustomShader({ lightingModel: Cesium.LightingModel.UNLIT });

    // Canvas pixels hidden behind the page's overlays do not count as visible.
    const canvas = scene.canvas;
    const cr = canvas.getBoundingClientRect();
    const sx = canvas.width / cr.width;
    const sy = canvas.height / cr.height;
    const covers = ['#panel', '#attribution', '.cesium-widget-credits', '.cesium-viewer-bottom']
      .flatMap((sel) => [...document.querySelectorAll(sel)])
      .map((el) => el.getBoundingClientRect())
      .filter((r) => r.width > 0 && r.height > 0)
      .map((r) => ({ x0: (r.left - cr.left) * sx, x1: (r.right - cr.left) * sx,
        y0: (r.top - cr.top) * sy, y1: (r.bottom - cr.top) * sy }));
    const W = canvas.width;
    const H = canvas.height;
    const usable = new Uint8Array(W * H);
    for (let y = 0; y < H; y++) {
      for (let x = 0; x < W; x++) {
        usable[y * W + x] = covers.some((r) => x >= r.x0 && x < r.x1 && y >= r.y0 && y < r.y1) ? 0 : 1;
      }
    }
    const code = new Int32Array(W * H);
    const bits = Math.ceil(Math.log2(feats.length + 1));
    const scratch = document.createElement('canvas');
    scratch.width = W;
    scratch.height = H;
    const c2 = scratch.getContext('2d', { willReadFrequently: true });
    const ON = new Cesium.Color(0.97, 0.97, 0.97, 1);
    for (let b = 0; b < bits; b++) {
      feats.forEach((f, k) => { f.color = ((k + 1) >> b) & 1 ? ON : Cesium.Color.BLACK; });
      await render(3);
      c2.clearRect(0, 0, W, H);
      c2.drawImage(canvas, 0, 0);
      const px = c2.getImageData(0, 0, W, H).data;
      for (let i = 0; i < W * H; i++) {
        if (code[i] < 0) continue;
        const r = px[4 * i];
        const gg = px[4 * i + 1];
        const bb = px[4 * i + 2];
        if (r > 190 && gg > 190 && bb > 190) code[i] |= 1 << b;
        else if (!(r < 50 && gg < 50 && bb < 50)) code[i] = -1; // ground, sky or an anti-aliased edge
      }
    }
    // Per feature: its pixel count, and the pixel of it nearest to its centroid (a point to click it at).
    const acc = new Map();
    for (let i = 0; i < W * H; i++) {
      if (!(code[i] > 0 && usable[i])) continue;
      const a = acc.get(code[i]) || { n: 0, sx: 0, sy: 0 };
      a.n += 1;
      a.sx += i % W;
      a.sy += Math.floor(i / W);
      acc.set(code[i], a);
    }
    for (const a of acc.values()) {
      a.cx = a.sx / a.n;
      a.cy = a.sy / a.n;
      a.best = Infinity;
    }
    for (let i = 0; i < W * H; i++) {
      const a = code[i] > 0 && usable[i] ? acc.get(code[i]) : undefined;
      if (!a) continue;
      const x = i % W;
      const y = Math.floor(i / W);
      const d = (x - a.cx) ** 2 + (y - a.cy) ** 2;
      if (d < a.best) Object.assign(a, { best: d, x, y });
    }
    const MIN_PIXELS = 12; // a building must show as a patch, not a few stray pixels
    const perFeature = {};
    for (const [c, a] of acc) {
      const f = feats[c - 1];
      if (!f) continue; // a code no feature has: pixels mixed from several features
      const key = `${f.getProperty('osm_type')}/${f.getProperty('osm_id')}`;
      const prev = perFeature[key];
      if (prev && prev.pixels >= a.n) continue;
      // page (CSS) coordinates of the click point
      perFeature[key] = { pixels: a.n, roof_shape: String(f.getProperty('roof_shape')),
        x: cr.left + (a.x + 0.5) / sx, y: cr.top + (a.y + 0.5) / sy };
    }
    const shown = [...seen].filter((k) => perFeature[k] && perFeature[k].pixels >= MIN_PIXELS);
    const hidden = [...seen].filter((k) => !shown.includes(k));
    const counts = Object.values(perFeature).map((v) => v.pixels);
    return { features: seen.size, shown: shown.length, hidden, minPixelsRequired: MIN_PIXELS,
      minPixels: counts.length ? Math.min(...counts) : 0, perFeature };
  });
  note('visible', result.visible.shown, 'of', result.visible.features);

  // --- clicking a building highlights its shape ------------------------------------------------------------
  // The biggest on-screen building of --pick-shape, clicked at the point the audit found for it.
  const candidates = Object.entries(result.visible.perFeature)
    .filter(([, v]) => v.roof_shape === opt['pick-shape'])
    .sort((a, b) => b[1].pixels - a[1].pixels);
  if (!candidates.length) {
    problems.push(`no visible building with roof_shape ${opt['pick-shape']} to click`);
  } else {
    const [key, at] = candidates[0];
    await page.mouse.click(at.x, at.y);
    await frames(page, 3);
    result.pick = { feature: key, x: Math.round(at.x), y: Math.round(at.y), ...await page.evaluate(() => ({
      text: document.getElementById('picked').hidden ? null : document.getElementById('picked').textContent,
      selected: window.citylodGallery.selected,
      selectedItems: [...document.querySelectorAll('#legend li.selected')].map((li) => li.dataset.shape),
    })) };
    note('pick', JSON.stringify(result.pick));
  }
} catch (e) {
  problems.push(e.message.split('\n')[0]);
} finally {
  if (browser) await browser.close();
}

finish(result, problems);
