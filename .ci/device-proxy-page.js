// The page's "Device proxy" line with a local-model device (run by .ci/device_proxy_check.py, which starts the
// capable mock and serve): opens the page in headless Chromium with playwright-core (found through NODE_PATH) and
// waits, up to 180 s, until the line (#st-device-proxy) shows a proxy, its bound and the model's number and age,
// while /api/state, read right before and after, reports the device's proxy within 0.2 mm of the one shown. The
// page stays open, so a loaded machine's dropped ticks (which carry no device report) only delay the check.
// Prints the line it saw; exits 1 with what the page showed when it never matched.
// Usage: node device-proxy-page.js BASE_URL CHROMIUM_PATH
'use strict';
const { chromium } = require('playwright-core');

const [base, executablePath] = process.argv.slice(2);
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
const NUMBER = '(-?\\d+(?:\\.\\d+)?)';
const LINE = new RegExp('\\(' + NUMBER + ', ' + NUMBER + ', ' + NUMBER + '\\) mm, ≤ [^,]+, model (\\d+) ' + NUMBER + ' ms old');
const TOLERANCE_MM = 0.2;

async function deviceProxyMm() {
  try {
    const res = await fetch(base + '/api/state');
    const s = await res.json();
    return s.device_local ? s.device_local.proxy_m.map((c) => c * 1000) : null;
  } catch (e) {
    return null;
  }
}

(async () => {
  const browser = await chromium.launch({ executablePath, args: ['--no-sandbox', '--disable-gpu', '--disable-dev-shm-usage'] });
  let last = '(the page never loaded)';
  try {
    const page = await browser.newPage();
    await page.goto(base + '/');
    await page.waitForFunction(() => Number(document.getElementById('st-tick').dataset.tick) > 0, null, { timeout: 120000 });
    const end = Date.now() + 180000;
    while (Date.now() < end) {
      const before = await deviceProxyMm();
      const text = (await page.textContent('#st-device-proxy')) || '';
      const after = await deviceProxyMm();
      last = text;
      const shown = LINE.exec(text);
      if (shown && before && after) {
        const mm = [1, 2, 3].map((i) => Number(shown[i]));
        const near = (api) => api.every((a, i) => Math.abs(a - mm[i]) <= TOLERANCE_MM);
        if (near(before) && near(after)) {
          console.log('check-browser: ok: with a capable mock the Device proxy line shows the device\'s proxy: ' + text);
          return;
        }
      }
      await sleep(100);
    }
    console.error('check-browser: FAIL: with a local-model device the Device proxy line shows "' + last +
      '", not the device\'s proxy that /api/state reports');
    process.exitCode = 1;
  } finally {
    await browser.close();
  }
})().catch((e) => {
  console.error('check-browser: FAIL: ' + e);
  process.exit(1);
});
