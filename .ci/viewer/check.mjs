// Opens voxhap's recordings and live view in Foxglove Studio 1.48 (the @foxglove/studio-base web bundle mounted by
// index.html/app.js) in headless Chromium with playwright-core, with the shipped layout, and fails on any problem
// the viewer reports or any panel of the layout left empty. Run by .ci/check-viewer.sh.
//
// Usage: node check.mjs NPM_DIR VIEWER_DIR LAYOUT CHROMIUM OUT_DIR TARGET...
//   NPM_DIR: where `npm ci` installed .ci/viewer/package-lock.json (node_modules); VIEWER_DIR: .ci/viewer;
//   TARGET: recording:FILE.mcap or live:ws://HOST:PORT. Screenshots go to OUT_DIR/<n>-<kind>.png.
import http from "node:http";
import fs from "node:fs";
import path from "node:path";
import { createRequire } from "node:module";

const [npmDir, viewerDir, layoutPath, chromiumPath, outDir, ...targets] = process.argv.slice(2);
const require = createRequire(path.join(path.resolve(npmDir), "package.json"));
const { chromium } = require("playwright-core");
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

// ---- A static HTTP server on 127.0.0.1 for the app, the bundle, the layout and the recordings (with byte ranges:
// Studio reads a remote MCAP file by ranges).
const recordings = new Map();
const types = { ".html": "text/html", ".js": "text/javascript", ".json": "application/json", ".wasm": "application/wasm",
  ".png": "image/png", ".ttf": "font/ttf", ".mcap": "application/octet-stream" };
function fileFor(urlPath) {
  if (urlPath === "/" || urlPath === "/index.html") return path.join(viewerDir, "index.html");
  if (urlPath === "/app.js") return path.join(viewerDir, "app.js");
  if (urlPath === "/layout.json") return layoutPath;
  if (urlPath.startsWith("/recordings/")) return recordings.get(urlPath);
  if (urlPath.startsWith("/node_modules/") && !urlPath.includes("..")) return path.join(npmDir, urlPath);
  return undefined;
}
const server = http.createServer((req, res) => {
  const urlPath = decodeURIComponent(new URL(req.url, "http://x").pathname);
  const file = fileFor(urlPath);
  if (!file || !fs.existsSync(file) || !fs.statSync(file).isFile()) {
    res.writeHead(404).end();
    return;
  }
  const size = fs.statSync(file).size;
  const headers = { "content-type": types[path.extname(file)] || "application/octet-stream", "accept-ranges": "bytes",
    "access-control-allow-origin": "*", "cache-control": "no-store" };
  const range = /^bytes=(\d+)-(\d*)$/.exec(req.headers.range || "");
  if (range) {
    const start = Number(range[1]);
    const end = range[2] ? Math.min(Number(range[2]), size - 1) : size - 1;
    if (start >= size || end < start) {
      res.writeHead(416, { "content-range": `bytes */${size}` }).end();
      return;
    }
    res.writeHead(206, { ...headers, "content-length": end - start + 1, "content-range": `bytes ${start}-${end}/${size}` });
    if (req.method === "HEAD") return res.end();
    fs.createReadStream(file, { start, end }).pipe(res);
    return;
  }
  res.writeHead(200, { ...headers, "content-length": size });
  if (req.method === "HEAD") return res.end();
  fs.createReadStream(file).pipe(res);
});
await new Promise((r) => server.listen(0, "127.0.0.1", r));
const base = `http://127.0.0.1:${server.address().port}`;

