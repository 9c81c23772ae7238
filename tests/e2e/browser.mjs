// Headless Chromium for the e2e drivers (viewer_e2e.mjs, gallery_e2e.mjs, lod_views_e2e.mjs): a fresh profile
// (nothing cached, no state leaking between runs), the measured flag set (stack-notes §4: WebGL 2 through
// SwiftShader, no background traffic), and a record of every request host, failed request and console error of
// the page; startDriver holds what every driver does before and after its own checks.
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { chromium } from 'playwright-core';

export async function openBrowser({ chromiumPath, hosts, consoleErrors, failedRequests, note, tag }) {
  const udd = fs.mkdtempSync(path.join(os.tmpdir(), 'citylod-chromium-'));
  let ctx;
  const close = async () => {
    if (ctx) await ctx.close().catch(() => {});
    fs.rmSync(udd, { recursive: true, force: true });
  };
  try {
    ctx = await chromium.launchPersistentContext(udd, {
      executablePath: chromiumPath,
      headless: true,
      viewport: { width: 1280, height: 800 },
      deviceScaleFactor: 1,
      args: ['--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
        '--disable-background-networking', '--disable-component-update', '--disable-sync'],
    });
  } catch (e) {
    await close();
    throw e;
  }
  // Every network request of the page and its workers; data: and blob: URLs never leave the browser.
  ctx.on('request', (req) => {
    const u = new URL(req.url());
    if (u.protocol === 'http:' || u.protocol === 'https:' || u.protocol === 'ws:' || u.protocol === 'wss:') {
      hosts.add(u.host);
    }
  });
  ctx.on('requestfailed', (req) => failedRequests.push(`${req.url()}: ${req.failure()?.errorText}`));
  const page = ctx.pages()[0] || (await ctx.newPage());
  page.on('console', (m) => {
    if (m.type() === 'error') consoleErrors.push(m.text());
    if (m.type() === 'error' || m.text().startsWith(tag)) note('[page]', m.text());
  });
  page.on('pageerror', (e) => {
    consoleErrors.push(`pageerror: ${e.message}`);
    note('[pageerror]', e.message);
  });
  return { ctx, page, close };
}

// What every driver reports about the page's traffic; a request to another host than the server's is a problem.
function recordTraffic(result, problems, { hosts, consoleErrors, failedRequests, serverHost, seconds }) {
  result.hosts = [...hosts].sort();
  result.consoleErrors = consoleErrors;
  result.failedRequests = failedRequests;
  result.seconds = seconds;
  const foreign = result.hosts.filter((h) => h !== serverHost);
  if (foreign.length) problems.push(`requests to hosts other than ${serverHost}: ${foreign.join(', ')}`);
}

// A driver's start: its required options (exit 2 with the usage when one is missing), Chromium present (exit 1),
// a stopwatch for progress lines on stderr, and the traffic record. finish(result, problems) adds the traffic to
// the result, prints it as one JSON line and exits 1 with the problems on stderr when there are any.
export function startDriver(name, opt, required, usage) {
  for (const k of required) {
    if (!opt[k]) {
      console.error(`usage: node ${name}.mjs ${usage}   (missing --${k})`);
      process.exit(2);
    }
  }
  if (!fs.existsSync(opt.chromium)) {
    console.error(`chromium not found at ${opt.chromium}: install it with scripts/install-system.sh test`);
    process.exit(1);
  }
  const t0 = Date.now();
  const secs = () => ((Date.now() - t0) / 1000).toFixed(2);
  const note = (...a) => console.error(`${secs()}s`, ...a);
  const timeout = Number(opt.timeout);
  const traffic = { hosts: new Set(), consoleErrors: [], failedRequests: [], serverHost: new URL(opt.url).host };
  // Poll on a timer: the default (every animation frame) lags seconds behind when SwiftShader frames are slow.
  const WAIT = { timeout, polling: 200 };
  return {
    note,
    timeout,
    WAIT,
    open: (tag) => openBrowser({ chromiumPath: opt.chromium, ...traffic, note, tag }),
    // The viewer page at opt.url in a width x height viewport (the screen-space error depends on its height),
    // ready (window.citylod.ready) or thrown with the viewer's error.
    async openViewer(page, width, height) {
      await page.setViewportSize({ width, height });
      await page.goto(opt.url, { waitUntil: 'load', timeout });
      await page.waitForFunction(() => window.citylod && (window.citylod.ready || window.citylod.error), null, WAIT);
      const err = await page.evaluate(() => window.citylod.error);
      if (err) throw new Error(`viewer error: ${err}`);
      note('viewer ready');
    },
    // Write a page's canvas.toDataURL('image/png') to file.
    savePng: (dataUrl, file) => fs.writeFileSync(file, Buffer.from(dataUrl.replace(/^data:image\/png;base64,/, ''),
      'base64')),
    finish(result, problems) {
      recordTraffic(result, problems, { ...traffic, seconds: Number(secs()) });
      console.log(JSON.stringify(result));
      if (problems.length) {
        console.error(`${name} FAILED: ${problems.join('; ')}`);
        process.exit(1);
      }
    },
  };
}
