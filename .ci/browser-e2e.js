// Drives the built-in page in headless Chromium with playwright-core (installed by check-browser.sh into a
// temporary directory, found through NODE_PATH): drags the virtual hand in the top view and checks the
// server's hand target follows, sets the stiffness, scales a mode and checks that a refused change shows the
// server's error inline; then on a 390 x 844 phone screen checks that nothing is wider than the screen, that the
// on/off switch, peak strength and breakpoints work, that slices stay under 200 KiB/s and the status line and
// stream rate show; that the proxy marker is drawn on top of the probe's and both stay visible when they
// coincide; then that a wrong token is said and a drag with it sends nothing.
// Usage: node browser-e2e.js BASE_URL TOKEN CHROMIUM_PATH
'use strict';
const { chromium } = require('playwright-core');

const [base, token, executablePath] = process.argv.slice(2);
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

async function state() {
  const res = await fetch(base + '/api/state');
  if (!res.ok) throw new Error('/api/state: HTTP ' + res.status);
  return res.json();
}

async function until(what, predicate, timeoutMs) {
  // Generous deadlines: on a loaded CI machine the page, the server and the browser all run late; a check
  // waits for what it looks for and fails only when it never comes.
  const end = Date.now() + Math.max(timeoutMs || 0, 30000);
  let last;
  while (Date.now() < end) {
    last = await predicate();
    if (last) return last;
    await sleep(100);
  }
  throw new Error('timed out waiting for ' + what);
}

async function sceneMode(name) {
  const sc = await (await fetch(base + '/api/scene')).json();
  return sc.modes.find((m) => (m.name || m.kind) === name);
}

