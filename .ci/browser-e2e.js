// Drives the built-in page in headless Chromium with playwright-core (installed by check-browser.sh into a
// temporary directory, found through NODE_PATH): drags the virtual hand in the top view and checks the
// server's hand target follows, sets the stiffness, scales a mode and checks that a refused change shows the
// server's error inline. Usage: node browser-e2e.js BASE_URL TOKEN CHROMIUM_PATH
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
  const end = Date.now() + (timeoutMs || 5000);
  let last;
  while (Date.now() < end) {
    last = await predicate();
    if (last) return last;
    await sleep(100);
  }
  throw new Error('timed out waiting for ' + what);
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
    await page.waitForFunction(() => Number(document.getElementById('st-tick').dataset.tick) > 0, null, { timeout: 10000 });
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
  } catch (e) {
    check(false, e.message);
  } finally {
    await browser.close();
  }
  process.exit(failed ? 1 : 0);
})();