// The first and last message log times (ns) from an MCAP file's Statistics record, found through its footer
// (MCAP specification: footer = opcode 0x02, length, summary_start, summary_offset_start, crc; then the magic).
function mcapTimeRange(file) {
  const b = fs.readFileSync(file);
  const footer = b.length - 8 - 29;
  if (b.length < 8 + 29 || b[footer] !== 0x02) throw new Error(`${file}: no MCAP footer`);
  const summaryStart = Number(b.readBigUInt64LE(footer + 9));
  if (summaryStart === 0) throw new Error(`${file}: no summary section`);
  for (let o = summaryStart; o < footer;) {
    const op = b[o];
    const len = Number(b.readBigUInt64LE(o + 1));
    if (op === 0x0b) {
      const r = o + 9 + 8 + 2 + 4 + 4 + 4 + 4; // message, schema, channel, attachment, metadata, chunk counts
      return { start: b.readBigUInt64LE(r), end: b.readBigUInt64LE(r + 8) };
    }
    o += 9 + len;
  }
  throw new Error(`${file}: no Statistics record in the summary`);
}
const rfc3339 = (ns) => {
  const s = new Date(Number(ns / 1000000000n) * 1000).toISOString().replace(/\.000Z$/, "");
  return `${s}.${String(ns % 1000000000n).padStart(9, "0")}Z`;
};

// ---- What the viewer shows: every way Studio 1.48 reports a problem, and whether each panel drew its data.
const layout = JSON.parse(fs.readFileSync(layoutPath, "utf8"));
const panelIds = Object.keys(layout.configById);

// Pixel figures of a screenshot, computed in the page (a PNG decoded into a canvas): the share of coloured
// pixels (max - min channel >= 48: the data's colours, not the grey background, grid, text or frame lines) and
// how many pixels lie within 40 of each given colour.
async function pixelStats(page, png, colours) {
  return page.evaluate(async ([b64, colours]) => {
    const img = new Image();
    img.src = `data:image/png;base64,${b64}`;
    await img.decode();
    const c = document.createElement("canvas");
    c.width = img.width;
    c.height = img.height;
    const ctx = c.getContext("2d");
    ctx.drawImage(img, 0, 0);
    const d = ctx.getImageData(0, 0, c.width, c.height).data;
    const rgb = colours.map((h) => [1, 3, 5].map((i) => parseInt(h.slice(i, i + 2), 16)));
    const near = rgb.map(() => 0);
    let coloured = 0;
    for (let i = 0; i < d.length; i += 4) {
      const [r, g, b] = [d[i], d[i + 1], d[i + 2]];
      if (Math.max(r, g, b) - Math.min(r, g, b) >= 48) coloured += 1;
      rgb.forEach(([R, G, B], k) => {
        if (Math.abs(r - R) <= 40 && Math.abs(g - G) <= 40 && Math.abs(b - B) <= 40) near[k] += 1;
      });
    }
    return { pixels: d.length / 4, coloured: coloured / (d.length / 4), near };
  }, [png.toString("base64"), colours]);
}

const panelBox = (page, id) => page.locator(`[data-testid="panel-mouseenter-container ${id}"]`);