// A phone (390 x 844): nothing wider than the screen, and the controls work there; the slice traffic stays
// within its budget and the page shows the stream's real rate.
async function phone(browser, check) {
  const page = await browser.newPage({ viewport: { width: 390, height: 844 }, deviceScaleFactor: 2 });
  const pageErrors = [];
  page.on('pageerror', (e) => pageErrors.push(String(e)));
  const slices = [];
  page.on('response', async (res) => {
    if (!res.url().includes('/api/slice')) return;
    try {
      slices.push({ t: Date.now(), bytes: (await res.body()).length });
    } catch (e) {
      /* page closed */
    }
  });
  await page.goto(base + '/?token=' + encodeURIComponent(token));
  await page.waitForFunction(() => Number(document.getElementById('st-tick').dataset.tick) > 0, null, { timeout: 60000 });
  await sleep(1500);
  const widths = await page.evaluate(() => {
    const wide = [];
    for (const el of document.querySelectorAll('body *')) {
      const r = el.getBoundingClientRect();
      if (r.width > 0 && r.right > window.innerWidth + 0.5) wide.push(el.tagName.toLowerCase() + (el.id ? '#' + el.id : '') + ' ' + Math.round(r.right));
    }
    return { scroll: document.documentElement.scrollWidth, inner: window.innerWidth, wide: wide.slice(0, 5) };
  });
  check(widths.scroll <= widths.inner && widths.wide.length === 0,
    'no horizontal overflow at 390x844: page ' + widths.scroll + ' px wide for a ' + widths.inner + ' px screen' +
      (widths.wide.length ? '; too wide: ' + widths.wide.join(', ') : ''));

  const status = await page.textContent('#status-line');
  check(/^connected/.test(status) && /control token accepted/.test(status), 'the status line: ' + status);
  await until('the measured stream rate', async () => /states\/s received/.test(await page.textContent('#st-stream')), 4000);
  check(true, 'the real stream rate is shown: ' + (await page.textContent('#st-stream')));

  // The on/off switch of the first mode with a transfer function: off keeps the breakpoints.
  const scene = await (await fetch(base + '/api/scene')).json();
  const index = (scene.modes || []).findIndex((m) => Array.isArray(m.transfer));
  if (index >= 0) {
    const name = scene.modes[index].name || scene.modes[index].kind;
    const before = JSON.stringify((await sceneMode(name)).transfer);
    await page.locator('#mode-' + index + '-on').scrollIntoViewIfNeeded();
    await page.click('#mode-' + index + '-on');
    await until(name + ' off', async () => (await sceneMode(name)).enabled === false);
    check(JSON.stringify((await sceneMode(name)).transfer) === before, 'the switch turns ' + name + ' off and keeps its breakpoints ' + before);
    await page.click('#mode-' + index + '-on');
    await until(name + ' on', async () => (await sceneMode(name)).enabled === undefined);
    check(true, 'the switch turns ' + name + ' on again');
    // Peak 0 and back: the breakpoints' shape survives (issue 17).
    await page.fill('#mode-' + index + '-peak', '0');
    await page.press('#mode-' + index + '-peak', 'Enter');
    await until(name + ' off by peak 0', async () => (await sceneMode(name)).enabled === false);
    await page.fill('#mode-' + index + '-peak', '2');
    await page.press('#mode-' + index + '-peak', 'Enter');
    const back = await until(name + ' on at peak 2', async () => {
      const m = await sceneMode(name);
      return m.enabled === undefined && Math.abs(Math.max(...m.transfer.map((p) => p[1])) - 2) < 1e-9 ? m : null;
    });
    const shape = (t) => JSON.stringify(t.map((p) => [p[0], Number((p[1] / Math.max(...t.map((q) => q[1]))).toFixed(9))]));
    check(shape(back.transfer) === shape(JSON.parse(before)), 'peak 0 and back to 2 N keeps the shape: ' + JSON.stringify(back.transfer));
    // Breakpoints typed in the field.
    await page.fill('#mode-' + index + '-points', '[[0, 0], [0.5, 0.7], [1, 0.9]]');
    await page.press('#mode-' + index + '-points', 'Enter');
    await until('the typed breakpoints', async () => JSON.stringify((await sceneMode(name)).transfer) === '[[0,0],[0.5,0.7],[1,0.9]]');
    check(true, 'the breakpoints field sets ' + name + "'s transfer function");
  }

  // Slice traffic over 4 s, while the arm moves: at most 200 KiB in any second.
  slices.length = 0;
  await sleep(4000);
  let worst = 0;
  for (const s of slices) worst = Math.max(worst, slices.filter((o) => o.t >= s.t && o.t < s.t + 1000).reduce((a, o) => a + o.bytes, 0));
  const total = slices.reduce((a, o) => a + o.bytes, 0);
  check(worst <= 200 * 1024 * 1.05, 'slices: ' + slices.length + ' answers, ' + (total / 4 / 1024).toFixed(1) + ' KiB/s on average, at most ' + (worst / 1024).toFixed(1) + ' KiB in one second');
  if (process.env.KEEP_SCREENSHOTS) {
    await page.screenshot({ path: process.env.KEEP_SCREENSHOTS + '/phone-390x844.png', fullPage: true });
  }
  check(pageErrors.length === 0, 'no script errors on the phone' + (pageErrors.length ? ': ' + pageErrors.join('; ') : ''));
  await page.close();
}

// The badge follows rate changes; while the WebSocket is down the status panel says its numbers are stale, and
// live again it does not; a recording that stopped on an error shows the server's recording_error (the page is
// given one through /api/stats and /api/scene answers rewritten in the browser: no disk is filled here).
async function badgeStaleAndRecordingError(browser, check) {
  const page = await browser.newPage({ viewport: { width: 1280, height: 900 } });
  const pageErrors = [];
  page.on('pageerror', (e) => pageErrors.push(String(e)));
  await page.goto(base + '/?token=' + encodeURIComponent(token));
  await until('a state on the page', async () => page.evaluate(() => Number(document.getElementById('st-tick').dataset.tick) > 0));
  await until('the badge at 60 Hz', async () => /60 Hz/.test(await page.textContent('#conn-text')));
  await page.selectOption('#rate', '30');
  const badge = await until('the badge at 30 Hz', async () => {
    const text = await page.textContent('#conn-text');
    return /30 Hz/.test(text) ? text : null;
  });
  check(true, 'the badge follows the rate change: ' + JSON.stringify(badge));
  await page.evaluate(() => window.voxhapPage.dropConnection());
  const stale = await until('the status panel marked stale', async () => {
    const heading = await page.textContent('#status-h');
    const marked = await page.evaluate(() => document.querySelector('dl.status').classList.contains('stale'));
    return marked && /stale/.test(heading) ? heading : null;
  });
  check(true, 'disconnected, the status panel says ' + JSON.stringify(stale));
  await until('live again and not stale', async () => (await page.textContent('#status-h')) === 'Status' &&
    /^live/.test(await page.textContent('#conn-text')));
  check(true, 'reconnected, the stale mark is gone');
  const reason = 'cannot write /tmp/x.mcap: No space left on device (os error 28)';
  await page.route('**/api/stats', async (route) => {
    const res = await route.fetch();
    const body = await res.json();
    body.servo = Object.assign({}, body.servo, { recorder_errors: 1 });
    await route.fulfill({ response: res, json: body });
  });
  await page.route('**/api/scene', async (route) => {
    const res = await route.fetch();
    const body = await res.json();
    body.recording = '/tmp/x.mcap';
    body.recording_error = reason;
    await route.fulfill({ response: res, json: body });
  });
  const shown = await until('the recording error on the page', async () => {
    const text = await page.textContent('#st-rec');
    return text.includes(reason) ? text : null;
  });
  check(/STOPPED/.test(shown), 'the page shows the recording error: ' + JSON.stringify(shown));
  check(pageErrors.length === 0, 'no script errors' + (pageErrors.length ? ': ' + pageErrors.join('; ') : ''));
  await page.close();
}

// The probe and proxy markers (issue 17: they overlapped at the proxy). The proxy is drawn last, a filled dot
// inside the probe's hollow ring, and a view says "proxy on probe" when they coincide. Checked on the page's
// own layout numbers and on the canvas pixels, with the simulated hand held in free space (no contact, so the
// proxy sits on the probe).
async function markers(browser, check) {
  const page = await browser.newPage({ viewport: { width: 1280, height: 900 } });
  await page.goto(base + '/?token=' + encodeURIComponent(token));
  await page.waitForFunction(() => Number(document.getElementById('st-tick').dataset.tick) > 0, null, { timeout: 60000 });
  const geometry = await page.evaluate(() => window.voxhapPage.markerLayout([100, 100], [100, 100], 0, 0));
  // In contact the markers may overlap on screen with the proxy 916 um away and 0.46 N sent: not "on probe".
  const contact = await page.evaluate(() => window.voxhapPage.markerLayout([100, 100], [101, 100], 916e-6, 0.46));
  check(contact.label !== 'proxy on probe' && /in contact/.test(contact.label),
    'overlapping markers in contact (916 um, 0.46 N) are labelled ' + JSON.stringify(contact.label));
  // The ring's inner edge (radius less half its line and its 1.25 px outline) clears the dot and its outline.
  const clearance = geometry.probeRadius - geometry.probeLine / 2 - 1.25 - (geometry.proxyRadius + geometry.proxyLine / 2);
  check(clearance >= 1 && geometry.label === 'proxy on probe',
    'coinciding markers: a ' + geometry.proxyRadius + ' px proxy dot inside a ' + geometry.probeRadius + ' px probe ring, ' +
      clearance.toFixed(2) + ' px clear of each other, labelled ' + JSON.stringify(geometry.label));
  const scene = await (await fetch(base + '/api/scene')).json();
  const volume = (scene.volumes || [])[0];
  if (!scene.simulated || !volume) {
    console.log('skip: live marker check needs the simulated arm and a volume');
    await page.close();
    return;
  }
  // A corner of the volume, far from the built-in ball: no primitive there, so the proxy follows the probe.
  const corner = [0, 1, 2].map((i) => volume.min_m[i] + 0.08 * (volume.max_m[i] - volume.min_m[i]));
  const post = (body) => fetch(base + '/api/hand', { method: 'POST', headers: { Authorization: 'Bearer ' + token }, body: JSON.stringify(body) });
  check((await post({ position_m: corner })).ok, 'the hand is held at ' + JSON.stringify(corner.map((x) => Number(x.toFixed(4)))));
  const seen = await until('the proxy on the probe in the top view', async () => page.evaluate(() => {
    const m = window.voxhapPage.markers()[0].markers;
    if (!m || !m.layout.label) return null;
    // Read the canvas in the same task as the layout it was drawn with.
    const canvas = document.getElementById('view-z');
    const ctx = canvas.getContext('2d');
    const dpr = canvas.width / canvas.getBoundingClientRect().width;
    const at = (x, y) => Array.from(ctx.getImageData(Math.round(x * dpr), Math.round(y * dpr), 1, 1).data.slice(0, 3));
    return {
      m: m,
      proxyPixel: at(m.proxy[0], m.proxy[1]),
      // The ring in each compass direction: the brightest pixel within 2 px of its centre line, because one
      // sampled pixel can fall on the antialiased edge of a 2 px line at a fractional position (a CI run saw
      // [138,138,138] at the top). Brightness is the smallest channel, so the yellow proxy dot never counts.
      ring: [[0, -1], [1, 0], [0, 1], [-1, 0]].map(([dx, dy]) => {
        let best = [0, 0, 0];
        for (let d = -2; d <= 2; d += 0.5) {
          const p = at(m.probe[0] + dx * (m.layout.probeRadius + d), m.probe[1] + dy * (m.layout.probeRadius + d));
          if (Math.min(...p) > Math.min(...best)) best = p;
        }
        return best;
      }),
      proxyColour: getComputedStyle(document.documentElement).getPropertyValue('--scene-proxy').trim(),
    };
  }), 10000);
  await post({ position_m: null });
  const hex = (c) => [1, 3, 5].map((i) => parseInt(c.slice(i, i + 2), 16));
  const near = (a, b) => a.every((x, i) => Math.abs(x - b[i]) <= 40);
  check(seen.m.order[seen.m.order.length - 1] === 'proxy', 'the proxy is drawn last: ' + seen.m.order.join(' < '));
  check(near(seen.proxyPixel, hex(seen.proxyColour)),
    'the proxy dot shows on top at the proxy: pixel ' + JSON.stringify(seen.proxyPixel) + ', proxy colour ' + seen.proxyColour);
  check(seen.ring.every((p) => p.every((x) => x >= 200)),
    'the probe ring shows around it (' + seen.m.layout.apartPx.toFixed(2) + ' px apart): brightest pixels above, right, below, left ' + JSON.stringify(seen.ring) +
      ', label ' + JSON.stringify(seen.m.layout.label));
  await page.close();
}