// Whether a panel shows its data, and the figures that say so. Each panel type of the layout has its rule; a
// type without one fails the check (a new panel in the layout needs a rule here).
async function panelFilled(page, id) {
  const type = id.split("!")[0];
  const config = layout.configById[id];
  const box = panelBox(page, id);
  if ((await box.count()) !== 1) return { ok: false, what: "not on the page" };
  const text = await box.innerText();
  if (text.includes("This panel encountered an unexpected error")) return { ok: false, what: "the panel crashed" };
  // The panel's drawing: its largest canvas (the 3D view, the chart).
  const canvases = box.locator("canvas");
  let best;
  for (let k = 0; k < (await canvases.count()); k += 1) {
    const bb = await canvases.nth(k).boundingBox();
    if (bb && bb.width * bb.height > (best ? best.width * best.height : 0)) best = bb;
  }
  // Everything else in the panel (a floating legend, labels, tooltips) is hidden while the picture is taken.
  const hide = (on) => box.evaluate((root, on) => {
    for (const el of root.querySelectorAll("*")) {
      if (on && !(el instanceof HTMLCanvasElement) && !el.querySelector("canvas")) {
        el.dataset.viewerCheckVisibility = el.style.visibility;
        el.style.visibility = "hidden";
      } else if (!on && "viewerCheckVisibility" in el.dataset) {
        el.style.visibility = el.dataset.viewerCheckVisibility;
        delete el.dataset.viewerCheckVisibility;
      }
    }
  }, on);
  await hide(true);
  const png = best ? await page.screenshot({ clip: best }) : await box.screenshot();
  await hide(false);
  if (type === "3D") {
    const s = await pixelStats(page, png, []);
    return { ok: s.coloured >= 0.01, what: `${(100 * s.coloured).toFixed(1)}% coloured pixels (needs 1%)` };
  }
  if (type === "Plot") {
    const paths = config.paths.filter((p) => p.enabled !== false);
    const s = await pixelStats(page, png, paths.map((p) => p.color));
    // The legend shows each series' value at the playback time (showPlotValuesInLegend): a number once data came.
    const numbers = text.split("\n").filter((l) => /^-?\d+(\.\d+)?(e[-+]?\d+)?$/i.test(l.trim()));
    const drawn = s.near.reduce((a, b) => a + b, 0);
    return { ok: numbers.length >= paths.length && drawn >= 30,
      what: `${numbers.length}/${paths.length} legend values, ${drawn} pixels in the series' colours (needs 30)` };
  }
  if (type === "StateTransitions") {
    const s = await pixelStats(page, png, []);
    return { ok: s.coloured >= 0.005, what: `${(100 * s.coloured).toFixed(1)}% coloured pixels (needs 0.5%)` };
  }
  if (type === "RawMessages") {
    const waiting = /Waiting for next message|No messages|No topic selected/.test(text);
    const lines = text.split("\n").filter((l) => l.trim() !== "").length;
    return { ok: !waiting && lines >= 4, what: waiting ? "waiting for a message" : `${lines} lines of message fields` };
  }
  return { ok: false, what: `the check has no rule for a ${type} panel` };
}

// The problems a data source reports (the data source sidebar's Problems tab; its count is also the badge on the
// sidebar's data source button).
async function playerProblems(page) {
  const tab = page.getByRole("tab", { name: /Problems/ });
  if (!(await tab.isVisible())) await page.locator('[data-sidebar-key="connection"]').click();
  await tab.click();
  await page.waitForTimeout(300);
  const body = await page.locator("body").innerText();
  await page.getByRole("tab", { name: /Topics/ }).click();
  if (body.includes("No problems found")) return [];
  const shown = body.slice(body.indexOf("Problems"), body.indexOf("Problems") + 2000);
  return [`the data source reports problems (${(await tab.innerText()).replace(/\s+/g, " ")}):\n${shown}`];
}

// The errors a panel's settings tree shows (e.g. a 3D topic or display frame that cannot be drawn).
async function settingsErrors(page, id) {
  const box = panelBox(page, id);
  const gear = box.locator('button:has(svg[data-testid="SettingsIcon"])').first();
  if ((await gear.count()) === 0) return [];
  await gear.click();
  await page.waitForTimeout(500);
  if (process.env.VIEWER_DEBUG) await page.screenshot({ path: path.join(outDir, `settings-${id.replace(/\W/g, "_")}.png`) });
  const errors = [];
  // A node's error (an error button in its header) or a field's (an error icon by its label).
  const icons = page.locator('button.MuiIconButton-colorError:has(svg[data-testid="ErrorIcon"]):visible, ' +
    'svg.MuiSvgIcon-colorError[data-testid="ErrorIcon"]:visible');
  for (let k = 0; k < (await icons.count()); k += 1) {
    await icons.nth(k).hover();
    const tip = page.locator('[role="tooltip"]').last();
    await tip.waitFor({ timeout: 3000 }).catch(() => {});
    errors.push(`${id} settings: ${(await tip.count()) ? await tip.innerText() : "an error icon (no text)"}`);
  }
  return errors;
}

const browser = await chromium.launch({ executablePath: chromiumPath, headless: true,
  args: ["--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"] });