// A wrong token: the page says so, and dragging sends nothing (no storm of refused requests).
async function refusedToken(browser, check) {
  const page = await browser.newPage({ viewport: { width: 1280, height: 900 } });
  let controlRequests = 0;
  page.on('request', (req) => {
    if (req.method() === 'POST' && !req.url().endsWith('/api/stiffness')) controlRequests += 1;
  });
  await page.goto(base + '/?token=wrong-' + encodeURIComponent(token));
  await page.waitForFunction(() => Number(document.getElementById('st-tick').dataset.tick) > 0, null, { timeout: 60000 });
  await until('the refused-token banner', async () => page.isVisible('#token-banner'), 5000);
  check(true, 'a refused token is said: ' + (await page.textContent('#token-banner')));
  const box = await page.locator('#view-z').boundingBox();
  await page.mouse.move(box.x + box.width / 2, box.y + box.height / 2);
  await page.mouse.down();
  for (let i = 1; i <= 12; i++) {
    await page.mouse.move(box.x + box.width / 2 + i * 6, box.y + box.height / 2);
    await sleep(30);
  }
  await page.mouse.up();
  await sleep(300);
  check(controlRequests === 0, 'a drag with a refused token sends no requests (' + controlRequests + ' sent): ' + (await page.textContent('#hand-msg')));
  check((await page.textContent('#status-line')).includes('REFUSED'), 'the status line says the token was refused');
  await page.close();
}