let failed = false;
try {
  for (const [i, target] of targets.entries()) {
    const kind = target.slice(0, target.indexOf(":"));
    const where = target.slice(target.indexOf(":") + 1);
    let url;
    const label = `${kind} ${kind === "recording" ? path.basename(where) : where}`;
    if (kind === "recording") {
      const p = `/recordings/${i}-${path.basename(where)}`;
      recordings.set(p, where);
      // Opened at its last message (the viewer seeks there, as a user does to see it all): the stats arrive last,
      // and the plots follow the last 10 s.
      const { start, end } = mcapTimeRange(where);
      url = `${base}/?ds=remote-file&ds.url=${encodeURIComponent(base + p)}&layoutId=voxhap&time=${rfc3339(end)}`;
      console.log(`${label}: messages from ${rfc3339(start)} to ${rfc3339(end)} (the file's statistics record)`);
    } else if (kind === "live") {
      url = `${base}/?ds=foxglove-websocket&ds.url=${encodeURIComponent(where)}&layoutId=voxhap`;
    } else {
      throw new Error(`unknown target ${target}`);
    }
    const page = await browser.newPage({ viewport: { width: 1280, height: 800 } });
    const problems = [];
    page.on("pageerror", (e) => problems.push(`page error: ${e.stack || e}`));
    page.on("console", (m) => {
      if (m.type() === "error") problems.push(`console error: ${m.text()}`);
    });
    // Nothing leaves the machine: a request to any other host is refused, and is a failure.
    await page.route("**/*", (route) => {
      const u = new URL(route.request().url());
      if (u.hostname === "127.0.0.1" || u.protocol === "data:" || u.protocol === "blob:") return route.continue();
      problems.push(`a request off the machine: ${route.request().url()}`);
      return route.abort();
    });
    // Every notification Studio pops up (notistack snackbars: errors and warnings from the player and panels).
    await page.addInitScript(() => {
      window.__viewerToasts = [];
      new MutationObserver(() => {
        for (const el of document.querySelectorAll("#notistack-snackbar, .SnackbarItem-message")) {
          const t = el.textContent;
          if (t && !window.__viewerToasts.includes(t)) window.__viewerToasts.push(t);
        }
      }).observe(document, { childList: true, subtree: true });
    });
    const t0 = Date.now();
    await page.goto(url);
    // The layout is up when every panel of it is on the page.
    for (const id of panelIds) await panelBox(page, id).waitFor({ timeout: 60000 });
    const tLayout = Date.now() - t0;
    // Every panel must show its data within 90 s (generous for a loaded CI machine: the check fails only when
    // a panel never fills).
    let status = {};
    const deadline = Date.now() + 90000;
    for (;;) {
      status = {};
      for (const id of panelIds) status[id] = await panelFilled(page, id);
      if (Object.values(status).every((s) => s.ok) || Date.now() > deadline) break;
      await page.waitForTimeout(1000);
    }
    const tFilled = Date.now() - t0;
    await page.screenshot({ path: path.join(outDir, `${i}-${kind}.png`) });
    console.log(`${label}: layout up in ${(tLayout / 1000).toFixed(1)} s, panels checked at ${(tFilled / 1000).toFixed(1)} s;` +
      ` screenshot ${i}-${kind}.png`);
    for (const id of panelIds) {
      console.log(`  ${status[id].ok ? "ok   " : "EMPTY"} ${id}: ${status[id].what}`);
      if (!status[id].ok) failed = true;
    }
    problems.push(...(await playerProblems(page)));
    for (const id of panelIds) problems.push(...(await settingsErrors(page, id)));
    problems.push(...(await page.evaluate(() => window.__viewerErrors || [])));
    problems.push(...(await page.evaluate(() => window.__viewerToasts || [])).map((t) => `notification: ${t}`));
    for (const p of problems) console.log(`  PROBLEM ${p}`);
    if (problems.length) failed = true;
    await page.close();
  }
} finally {
  await browser.close();
  server.close();
}
process.exit(failed ? 1 : 0);