(async () => {
  const browser = await chromium.launch({
    executablePath,
    args: ['--no-sandbox', '--disable-gpu', '--disable-dev-shm-usage'],
  });
  let failed = false;
  const check = (ok, message) => {
    console.log((ok ? 'ok: ' : 'FAIL: ') + message);
    if (!ok) failed = true;
  };
  try {
    const page = await browser.newPage({ viewport: { width: 1280, height: 900 } });
    const pageErrors = [];
    page.on('pageerror', (e) => pageErrors.push(String(e)));
    await page.goto(base + '/?token=' + encodeURIComponent(token));
    await page.waitForFunction(() => Number(document.getElementById('st-tick').dataset.tick) > 0, null, { timeout: 60000 });
    check(true, 'the page shows ticks');
    check((await page.inputValue('#token')) === token, 'the token field is prefilled from ?token=');
    check(!page.url().includes('token='), 'the token is removed from the address bar');

    const scene = await (await fetch(base + '/api/scene')).json();
    if (scene.simulated) {
      // Drag in the top view from the centre towards the upper right, then release.
      const box = await page.locator('#view-z').boundingBox();
      const cx = box.x + box.width / 2;
      const cy = box.y + box.height / 2;
      await page.mouse.move(cx, cy);
      await page.mouse.down();
      for (let i = 1; i <= 10; i++) {
        await page.mouse.move(cx + i * 8, cy - i * 6);
        await sleep(30);
      }
      const held = await until('hand_target_m to be set', async () => {
        const s = await state();
        return s.hand_target_m ? s : null;
      });
      const [x, y] = held.hand_target_m;
      check(x > 0.005 && y > 0.003, 'dragging right and up pulls the hand to +x, +y: ' + JSON.stringify(held.hand_target_m));
      const probeZ = held.probe_m[2];
      check(Math.abs(held.hand_target_m[2] - probeZ) < 0.02, 'the out-of-view z stays near the probe z');
      await page.mouse.up();
      await until('hand_target_m to clear after release', async () => (await state()).hand_target_m === null);
      check(true, 'releasing sends position_m: null (the hand resumes its path)');
    } else {
      console.log('skip: the device is not simulated, no dragging');
    }

    // Stiffness through the number field.
    const k = Math.round(((await state()).stiffness_n_per_m || 500) * 0.8);
    await page.fill('#k-number', String(k));
    await page.press('#k-number', 'Enter');
    await until('stiffness ' + k, async () => Math.abs((await state()).stiffness_n_per_m - k) < 1e-6);
    check(true, 'the stiffness field sets k = ' + k + ' N/m');
    await page.fill('#b-number', '0.5');
    await page.press('#b-number', 'Enter');
    await until('damping 0.5', async () => Math.abs((await state()).damping_n_s_per_m - 0.5) < 1e-9);
    check(true, 'the damping field sets b = 0.5 N s/m');

    // A mode with a transfer function: scale its peak, then send bad breakpoints and expect the error inline.
    const index = (scene.modes || []).findIndex((m) => Array.isArray(m.transfer));
    if (index >= 0) {
      const name = scene.modes[index].name || scene.modes[index].kind;
      await page.fill('#mode-' + index + '-peak', '1.25');
      await page.press('#mode-' + index + '-peak', 'Enter');
      await until(name + ' peak 1.25 N', async () => {
        const sc = await (await fetch(base + '/api/scene')).json();
        const m = sc.modes.find((m) => (m.name || m.kind) === name);
        return m && Math.abs(Math.max(...m.transfer.map((p) => p[1])) - 1.25) < 1e-9;
      });
      check(true, 'the peak strength field rescales ' + name + "'s transfer function");
      // The scene generation changed, so the page fetched the scene again and shows the new breakpoints.
      await until('the page to show the rescaled breakpoints', async () =>
        (await page.inputValue('#mode-' + index + '-points')).includes('1.25'));
      check(true, 'the page rebuilt its mode controls from the new scene: ' + (await page.inputValue('#mode-' + index + '-points')));
      await page.fill('#mode-' + index + '-points', '[[0.5, 1.0], [0.2, 2.0]]');
      await page.press('#mode-' + index + '-points', 'Enter');
      const msg = page.locator('#mode-' + index + '-msg');
      await until('an inline error', async () => (await msg.getAttribute('class')).includes('error'));
      check(true, 'a refused transfer function shows the server error inline: ' + (await msg.textContent()));
    }
    check(pageErrors.length === 0, 'no script errors' + (pageErrors.length ? ': ' + pageErrors.join('; ') : ''));
    await page.close();

    await markers(browser, check);
    await badgeStaleAndRecordingError(browser, check);
    await phone(browser, check);
    await refusedToken(browser, check);
  } catch (e) {
    check(false, e.message);
  } finally {
    await browser.close();
  }
  process.exit(failed ? 1 : 0);
})();
