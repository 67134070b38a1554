// voxhap's built-in page: live views of a servo session (schema voxhap.visualiser.v1).
// Plain JS, no build step: the server embeds this file as is.
//
// Data flow: one WebSocket (/ws?rate=N) brings a `hello` (with the scene) and then `state` messages; the page
// keeps only the newest state and redraws on the next animation frame. Slices of the volume come from
// GET /api/slice?encoding=u8 (8-bit, base64), re-requested only when the proxy moved more than a voxel across
// the view's plane or the scene or chosen volume changed, and never more than SLICE_BUDGET_BYTES_PER_S in any
// second. Servo statistics come from GET /api/stats every second while connected, the scene from
// GET /api/scene when scene_generation changes. Changes go out as REST POSTs with the token as a Bearer
// header; without a token, or with one the server refused, the page sends nothing and says why.
'use strict';

(function () {
  const SCHEMA = 'voxhap.visualiser.v1';
  const SLICE_SIZE = 128;
  const SLICE_BUDGET_BYTES_PER_S = 200 * 1024; // issue 17: one page pulled 2.2 MiB/s of slices
  // Requests are planned against 85 % of the budget: answers vary in size and arrive a little later than asked.
  const SLICE_PLAN_BYTES_PER_S = 0.85 * SLICE_BUDGET_BYTES_PER_S;
  const SLICE_RETRY_MS = 2000;
  const CONTROL_DEBOUNCE_MS = 250; // a held arrow key on a slider sends one request, not one per step
  const PLOT_WINDOW_S = 10;
  const MARKER_LABEL_PX = 3; // probe and proxy closer than this on a view: say "proxy on probe"
  // ... but only when they really coincide: no more than this apart in space and this force sent (in contact the
  // proxy may be a millimetre off and half a newton pushing while the two markers still overlap on screen).
  const PROXY_ON_PROBE_M = 1e-6;
  const PROXY_ON_PROBE_N = 1e-3;

  const HAND_PERIOD_MS = 33; // ~30 Hz
  const TOKEN_KEY = 'voxhap.token';
  const DEFAULT_BOUNDS = { min: [-0.05, -0.05, -0.05], max: [0.05, 0.05, 0.05] };
  const AXIS_NAMES = ['x', 'y', 'z'];
  // The scene palette is defined once, as --scene-* variables in style.css (Foxglove gets the same colours
  // from voxhap, which reads those lines too). Mode colours are chosen to stand out on grey; every mode is
  // also named in the legend.
  const cssColour = (name) => getComputedStyle(document.documentElement).getPropertyValue(`--scene-${name}`).trim();
  const COLOURS = {
    probe: cssColour('probe'),
    proxy: cssColour('proxy'),
    hand: cssColour('hand'),
    force: cssColour('force'),
    fx: cssColour('force-x'),
    fy: cssColour('force-y'),
    fz: cssColour('force-z'),
    mag: cssColour('force-magnitude'),
  };
  const MODE_COLOURS = [0, 1, 2, 3, 4, 5, 6, 7].map((i) => cssColour(`mode-${i}`));

  const $ = (id) => document.getElementById(id);

  // ---------------------------------------------------------------- app state

  const app = {
    scene: null,
    sceneGeneration: null,
    sceneFetching: false,
    simulated: false,
    rateHz: 60,
    recorderErrors: 0,
    servoRateHz: null,
    state: null,
    dirty: true,
    bounds: DEFAULT_BOUNDS,
    voxelM: 0.1 / 64,
    forceScale: 0.01, // N per CSS pixel
    forceScaleSince: 0,
    history: [], // {t, fx, fy, fz, mag}
    peaks: {}, // mode name -> peak strength first seen (sets the slider range)
    sliceVolume: '', // '' = the server's default (first scalar volume)
  };

  // The two orthographic views: h = world axis to the right, v = world axis up, w = the axis looked along.
  const views = [
    { axis: 'z', h: 0, v: 1, w: 2, canvas: $('view-z'), caption: $('cap-z') },
    { axis: 'y', h: 0, v: 2, w: 1, canvas: $('view-y'), caption: $('cap-y') },
  ];
  for (const view of views) {
    view.slice = null; // last slice answer
    view.image = null; // offscreen canvas with its pixels
    view.sliceAt = null; // proxy position it was requested at
    view.sliceRequested = 0; // performance.now() of the last request
    view.sliceInflight = false;
    view.sliceStale = true; // fetch at the first state, then when the proxy crosses a voxel or the scene changes
    view.sliceBytes = 24 * 1024; // size of the last answer (a 128 x 128 u8 slice is about 23 KiB)
    view.sliceError = null;
    view.frame = null; // layout of the last draw (for pointer mapping)
  }

  // ---------------------------------------------------------------- small helpers

  function num(x, digits) {
    return typeof x === 'number' && isFinite(x) ? x.toFixed(digits) : '–';
  }

  function mm(m, digits) {
    return num(m * 1000, digits === undefined ? 1 : digits);
  }

  /** A length in metres with a unit that suits it (nm, µm, mm). */
  function length(m) {
    if (typeof m !== 'number' || !isFinite(m)) return '–';
    const a = Math.abs(m);
    if (a === 0) return '0 m';
    if (a < 1e-9) return m.toExponential(2) + ' m';
    if (a < 1e-6) return (m * 1e9).toPrecision(3) + ' nm';
    if (a < 1e-3) return (m * 1e6).toPrecision(3) + ' µm';
    return (m * 1e3).toPrecision(3) + ' mm';
  }

  function micros(us) {
    if (typeof us !== 'number' || !isFinite(us)) return '–';
    return us < 10 ? us.toFixed(2) + ' µs' : us < 1000 ? us.toFixed(0) + ' µs' : (us / 1000).toFixed(2) + ' ms';
  }

  function isVec3(v) {
    return Array.isArray(v) && v.length === 3 && v.every((x) => typeof x === 'number' && isFinite(x));
  }

  function norm(v) {
    return Math.hypot(v[0], v[1], v[2]);
  }

  /** A 1, 2, 5 × 10^k step giving about `count` steps over `span`. */
  function niceStep(span, count) {
    const raw = Math.abs(span) / Math.max(1, count);
    if (!(raw > 0) || !isFinite(raw)) return 1;
    const p = Math.pow(10, Math.floor(Math.log10(raw)));
    const f = raw / p;
    return (f <= 1 ? 1 : f <= 2 ? 2 : f <= 5 ? 5 : 10) * p;
  }

  /** The smallest 1, 2, 5 × 10^k value at least `x`. */
  function niceCeil(x) {
    if (!(x > 0) || !isFinite(x)) return 1;
    const p = Math.pow(10, Math.floor(Math.log10(x)));
    for (const f of [1, 2, 5, 10]) if (f * p >= x * (1 - 1e-9)) return f * p;
    return 10 * p;
  }

  function trimNumber(x) {
    return String(Number(x.toPrecision(6)));
  }

  function setText(el, text) {
    if (el.textContent !== text) el.textContent = text;
  }

  function setFlag(el, on, yes, no) {
    // Meaning in words and a symbol, colour only as a third cue.
    setText(el, on ? '✔ ' + yes : '✖ ' + no);
    el.classList.toggle('flag-on', !!on);
    el.classList.toggle('flag-off', !on);
    el.classList.remove('flag-unknown');
  }

  /** Calls `fn` with the last arguments once no call came for `ms`. */
  function debounce(fn, ms) {
    let timer = null;
    return function () {
      const args = arguments;
      clearTimeout(timer);
      timer = setTimeout(() => fn.apply(null, args), ms);
    };
  }

  function showMsg(el, text, isError) {
    el.textContent = text || '';
    el.classList.toggle('error', !!isError);
    el.classList.toggle('ok', !!text && !isError);
    if (isError) el.setAttribute('role', 'alert');
    else el.setAttribute('role', 'status');
  }

  // ---------------------------------------------------------------- token

  const tokenInput = $('token');
  // The token the server refused last: not sent again until it is edited (no storms of refused requests).
  const auth = { refused: null, accepted: null };

  function currentToken() {
    return tokenInput.value.trim();
  }

  /** Why the page will not send a change now, or null. */
  function tokenProblem() {
    const token = currentToken();
    if (!token) return 'enter the control token (voxhap serve prints it) to change anything';
    if (token === auth.refused) {
      return 'the server refused this control token (a restarted voxhap serve has a new one): paste the new token';
    }
    return null;
  }

  function showTokenBanner(text) {
    const banner = $('token-banner');
    banner.textContent = text || '';
    banner.hidden = !text;
    updateStatusLine();
  }

  function tokenRefused(token) {
    auth.refused = token;
    auth.accepted = null;
    showTokenBanner(
      'The server refused the control token. voxhap serve makes a new token each time it starts: paste the one it ' +
        'printed into "Control token" (Controls). Viewing goes on; changes are not sent until then.'
    );
  }

  /** Asks the server whether the token is still good (after a (re)connect or an edit); changes nothing. */
  async function checkToken() {
    const token = currentToken();
    if (!token || token === auth.refused) return;
    try {
      // An empty stiffness body: the token is checked first (401), then the body is refused (400).
      const res = await fetch(apiUrl('api/stiffness'), {
        method: 'POST',
        headers: { 'Content-Type': 'application/json', Authorization: 'Bearer ' + token },
        body: '{}',
      });
      if (currentToken() !== token) return;
      if (res.status === 401 || res.status === 403) tokenRefused(token);
      else auth.accepted = token;
      updateStatusLine();
    } catch (e) {
      /* not connected: checked again on the next hello */
    }
  }

  function storageGet() {
    try {
      return sessionStorage.getItem(TOKEN_KEY);
    } catch (e) {
      return null;
    }
  }

  function storageSet(value) {
    try {
      sessionStorage.setItem(TOKEN_KEY, value);
    } catch (e) {
      /* storage disabled: the field still works for this page */
    }
  }

  (function initToken() {
    const params = new URLSearchParams(location.search);
    const fromUrl = params.get('token');
    if (fromUrl !== null) {
      storageSet(fromUrl);
      // Keep the token out of the address bar (and out of copied links); it stays in this tab's storage.
      params.delete('token');
      const rest = params.toString();
      try {
        history.replaceState(null, '', location.pathname + (rest ? '?' + rest : '') + location.hash);
      } catch (e) {
        /* not fatal */
      }
    }
    tokenInput.value = fromUrl !== null ? fromUrl : storageGet() || '';
    tokenInput.addEventListener('input', () => {
      storageSet(tokenInput.value);
      auth.refused = null;
      auth.accepted = null;
      showTokenBanner('');
      checkToken();
    });
    $('token-show').addEventListener('change', (e) => {
      tokenInput.type = e.target.checked ? 'text' : 'password';
    });
  })();

  // ---------------------------------------------------------------- HTTP

  function apiUrl(path) {
    return new URL(path, document.baseURI).toString();
  }

  async function getJson(path) {
    return (await getJsonSized(path)).data;
  }

  /** GET `path` → {data, bytes}: the JSON answer and its size in characters (≈ bytes: ASCII). */
  async function getJsonSized(path) {
    let res;
    try {
      res = await fetch(apiUrl(path), { cache: 'no-store' });
    } catch (e) {
      throw new Error('cannot reach the server');
    }
    const text = await res.text();
    let data = null;
    try {
      data = JSON.parse(text);
    } catch (e) {
      /* not JSON */
    }
    if (!res.ok) {
      const why = (data && (data.error || data.message)) || text.trim() || res.statusText;
      throw new Error('HTTP ' + res.status + ': ' + why);
    }
    if (data === null) throw new Error('the answer is not JSON');
    return { data: data, bytes: text.length };
  }

  /** POSTs `body` as JSON with the token; resolves to the reply, rejects with the server's error message. */
  async function post(path, body) {
    const problem = tokenProblem();
    if (problem) throw new Error(problem);
    const headers = { 'Content-Type': 'application/json' };
    const token = currentToken();
    headers.Authorization = 'Bearer ' + token;
    let res;
    try {
      res = await fetch(apiUrl(path), { method: 'POST', headers: headers, body: JSON.stringify(body) });
    } catch (e) {
      throw new Error('cannot reach the server (' + e.message + ')');
    }
    const text = await res.text();
    let data = null;
    try {
      data = JSON.parse(text);
    } catch (e) {
      /* not JSON */
    }
    if (!res.ok || (data && data.ok === false)) {
      let why = (data && (data.error || data.message)) || text.trim() || res.statusText || 'refused';
      if (res.status === 401 || res.status === 403) {
        tokenRefused(token);
        why += ' (the server refused the control token: paste the new one)';
      }
      throw new Error(why);
    }
    if (auth.accepted !== token) {
      auth.accepted = token;
      updateStatusLine();
    }
    return data || {};
  }

  // ---------------------------------------------------------------- WebSocket

  const conn = { ws: null, attempt: 0, timer: null, retryAt: 0, everOpen: false };

  function setConn(kind, text) {
    const el = $('conn');
    el.classList.remove('conn-up', 'conn-down', 'conn-wait');
    el.classList.add('conn-' + kind);
    setText($('conn-icon'), kind === 'up' ? '●' : kind === 'wait' ? '◐' : '○');
    setText($('conn-text'), text);
    app.live = kind === 'up';
    app.dirty = true;
    if (!app.live) {
      // The device flags are the server's; while the page is not connected it does not know them.
      for (const id of ['st-device', 'st-engaged']) {
        const el = $(id);
        setText(el, '? unknown (the page is not connected)');
        el.classList.remove('flag-on', 'flag-off');
        el.classList.add('flag-unknown');
      }
      stream.count = 0;
      stream.since = performance.now();
      stream.rate = null;
    }
    // While not connected every number in the status panel is the last one received: marked stale.
    const panel = document.querySelector('dl.status');
    const stale = !app.live && conn.everOpen;
    if (panel) panel.classList.toggle('stale', stale);
    setText($('status-h'), stale ? 'Status (stale: not connected)' : 'Status');
    updateStatusLine();
  }

  /** The badge while live: the update rate asked for now (it follows every rate change). */
  function showLiveRate() {
    if (conn.ws && conn.stateSeen) setConn('up', 'live, ' + app.rateHz + ' Hz updates');
  }

  // ---------------------------------------------------------------- status line

  // States received per second, measured by the page (the asked rate is an upper bound: see VISUALISER.md).
  const stream = { count: 0, since: performance.now(), rate: null };

  function measureRates() {
    const now = performance.now();
    const seconds = (now - stream.since) / 1000;
    if (app.live && seconds > 0) stream.rate = stream.count / seconds;
    stream.count = 0;
    stream.since = now;
    setText($('st-stream'), stream.rate === null ? '–' : num(stream.rate, 1) + ' states/s received (asked ' + app.rateHz + ' Hz)');
    setText(
      $('st-slices'),
      num(sliceBytesLastSecond(now) / 1024, 1) + ' KiB/s (at most ' + SLICE_BUDGET_BYTES_PER_S / 1024 + ' KiB/s), ' + sliceTraffic.fetched + ' fetched'
    );
    updateStatusLine();
  }

  function updateStatusLine() {
    const parts = [];
    parts.push(app.live ? 'connected' : 'not connected');
    if (app.live && stream.rate !== null) parts.push('stream ' + num(stream.rate, 1) + ' states/s of ' + app.rateHz + ' Hz asked');
    parts.push('slices ' + num(sliceBytesLastSecond(performance.now()) / 1024, 1) + ' KiB/s');
    const token = currentToken();
    parts.push(
      !token ? 'no control token (view only)' : token === auth.refused ? 'control token REFUSED' : token === auth.accepted ? 'control token accepted' : 'control token not checked yet'
    );
    setText($('status-line'), parts.join(' · '));
  }

  function wsUrl() {
    const url = new URL('ws', document.baseURI);
    url.protocol = url.protocol === 'https:' ? 'wss:' : 'ws:';
    url.search = '?rate=' + app.rateHz;
    return url.toString();
  }

  function connect() {
    clearTimeout(conn.timer);
    conn.timer = null;
    setConn('wait', conn.attempt ? 'reconnecting (attempt ' + (conn.attempt + 1) + ')…' : 'connecting…');
    let ws;
    try {
      ws = new WebSocket(wsUrl());
    } catch (e) {
      scheduleReconnect('cannot open the WebSocket: ' + e.message);
      return;
    }
    conn.ws = ws;
    ws.onopen = () => {
      conn.attempt = 0;
      conn.everOpen = true;
      conn.stateSeen = false;
      setConn('up', 'live, waiting for the first state…');
    };
    ws.onmessage = (event) => {
      if (typeof event.data !== 'string') return;
      let msg;
      try {
        msg = JSON.parse(event.data);
      } catch (e) {
        return;
      }
      onMessage(msg);
    };
    ws.onclose = (event) => {
      if (conn.ws !== ws) return;
      conn.ws = null;
      const why = event.reason ? ': ' + event.reason : event.code && event.code !== 1006 ? ' (code ' + event.code + ')' : '';
      scheduleReconnect('disconnected' + why);
    };
    ws.onerror = () => {
      /* onclose follows and reconnects */
    };
  }

  function scheduleReconnect(why) {
    conn.attempt += 1;
    // 0.5 s, 1 s, 2 s, ... up to 10 s, with jitter so many pages do not reconnect in step.
    const base = Math.min(10000, 500 * Math.pow(2, conn.attempt - 1));
    const delay = Math.round(base * (0.8 + 0.4 * Math.random()));
    conn.retryAt = performance.now() + delay;
    const tick = () => {
      const left = Math.max(0, conn.retryAt - performance.now());
      setConn('down', why + ' — reconnecting in ' + Math.ceil(left / 1000) + ' s (attempt ' + (conn.attempt + 1) + ')');
      if (left <= 0) connect();
      else conn.timer = setTimeout(tick, Math.min(1000, left));
    };
    tick();
  }

  function send(msg) {
    if (conn.ws && conn.ws.readyState === WebSocket.OPEN) conn.ws.send(JSON.stringify(msg));
  }

  function onMessage(msg) {
    switch (msg.type) {
      case 'hello':
        if (msg.schema && msg.schema !== SCHEMA) {
          console.warn('voxhap: server schema ' + msg.schema + ', page expects ' + SCHEMA);
        }
        if (typeof msg.rate_hz === 'number') app.rateHz = msg.rate_hz;
        if (typeof msg.servo_rate_hz === 'number') app.servoRateHz = msg.servo_rate_hz;
        syncRateSelect();
        showLiveRate();
        if (msg.scene) setScene(msg.scene);
        checkToken(); // a restarted server has a new token
        break;
      case 'state':
        onState(msg);
        break;
      case 'reply':
      case 'error':
        // The page sends its commands over REST; nothing to match here.
        break;
      default:
        break;
    }
  }

  // ---------------------------------------------------------------- scene

  function modeName(mode) {
    return mode.name || mode.kind;
  }

  function setScene(scene) {
    app.scene = scene;
    app.simulated = !!scene.simulated;
    // View window: the union of the volumes' boxes (the default 10 cm cube without volumes).
    const vols = Array.isArray(scene.volumes) ? scene.volumes.filter((v) => isVec3(v.min_m) && isVec3(v.max_m)) : [];
    if (vols.length) {
      const min = [Infinity, Infinity, Infinity];
      const max = [-Infinity, -Infinity, -Infinity];
      let voxel = Infinity;
      for (const v of vols) {
        for (let i = 0; i < 3; i++) {
          min[i] = Math.min(min[i], v.min_m[i]);
          max[i] = Math.max(max[i], v.max_m[i]);
          const n = Array.isArray(v.dims) ? v.dims[i] : 0;
          if (n > 1) voxel = Math.min(voxel, (v.max_m[i] - v.min_m[i]) / (n - 1));
        }
      }
      app.bounds = { min: min, max: max };
      app.voxelM = isFinite(voxel) && voxel > 0 ? voxel : 0.1 / 64;
    } else {
      app.bounds = DEFAULT_BOUNDS;
    }
    const label = [];
    if (vols.length) label.push('volumes: ' + vols.map((v) => v.name + ' (' + v.kind + ', ' + (v.dims || []).join('×') + ')').join(', '));
    label.push((scene.modes || []).length + ' modes');
    setText($('scene-label'), label.join(' · '));
    setText($('st-spec'), (scene.device || '–') + (scene.simulated ? ' (simulated arm)' : ''));
    // A recording that stopped on an error (disk full, I/O error) says why, as the server reports it.
    const rec = $('st-rec');
    setText(
      rec,
      (scene.recording ? String(scene.recording) : 'not recording') +
        (scene.recording_error ? ' — STOPPED: ' + String(scene.recording_error) : '')
    );
    rec.classList.toggle('rec-error', Boolean(scene.recording_error));
    $('hand-box').hidden = !app.simulated;
    buildVolumeSelect(vols);
    for (const view of views) view.canvas.classList.toggle('draggable', app.simulated);
    buildModes(scene.modes || []);
    buildModeKeys(scene.modes || []);
    // New scene (perhaps a new volume): fetch fresh slices.
    for (const view of views) view.sliceStale = true;
    app.dirty = true;
  }

  function buildVolumeSelect(vols) {
    const select = $('slice-volume');
    const keep = app.sliceVolume;
    while (select.options.length > 1) select.remove(1);
    for (const v of vols) {
      const option = document.createElement('option');
      option.value = v.name;
      option.textContent = v.name + ' (' + v.kind + ')';
      select.append(option);
    }
    app.sliceVolume = vols.some((v) => v.name === keep) ? keep : '';
    select.value = app.sliceVolume;
  }

  $('slice-volume').addEventListener('change', (e) => {
    app.sliceVolume = e.target.value;
    for (const view of views) view.sliceStale = true;
    maybeFetchSlices();
  });

  async function refetchScene() {
    if (app.sceneFetching) return;
    app.sceneFetching = true;
    try {
      setScene(await getJson('api/scene'));
    } catch (e) {
      if (app.live) console.warn('voxhap: scene: ' + e.message);
    } finally {
      app.sceneFetching = false;
    }
  }

  function buildModeKeys(modes) {
    const box = $('mode-keys');
    box.textContent = '';
    modes.forEach((mode, i) => {
      const key = document.createElement('span');
      key.className = 'key';
      const sw = document.createElement('span');
      sw.className = 'swatch';
      sw.setAttribute('aria-hidden', 'true');
      sw.style.background = MODE_COLOURS[i % MODE_COLOURS.length];
      key.append(sw, (i + 1) + ' ' + modeName(mode) + (mode.enabled === false ? ' (off)' : ''));
      box.append(key);
    });
  }

  // ---------------------------------------------------------------- mode controls

  function maxStrength(points) {
    return points.reduce((m, p) => Math.max(m, p[1]), 0);
  }

  function pointsText(points) {
    return JSON.stringify(points.map((p) => [Number(trimNumber(p[0])), Number(trimNumber(p[1]))]));
  }

  let modeSignature = '';

  function buildModes(modes) {
    const list = $('mode-list');
    const signature = JSON.stringify(modes.map((m) => [modeName(m), m.kind, !!m.transfer]));
    if (signature === modeSignature && list.children.length) {
      // Same modes: refresh the values in place (not those being edited).
      modes.forEach((mode) => {
        const box = list.querySelector('[data-mode="' + CSS.escape(modeName(mode)) + '"]');
        if (box && box._update) box._update(mode);
      });
      return;
    }
    modeSignature = signature;
    list.textContent = '';
    if (!modes.length) {
      const p = document.createElement('p');
      p.className = 'dim';
      p.textContent = 'the scene has no modes';
      list.append(p);
      return;
    }
    modes.forEach((mode, index) => list.append(modeBox(mode, index)));
  }

  function modeBox(mode, index) {
    const name = modeName(mode);
    const id = 'mode-' + index;
    const box = document.createElement('fieldset');
    box.className = 'mode';
    box.dataset.mode = name;
    const legend = document.createElement('legend');
    const sw = document.createElement('span');
    sw.className = 'swatch';
    sw.setAttribute('aria-hidden', 'true');
    sw.style.background = MODE_COLOURS[index % MODE_COLOURS.length];
    legend.append(sw, (index + 1) + ' ' + name + ' ');
    const kind = document.createElement('span');
    kind.className = 'dim';
    kind.textContent = '(' + mode.kind + (mode.volume ? ' on ' + mode.volume : '') + ')';
    legend.append(kind);
    box.append(legend);

    const msg = document.createElement('p');
    msg.className = 'msg';
    msg.id = id + '-msg';
    msg.setAttribute('aria-live', 'polite');

    // On/off: off keeps every setting (breakpoints too) and renders no force.
    let enabled = mode.enabled !== false;
    const switchLabel = document.createElement('label');
    switchLabel.className = 'inline mode-switch';
    const toggle = document.createElement('input');
    toggle.type = 'checkbox';
    toggle.id = id + '-on';
    toggle.className = 'mode-on';
    toggle.setAttribute('aria-label', name + ' on');
    switchLabel.append(toggle, ' on');
    box.append(switchLabel);

    function showEnabled(on) {
      enabled = on;
      toggle.checked = on;
      box.classList.toggle('mode-off', !on);
    }
    showEnabled(enabled);

    async function setEnabled(on) {
      showMsg(msg, 'sending…', false);
      try {
        const reply = await post('api/modes/' + encodeURIComponent(name) + '/enabled', { enabled: on });
        showEnabled(on);
        showMsg(msg, reply.message || name + (on ? ' on' : ' off'), false);
        return true;
      } catch (e) {
        showEnabled(enabled);
        showMsg(msg, e.message, true);
        return false;
      }
    }
    toggle.addEventListener('change', () => setEnabled(toggle.checked));

    if (!Array.isArray(mode.transfer)) {
      const p = document.createElement('p');
      p.className = 'help';
      if (mode.kind === 'friction') p.textContent = 'μ = ' + mode.mu + ' on ' + mode.surface + ' (no transfer function to scale)';
      else if (mode.kind === 'support_plane') p.textContent = 'fixed plane, ' + mode.strength_n + ' N (no transfer function to scale)';
      else p.textContent = 'no transfer function to scale';
      box.append(p, msg);
      box._update = (m) => {
        showEnabled(m.enabled !== false);
        if (m.kind === 'friction') p.textContent = 'μ = ' + m.mu + ' on ' + m.surface + ' (no transfer function to scale)';
      };
      return box;
    }

    let points = mode.transfer;
    if (!(name in app.peaks)) app.peaks[name] = maxStrength(points);

    // Peak strength: scales every breakpoint's strength.
    const row = document.createElement('div');
    row.className = 'row';
    const label = document.createElement('label');
    label.htmlFor = id + '-peak';
    label.textContent = 'Peak strength (N)';
    const range = document.createElement('input');
    range.type = 'range';
    range.id = id + '-peak-range';
    range.setAttribute('aria-label', name + ' peak strength (N), slider');
    const number = document.createElement('input');
    number.type = 'number';
    number.id = id + '-peak';
    number.min = '0';
    number.step = 'any';
    number.inputMode = 'decimal';
    row.append(range, number);

    const tfLabel = document.createElement('label');
    tfLabel.htmlFor = id + '-points';
    tfLabel.textContent = 'Breakpoints [x, N]';
    const tfRow = document.createElement('div');
    tfRow.className = 'row';
    const tf = document.createElement('input');
    tf.type = 'text';
    tf.id = id + '-points';
    tf.spellcheck = false;
    tf.className = 'mono';
    const apply = document.createElement('button');
    apply.type = 'button';
    apply.textContent = 'Apply';
    apply.setAttribute('aria-label', 'Apply ' + name + ' breakpoints');
    tfRow.append(tf, apply);
    box.append(label, row, tfLabel, tfRow, msg);

    function setRange(peak) {
      const top = niceCeil(Math.max(2 * (app.peaks[name] || 0), 2 * peak, 0.5));
      range.min = '0';
      range.max = String(top);
      range.step = String(top / 200);
    }

    function show(m) {
      points = m.transfer;
      const peak = maxStrength(points);
      setRange(peak);
      if (document.activeElement !== range) range.value = String(peak);
      if (document.activeElement !== number) number.value = trimNumber(peak);
      if (document.activeElement !== tf) tf.value = pointsText(points);
    }
    box._update = (m) => {
      showEnabled(m.enabled !== false);
      if (Array.isArray(m.transfer)) show(m);
    };
    show(mode);

    async function send(newPoints, what) {
      showMsg(msg, 'sending…', false);
      try {
        const reply = await post('api/modes/' + encodeURIComponent(name) + '/transfer', { transfer: newPoints });
        points = newPoints;
        showMsg(msg, reply.message || what, false);
        // The scene generation changes; the state stream brings it and the scene is fetched again.
      } catch (e) {
        showMsg(msg, e.message, true);
        show({ transfer: points }); // back to what the server has
      }
    }

    // Peak 0 switches the mode off and leaves its breakpoints alone (scaling them to 0 N would lose their
    // shape: issue 17); a peak > 0 scales them and switches the mode on.
    async function scaleTo(target) {
      if (!(target >= 0) || !isFinite(target)) {
        showMsg(msg, 'peak strength must be a number ≥ 0', true);
        return;
      }
      if (target === 0) {
        if (await setEnabled(false)) showMsg(msg, name + ' switched off (peak 0); its breakpoints are kept', false);
        show({ transfer: points });
        return;
      }
      const peak = maxStrength(points);
      const scaled = points.map((p) => [p[0], peak > 0 ? (p[1] * target) / peak : target]);
      await send(scaled, name + ' peak strength ' + trimNumber(target) + ' N');
      if (!enabled) await setEnabled(true);
    }
    const scaleSoon = debounce(scaleTo, CONTROL_DEBOUNCE_MS);

    range.addEventListener('input', () => {
      number.value = trimNumber(Number(range.value));
    });
    range.addEventListener('change', () => scaleSoon(Number(range.value)));
    number.addEventListener('change', () => {
      if (number.value === '') return;
      scaleSoon(Number(number.value));
    });
    const applyPoints = () => {
      let parsed;
      try {
        parsed = JSON.parse(tf.value);
      } catch (e) {
        showMsg(msg, 'breakpoints: not a JSON list like [[0, 0], [1, 2.5]]', true);
        return;
      }
      send(parsed, name + ' breakpoints set'); // the server validates (increasing x, strengths ≥ 0, ...)
    };
    apply.addEventListener('click', applyPoints);
    tf.addEventListener('keydown', (e) => {
      if (e.key === 'Enter') applyPoints();
    });
    return box;
  }

  // ---------------------------------------------------------------- stiffness, damping, rate

  function bindScalar(rangeEl, numberEl, msgEl, makeBody, label, unit) {
    let sending = false;
    async function sendValue(value) {
      if (!isFinite(value)) {
        showMsg(msgEl, label + ' must be a number', true);
        return;
      }
      sending = true;
      showMsg(msgEl, 'sending…', false);
      try {
        const reply = await post('api/stiffness', makeBody(value));
        showMsg(msgEl, reply.message || label + ' set to ' + trimNumber(value) + ' ' + unit, false);
      } catch (e) {
        showMsg(msgEl, e.message, true);
      } finally {
        sending = false;
      }
    }
    rangeEl.addEventListener('input', () => {
      numberEl.value = rangeEl.value;
    });
    const sendSoon = debounce(sendValue, CONTROL_DEBOUNCE_MS);
    rangeEl.addEventListener('change', () => sendSoon(Number(rangeEl.value)));
    numberEl.addEventListener('change', () => {
      if (numberEl.value !== '') sendSoon(Number(numberEl.value));
    });
    return function sync(value) {
      if (typeof value !== 'number' || !isFinite(value) || sending) return;
      if (Number(rangeEl.max) < value) rangeEl.max = String(niceCeil(value * 1.5));
      if (document.activeElement !== rangeEl) rangeEl.value = String(value);
      if (document.activeElement !== numberEl) {
        const text = trimNumber(value);
        if (numberEl.value !== text) numberEl.value = text;
      }
    };
  }

  const syncK = bindScalar($('k-range'), $('k-number'), $('k-msg'), (k) => ({ k: k }), 'stiffness', 'N/m');
  const syncB = bindScalar($('b-range'), $('b-number'), $('b-msg'), (b) => ({ damping: b }), 'damping', 'N·s/m');

  function syncRateSelect() {
    const select = $('rate');
    const value = String(Math.round(app.rateHz));
    if (![...select.options].some((o) => o.value === value)) {
      const option = document.createElement('option');
      option.value = value;
      option.textContent = value + ' Hz';
      select.append(option);
    }
    select.value = value;
  }

  $('rate').addEventListener('change', (e) => {
    const rate = Number(e.target.value);
    app.rateHz = rate;
    send({ type: 'rate', rate_hz: rate });
    showLiveRate();
  });

  // ---------------------------------------------------------------- state

  function onState(s) {
    if (!isVec3(s.probe_m) || !isVec3(s.proxy_m)) return;
    const previous = app.state;
    if (previous && (s.tick < previous.tick || s.t_s < previous.t_s)) app.history = []; // a new session
    app.state = s;
    app.dirty = true;
    stream.count += 1;

    if (!conn.stateSeen && conn.ws) setConn('up', 'live, ' + app.rateHz + ' Hz updates');
    conn.stateSeen = true;

    const f = isVec3(s.force_n) ? s.force_n : [0, 0, 0];
    app.history.push({ t: s.t_s, fx: f[0], fy: f[1], fz: f[2], mag: norm(f) });
    const cut = s.t_s - PLOT_WINDOW_S - 0.5;
    let drop = 0;
    while (drop < app.history.length && app.history[drop].t < cut) drop++;
    if (drop) app.history.splice(0, drop);

    if (app.sceneGeneration === null) app.sceneGeneration = s.scene_generation;
    else if (s.scene_generation !== app.sceneGeneration) {
      app.sceneGeneration = s.scene_generation;
      refetchScene();
    }
    updateStatus(s);
    maybeFetchSlices();
  }

  function updateStatus(s) {
    const tick = $('st-tick');
    setText(tick, String(s.tick));
    tick.dataset.tick = String(s.tick);
    setText($('st-time'), 't = ' + num(s.t_s, 2) + ' s');
    const at = (v) => '(' + v.map((x) => mm(x)).join(', ') + ') mm';
    setText($('st-probe'), at(s.probe_m));
    setText($('st-proxy'), at(s.proxy_m) + ', ' + length(norm([0, 1, 2].map((i) => s.proxy_m[i] - s.probe_m[i]))) + ' from the probe');
    setFlag($('st-device'), s.connected, 'connected', 'disconnected');
    setFlag($('st-engaged'), s.engaged, 'engaged', 'not engaged (no force sent)');
    // Why the force is off (none: the safety pipeline passes it), with the device's latched fault bits.
    const cause = typeof s.force_off_cause === 'string' ? s.force_off_cause : null;
    setText(
      $('st-force-off'),
      cause === null ? '–' : cause === 'none' ? 'nothing (forces pass)' :
        cause.replace(/_/g, ' ') + (s.device_fault_bits ? ' (fault bits 0x' + s.device_fault_bits.toString(16) + ')' : '')
    );
    setText($('st-age'), typeof s.sample_age_ticks === 'number' ? s.sample_age_ticks + ' ticks' : '–');
    // A local-model device's own proxy, its certificate and the model's age (none: no local model this tick).
    const dl = s.device_local;
    setText(
      $('st-device-proxy'),
      dl && isVec3(dl.proxy_m)
        ? at(dl.proxy_m) + ', ≤ ' + length(dl.proxy_bound_m) + ', model ' + dl.model_sequence + ' ' + num(dl.model_age_s * 1e3, 2) + ' ms old'
        : 'none (no local model)'
    );
    setText($('st-solve'), String(s.status || '–').replace(/_/g, ' ') + ', ' + (s.sweeps === undefined ? '–' : s.sweeps) + ' sweeps');
    setText($('st-bound'), typeof s.error_bound_m === 'number' ? '≤ ' + length(s.error_bound_m) : 'none (uncertified)');
    setText($('st-k'), num(s.stiffness_n_per_m, 0) + ' N/m');
    setText($('st-b'), num(s.damping_n_s_per_m, 2) + ' N·s/m');
    setText($('st-hand'), isVec3(s.hand_target_m) ? '(' + s.hand_target_m.map((x) => mm(x)).join(', ') + ') mm' : app.simulated ? 'following its path' : '–');
    setText($('st-dropped'), s.frames_dropped === undefined ? '–' : String(s.frames_dropped));
    syncK(s.stiffness_n_per_m);
    syncB(s.damping_n_s_per_m);
    const f = isVec3(s.force_n) ? s.force_n : null;
    setText($('force-now'), f ? '|F| = ' + num(norm(f), 3) + ' N, F = (' + f.map((x) => num(x, 3)).join(', ') + ') N' : '–');
  }

  // ---------------------------------------------------------------- stats

  async function pollStats() {
    if (!app.live) return; // no requests (and no console errors) while the server is away
    try {
      const stats = await getJson('api/stats');
      const servo = stats.servo || {};
      // A recording stopped on an error: /api/scene says why (recording_error).
      if (typeof servo.recorder_errors === 'number' && servo.recorder_errors > app.recorderErrors) {
        app.recorderErrors = servo.recorder_errors;
        refetchScene();
      }
      const late = servo.lateness || {};
      const compute = servo.compute || {};
      setText($('st-late'), micros(late.p99_us) + ' (max ' + micros(late.max_us) + ')');
      setText($('st-compute'), micros(compute.p99_us) + ' (max ' + micros(compute.max_us) + ')');
      setText(
        $('st-overruns'),
        (servo.ticks === undefined ? '–' : servo.ticks) + ' / ' + (servo.overruns === undefined ? '–' : servo.overruns) +
          (servo.rate_hz ? ' at ' + servo.rate_hz + ' Hz' : '')
      );
      // The energy ledger's totals (J shown in mJ) and its verdicts.
      const energy = servo.energy || {};
      const mj = (j) => (typeof j === 'number' ? num(j * 1e3, 3) + ' mJ' : '–');
      setText(
        $('st-energy'),
        'generated ' + mj(energy.generated_j) + ', net ' + mj(energy.net_generated_j) + ', work on probe ' +
          mj(energy.work_on_probe_j) + ', coupling ' + mj(energy.coupling_energy_j) +
          (energy.active ? ', ACTIVE' : '') + (energy.oscillating ? ', OSCILLATION' : '')
      );
      const rt = servo.realtime || {};
      setText(
        $('st-rt'),
        [
          rt.sched_fifo ? '✔ SCHED_FIFO' : '✖ SCHED_FIFO',
          rt.memory_locked ? '✔ memory locked' : '✖ memory locked',
          typeof rt.pinned_cpu === 'number' ? '✔ CPU ' + rt.pinned_cpu : '✖ not pinned',
        ].join(', ')
      );
      const server = stats.server || {};
      const parts = Object.keys(server)
        .filter((k) => typeof server[k] !== 'object')
        .map((k) => k.replace(/_/g, ' ') + ' ' + server[k]);
      setText($('st-server'), parts.length ? parts.join(', ') : '–');
      $('stats-error').hidden = true;
    } catch (e) {
      const el = $('stats-error');
      el.textContent = 'statistics: ' + e.message;
      el.hidden = false;
    }
  }

  // ---------------------------------------------------------------- slices

  // Slice answers of the last second, for the budget: {t: performance.now(), bytes}.
  const sliceTraffic = { log: [], fetched: 0, timer: null };

  function sliceBytesLastSecond(now) {
    const log = sliceTraffic.log;
    // Entries move to their arrival time, so the log is only nearly sorted: filter, do not just shift.
    sliceTraffic.log = log.filter((entry) => entry.t >= now - 1000);
    return sliceTraffic.log.reduce((sum, entry) => sum + entry.bytes, 0);
  }

  /** Fetches the slices that are due (a slice spans the whole volume, so only the proxy's coordinate along the
   * view's axis matters), within SLICE_BUDGET_BYTES_PER_S; a slice over budget waits for the next window. */
  function maybeFetchSlices() {
    const s = app.state;
    if (!s || !app.live) return;
    const now = performance.now();
    for (const view of views) {
      if (view.sliceInflight) continue;
      let due = view.sliceStale || !view.sliceAt || Math.abs(s.proxy_m[view.w] - view.sliceAt[view.w]) > app.voxelM;
      if (view.sliceError && now - view.sliceRequested < SLICE_RETRY_MS) due = false;
      if (!due) continue;
      if (sliceBytesLastSecond(now) + view.sliceBytes > SLICE_PLAN_BYTES_PER_S) {
        if (!sliceTraffic.timer) {
          const oldest = sliceTraffic.log.reduce((t, entry) => Math.min(t, entry.t), now);
          sliceTraffic.timer = setTimeout(() => {
            sliceTraffic.timer = null;
            maybeFetchSlices();
          }, Math.max(20, oldest + 1000 - now));
        }
        continue;
      }
      fetchSlice(view, s.proxy_m.slice());
    }
  }

  async function fetchSlice(view, at) {
    view.sliceInflight = true;
    view.sliceStale = false;
    view.sliceRequested = performance.now();
    view.sliceAt = at;
    // Reserve the expected size now, so two views asking at once stay within the budget.
    const entry = { t: performance.now(), bytes: view.sliceBytes };
    sliceTraffic.log.push(entry);
    let query = 'axis=' + view.axis + '&size=' + SLICE_SIZE + '&encoding=u8&at=' + at.map((x) => x.toFixed(6)).join(',');
    if (app.sliceVolume) query += '&volume=' + encodeURIComponent(app.sliceVolume);
    const volume = app.sliceVolume;
    try {
      const answer = await getJsonSized('api/slice?' + query);
      entry.bytes = answer.bytes;
      entry.t = performance.now(); // counted from its arrival (keeps the log in time order: see below)
      view.sliceBytes = answer.bytes;
      sliceTraffic.fetched += 1;
      if (volume === app.sliceVolume) setSlice(view, answer.data);
      else view.sliceStale = true; // the choice changed meanwhile: ask again
      view.sliceError = null;
    } catch (e) {
      view.sliceError = e.message;
    } finally {
      view.sliceInflight = false;
      const errors = views.filter((v) => v.sliceError).map((v) => v.axis + ' slice: ' + v.sliceError);
      setText($('slice-note'), errors.join('; '));
      app.dirty = true;
    }
  }

  function setSlice(view, slice) {
    const w = slice.width | 0;
    const h = slice.height | 0;
    if (typeof slice.values_u8 === 'string') {
      // 8-bit: byte b stands for min + b (max - min) / 255.
      const bytes = atob(slice.values_u8);
      if (!(w > 0 && h > 0) || bytes.length < w * h) throw new Error('malformed slice');
      const grey = new Array(w * h);
      for (let i = 0; i < w * h; i++) grey[i] = bytes.charCodeAt(i);
      slice = Object.assign({}, slice, { values: grey, min: 0, max: 255 });
    }
    if (!(w > 0 && h > 0) || !Array.isArray(slice.values) || slice.values.length < w * h) {
      throw new Error('malformed slice');
    }
    if (!isVec3(slice.origin_m) || !isVec3(slice.u_m) || !isVec3(slice.v_m)) throw new Error('malformed slice');
    let lo = slice.min;
    let hi = slice.max;
    if (!(typeof lo === 'number' && typeof hi === 'number' && hi > lo)) {
      lo = Infinity;
      hi = -Infinity;
      for (const x of slice.values) {
        if (typeof x === 'number' && isFinite(x)) {
          if (x < lo) lo = x;
          if (x > hi) hi = x;
        }
      }
      if (!(hi > lo)) hi = lo + 1;
    }
    const image = view.image && view.image.width === w && view.image.height === h ? view.image : document.createElement('canvas');
    image.width = w;
    image.height = h;
    const ctx = image.getContext('2d');
    const data = ctx.createImageData(w, h);
    const px = data.data;
    const scale = 255 / (hi - lo);
    for (let i = 0; i < w * h; i++) {
      const x = slice.values[i];
      const g = typeof x === 'number' && isFinite(x) ? Math.max(0, Math.min(255, (x - lo) * scale)) : 0;
      px[4 * i] = g;
      px[4 * i + 1] = g;
      px[4 * i + 2] = g;
      px[4 * i + 3] = 255;
    }
    ctx.putImageData(data, 0, 0);
    view.image = image;
    view.slice = slice;
  }

  // ---------------------------------------------------------------- drawing: views

  const MARGIN = { left: 46, right: 10, top: 10, bottom: 34 };

  function fitCanvas(canvas) {
    const rect = canvas.getBoundingClientRect();
    const dpr = window.devicePixelRatio || 1;
    const w = Math.max(1, Math.round(rect.width * dpr));
    const h = Math.max(1, Math.round(rect.height * dpr));
    if (canvas.width !== w || canvas.height !== h) {
      canvas.width = w;
      canvas.height = h;
    }
    const ctx = canvas.getContext('2d');
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    return { ctx: ctx, width: rect.width, height: rect.height };
  }

  /** Layout of a view: world window, scale (CSS px per metre), plot rectangle. */
  function viewFrame(view, width, height) {
    const b = app.bounds;
    const pad = 0.04;
    let h0 = b.min[view.h];
    let h1 = b.max[view.h];
    let v0 = b.min[view.v];
    let v1 = b.max[view.v];
    const dh = (h1 - h0) * pad;
    const dv = (v1 - v0) * pad;
    h0 -= dh;
    h1 += dh;
    v0 -= dv;
    v1 += dv;
    const pw = Math.max(10, width - MARGIN.left - MARGIN.right);
    const ph = Math.max(10, height - MARGIN.top - MARGIN.bottom);
    const scale = Math.min(pw / (h1 - h0), ph / (v1 - v0));
    // Centre the window in the plot area (same scale on both axes).
    const usedW = (h1 - h0) * scale;
    const usedH = (v1 - v0) * scale;
    const left = MARGIN.left + (pw - usedW) / 2;
    const top = MARGIN.top + (ph - usedH) / 2;
    return { h0: h0, h1: h1, v0: v0, v1: v1, scale: scale, left: left, top: top, width: usedW, height: usedH };
  }

  function toPx(frame, h, v) {
    return [frame.left + (h - frame.h0) * frame.scale, frame.top + frame.height - (v - frame.v0) * frame.scale];
  }

  function fromPx(frame, x, y) {
    return [frame.h0 + (x - frame.left) / frame.scale, frame.v0 + (frame.top + frame.height - y) / frame.scale];
  }

  function outlined(ctx, draw, colour, width) {
    ctx.lineWidth = (width || 1.5) + 2.5;
    ctx.strokeStyle = 'rgba(0,0,0,0.85)';
    draw();
    ctx.stroke();
    ctx.lineWidth = width || 1.5;
    ctx.strokeStyle = colour;
    draw();
    ctx.stroke();
  }

  function arrow(ctx, x0, y0, x1, y1, colour, width, dashed) {
    const dx = x1 - x0;
    const dy = y1 - y0;
    const len = Math.hypot(dx, dy);
    if (len < 0.5) return;
    const ux = dx / len;
    const uy = dy / len;
    const head = Math.min(10, 0.4 * len + 3);
    const path = () => {
      ctx.beginPath();
      ctx.moveTo(x0, y0);
      ctx.lineTo(x1, y1);
      ctx.moveTo(x1 - head * ux - 0.5 * head * uy, y1 - head * uy + 0.5 * head * ux);
      ctx.lineTo(x1, y1);
      ctx.lineTo(x1 - head * ux + 0.5 * head * uy, y1 - head * uy - 0.5 * head * ux);
    };
    ctx.setLineDash(dashed ? [5, 3] : []);
    outlined(ctx, path, colour, width);
    ctx.setLineDash([]);
  }

  function drawAxes(ctx, frame, view) {
    ctx.save();
    ctx.font = '11px system-ui, sans-serif';
    ctx.fillStyle = '#d8dde3';
    ctx.strokeStyle = '#7d8793';
    ctx.lineWidth = 1;
    ctx.strokeRect(frame.left - 0.5, frame.top - 0.5, frame.width + 1, frame.height + 1);
    const hSpan = (frame.h1 - frame.h0) * 1000;
    const vSpan = (frame.v1 - frame.v0) * 1000;
    const hStep = niceStep(hSpan, Math.max(2, frame.width / 70));
    const vStep = niceStep(vSpan, Math.max(2, frame.height / 50));
    ctx.textAlign = 'center';
    ctx.textBaseline = 'top';
    for (let t = Math.ceil((frame.h0 * 1000) / hStep) * hStep; t <= frame.h1 * 1000 + 1e-9; t += hStep) {
      const [x] = toPx(frame, t / 1000, frame.v0);
      ctx.beginPath();
      ctx.moveTo(x, frame.top + frame.height);
      ctx.lineTo(x, frame.top + frame.height + 4);
      ctx.stroke();
      ctx.fillText(trimNumber(t), x, frame.top + frame.height + 6);
    }
    ctx.textAlign = 'right';
    ctx.textBaseline = 'middle';
    for (let t = Math.ceil((frame.v0 * 1000) / vStep) * vStep; t <= frame.v1 * 1000 + 1e-9; t += vStep) {
      const [, y] = toPx(frame, frame.h0, t / 1000);
      ctx.beginPath();
      ctx.moveTo(frame.left - 4, y);
      ctx.lineTo(frame.left, y);
      ctx.stroke();
      ctx.fillText(trimNumber(t), frame.left - 6, y);
    }
    ctx.font = '12px system-ui, sans-serif';
    ctx.textAlign = 'right';
    ctx.textBaseline = 'bottom';
    ctx.fillText(AXIS_NAMES[view.h] + ' (mm) →', frame.left + frame.width, frame.top + frame.height + 32);
    ctx.save();
    ctx.translate(12, frame.top);
    ctx.rotate(-Math.PI / 2);
    ctx.textAlign = 'right';
    ctx.textBaseline = 'middle';
    ctx.fillText(AXIS_NAMES[view.v] + ' (mm) →', 0, 0);
    ctx.restore();
    ctx.restore();
  }

  function drawSlice(ctx, frame, view) {
    const slice = view.slice;
    if (!slice || !view.image) return;
    const h = view.h;
    const v = view.v;
    const o = slice.origin_m;
    const u = slice.u_m;
    const w = slice.v_m;
    const s = frame.scale;
    // Image pixel (i, j) covers [i, i + 1] x [j, j + 1]; its centre is sample origin + i u + j v.
    const oh = o[h] - 0.5 * u[h] - 0.5 * w[h];
    const ov = o[v] - 0.5 * u[v] - 0.5 * w[v];
    const [ex, ey] = toPx(frame, oh, ov);
    ctx.save();
    ctx.beginPath();
    ctx.rect(frame.left, frame.top, frame.width, frame.height);
    ctx.clip();
    ctx.transform(s * u[h], -s * u[v], s * w[h], -s * w[v], ex, ey);
    ctx.imageSmoothingEnabled = true;
    ctx.drawImage(view.image, 0, 0);
    ctx.restore();
  }

  function modeColour(index) {
    return MODE_COLOURS[index % MODE_COLOURS.length];
  }

  function drawPrimitive(ctx, frame, view, prim, proxy) {
    if (!isVec3(prim.direction)) return;
    const colour = modeColour(prim.mode | 0);
    const h = view.h;
    const v = view.v;
    const w = view.w;
    const P = isVec3(prim.position_m) ? prim.position_m : proxy;
    const D = prim.direction;
    const [px, py] = toPx(frame, P[h], P[v]);
    switch (prim.kind) {
      case 'point': {
        const r = 6;
        outlined(ctx, () => {
          ctx.beginPath();
          ctx.moveTo(px - r, py - r);
          ctx.lineTo(px + r, py + r);
          ctx.moveTo(px - r, py + r);
          ctx.lineTo(px + r, py - r);
        }, colour, 2);
        break;
      }
      case 'line': {
        const dh = D[h];
        const dv = D[v];
        const n = Math.hypot(dh, dv);
        if (n < 1e-6) {
          // Along the viewing axis: a circled dot.
          outlined(ctx, () => {
            ctx.beginPath();
            ctx.arc(px, py, 5, 0, 2 * Math.PI);
          }, colour, 2);
          break;
        }
        const L = 2 * (frame.width + frame.height);
        const ux = dh / n;
        const uy = -dv / n;
        outlined(ctx, () => {
          ctx.beginPath();
          ctx.moveTo(px - L * ux, py - L * uy);
          ctx.lineTo(px + L * ux, py + L * uy);
        }, colour, 1.5);
        break;
      }
      case 'plane': {
        // Trace of the plane n·(x − P) = 0 in the view's plane (x_w = the proxy's coordinate).
        const nh = D[h];
        const nv = D[v];
        const n2 = nh * nh + nv * nv;
        if (n2 < 1e-12) break; // parallel to the view: no trace
        const c = nh * P[h] + nv * P[v] + D[w] * (P[w] - proxy[w]);
        const q = [proxy[h], proxy[v]];
        const k = (nh * q[0] + nv * q[1] - c) / n2;
        const base = [q[0] - k * nh, q[1] - k * nv];
        const [bx, by] = toPx(frame, base[0], base[1]);
        const n = Math.sqrt(n2);
        const ux = -nv / n; // along the trace (screen x)
        const uy = -nh / n; // along the trace (screen y, flipped)
        const L = 2 * (frame.width + frame.height);
        outlined(ctx, () => {
          ctx.beginPath();
          ctx.moveTo(bx - L * ux, by - L * uy);
          ctx.lineTo(bx + L * ux, by + L * uy);
        }, colour, 1.5);
        // Normal tick: the side the plane pushes towards.
        outlined(ctx, () => {
          ctx.beginPath();
          ctx.moveTo(bx, by);
          ctx.lineTo(bx + (14 * nh) / n, by - (14 * nv) / n);
        }, colour, 2.5);
        break;
      }
      case 'directed': {
        const [qx, qy] = toPx(frame, proxy[h], proxy[v]);
        const len = (prim.strength_n || 0) / app.forceScale;
        const dx = D[h] * len;
        const dy = -D[v] * len;
        const shown = Math.hypot(dx, dy);
        const k = shown > 0 && shown < 12 ? 12 / shown : 1;
        arrow(ctx, qx, qy, qx + dx * k, qy + dy * k, colour, 1.5, true);
        break;
      }
      default:
        break;
    }
  }

  function updateForceScale() {
    // Keep the arrow of the largest force of the last 2 s between ~25 and ~110 px; 1, 2, 5 steps.
    const h = app.history;
    if (!h.length) return;
    const tEnd = h[h.length - 1].t;
    let peak = 0;
    for (let i = h.length - 1; i >= 0 && h[i].t >= tEnd - 2; i--) peak = Math.max(peak, h[i].mag);
    if (!(peak > 0)) return;
    const px = peak / app.forceScale;
    if (px > 110 || px < 25) {
      app.forceScale = Math.max(1e-5, niceCeil(peak / 80));
    }
  }

  /** How the probe (hollow ring) and the proxy (filled dot, drawn last) are drawn when their centres are at
   * `probe` and `proxy` (CSS px). The ring's inside stays clear of the dot (ring radius minus half its line
   * and outline > dot radius plus its outline), so with the proxy on the probe both stay visible as a dot in
   * a ring; when they are closer than MARKER_LABEL_PX the view also says "proxy on probe". */
  function markerLayout(probe, proxy, apartM, forceN) {
    const layout = { probeRadius: 9, probeLine: 2, proxyRadius: 4.5, proxyLine: 1.5, label: null };
    const apart = Math.hypot(probe[0] - proxy[0], probe[1] - proxy[1]);
    layout.apartPx = apart;
    if (apart < MARKER_LABEL_PX) {
      // Overlapping on screen: "proxy on probe" only when they coincide and no force is sent; in contact say so.
      const coincide = apartM <= PROXY_ON_PROBE_M && forceN <= PROXY_ON_PROBE_N;
      layout.label = coincide ? 'proxy on probe' : 'in contact, ' + length(apartM) + ' apart';
    }
    return layout;
  }

  function drawView(view) {
    const { ctx, width, height } = fitCanvas(view.canvas);
    ctx.fillStyle = '#1b1f24';
    ctx.fillRect(0, 0, width, height);
    const frame = viewFrame(view, width, height);
    view.frame = frame;
    ctx.fillStyle = '#000';
    ctx.fillRect(frame.left, frame.top, frame.width, frame.height);
    drawSlice(ctx, frame, view);
    drawAxes(ctx, frame, view);
    const s = app.state;
    if (!s) {
      ctx.fillStyle = '#d8dde3';
      ctx.font = '14px system-ui, sans-serif';
      ctx.textAlign = 'center';
      ctx.fillText('waiting for the server…', frame.left + frame.width / 2, frame.top + frame.height / 2);
      return;
    }
    const h = view.h;
    const v = view.v;
    setText(view.caption, 'slice at ' + AXIS_NAMES[view.w] + ' = ' + mm(view.sliceAt ? view.sliceAt[view.w] : s.proxy_m[view.w]) + ' mm');

    ctx.save();
    ctx.beginPath();
    ctx.rect(frame.left, frame.top, frame.width, frame.height);
    ctx.clip();

    for (const prim of Array.isArray(s.primitives) ? s.primitives : []) drawPrimitive(ctx, frame, view, prim, s.proxy_m);

    const [qx, qy] = toPx(frame, s.proxy_m[h], s.proxy_m[v]);
    const [px, py] = toPx(frame, s.probe_m[h], s.probe_m[v]);

    // Hand target (simulated arm): where a client pulls the virtual hand.
    const target = hand.dragging && hand.local ? hand.local : isVec3(s.hand_target_m) ? s.hand_target_m : null;
    if (target) {
      const [tx, ty] = toPx(frame, target[h], target[v]);
      ctx.setLineDash([3, 4]);
      outlined(ctx, () => {
        ctx.beginPath();
        ctx.moveTo(px, py);
        ctx.lineTo(tx, ty);
      }, COLOURS.hand, 1);
      ctx.setLineDash([]);
      outlined(ctx, () => {
        ctx.beginPath();
        ctx.moveTo(tx, ty - 8);
        ctx.lineTo(tx + 8, ty);
        ctx.lineTo(tx, ty + 8);
        ctx.lineTo(tx - 8, ty);
        ctx.closePath();
      }, COLOURS.hand, 1.5);
    }

    // Coupling spring (thin line probe -> proxy) and the force arrow first, then the probe and the proxy on
    // top of everything, the proxy last: at the proxy the primitives and the arrow start, and with no contact
    // the proxy sits on the probe (issue 17: "markers overlap at the proxy"). markerLayout says how.
    outlined(ctx, () => {
      ctx.beginPath();
      ctx.moveTo(px, py);
      ctx.lineTo(qx, qy);
    }, 'rgba(255,255,255,0.6)', 0.75);
    const f = isVec3(s.force_n) ? s.force_n : [0, 0, 0];
    arrow(ctx, qx, qy, qx + f[h] / app.forceScale, qy - f[v] / app.forceScale, COLOURS.force, 2.5, false);
    const apartM = norm([0, 1, 2].map((i) => s.proxy_m[i] - s.probe_m[i]));
    const layout = markerLayout([px, py], [qx, qy], apartM, norm(f));
    outlined(ctx, () => {
      ctx.beginPath();
      ctx.arc(px, py, layout.probeRadius, 0, 2 * Math.PI);
    }, COLOURS.probe, layout.probeLine);
    ctx.beginPath();
    ctx.arc(qx, qy, layout.proxyRadius, 0, 2 * Math.PI);
    ctx.fillStyle = COLOURS.proxy;
    ctx.fill();
    ctx.lineWidth = layout.proxyLine;
    ctx.strokeStyle = '#000';
    ctx.stroke();
    if (layout.label) {
      ctx.font = '600 11px system-ui, sans-serif';
      ctx.textAlign = 'left';
      ctx.textBaseline = 'middle';
      const lx = px + layout.probeRadius + 5;
      const ly = py - layout.probeRadius - 4;
      ctx.lineWidth = 3;
      ctx.strokeStyle = 'rgba(0,0,0,0.85)';
      ctx.strokeText(layout.label, lx, ly);
      ctx.fillStyle = '#fff';
      ctx.fillText(layout.label, lx, ly);
    }
    view.markers = { probe: [px, py], proxy: [qx, qy], layout: layout, order: ['primitives', 'hand', 'spring', 'force', 'probe', 'proxy'] };
    ctx.restore();

    // Scale bar for the force arrows (bottom right, inside the plot).
    const barN = niceStep(50 * app.forceScale, 1);
    const barPx = barN / app.forceScale;
    const bx1 = frame.left + frame.width - 8;
    const by = frame.top + frame.height - 10;
    ctx.fillStyle = 'rgba(0,0,0,0.6)';
    ctx.fillRect(bx1 - barPx - 62, by - 14, barPx + 68, 22);
    ctx.strokeStyle = COLOURS.force;
    ctx.lineWidth = 3;
    ctx.beginPath();
    ctx.moveTo(bx1 - barPx, by);
    ctx.lineTo(bx1, by);
    ctx.stroke();
    ctx.fillStyle = '#fff';
    ctx.font = '11px system-ui, sans-serif';
    ctx.textAlign = 'right';
    ctx.textBaseline = 'middle';
    ctx.fillText(trimNumber(barN) + ' N', bx1 - barPx - 4, by);

    if (!app.live) {
      // Not live: say so on the picture too (the badge at the top says why).
      const text = 'not live: last state received';
      ctx.font = '600 12px system-ui, sans-serif';
      const tw = ctx.measureText(text).width;
      ctx.fillStyle = 'rgba(120, 20, 20, 0.85)';
      ctx.fillRect(frame.left + 6, frame.top + 6, tw + 16, 22);
      ctx.fillStyle = '#fff';
      ctx.textAlign = 'left';
      ctx.fillText(text, frame.left + 14, frame.top + 17);
    }
  }

  // ---------------------------------------------------------------- drawing: force plot

  function drawPlot() {
    const canvas = $('force-plot');
    const { ctx, width, height } = fitCanvas(canvas);
    ctx.fillStyle = '#1b1f24';
    ctx.fillRect(0, 0, width, height);
    const left = 52;
    const right = 10;
    const top = 8;
    const bottom = 24;
    const pw = width - left - right;
    const ph = height - top - bottom;
    if (pw < 10 || ph < 10) return;
    const data = app.history;
    const tEnd = data.length ? data[data.length - 1].t : 0;
    const t0 = tEnd - PLOT_WINDOW_S;
    let lo = 0;
    let hi = 0;
    for (const d of data) {
      if (d.t < t0) continue;
      lo = Math.min(lo, d.fx, d.fy, d.fz);
      hi = Math.max(hi, d.mag, d.fx, d.fy, d.fz);
    }
    if (hi - lo < 0.05) {
      hi = Math.max(hi, 0.05);
    }
    const pad = (hi - lo) * 0.08;
    lo -= lo < 0 ? pad : 0;
    hi += pad;
    const X = (t) => left + ((t - t0) / PLOT_WINDOW_S) * pw;
    const Y = (f) => top + ph - ((f - lo) / (hi - lo)) * ph;

    ctx.font = '11px system-ui, sans-serif';
    ctx.fillStyle = '#d8dde3';
    ctx.strokeStyle = '#39424d';
    ctx.lineWidth = 1;
    const step = niceStep(hi - lo, Math.max(2, ph / 35));
    ctx.textAlign = 'right';
    ctx.textBaseline = 'middle';
    for (let f = Math.ceil(lo / step) * step; f <= hi + 1e-12; f += step) {
      const y = Math.round(Y(f)) + 0.5;
      ctx.beginPath();
      ctx.moveTo(left, y);
      ctx.lineTo(left + pw, y);
      ctx.stroke();
      ctx.fillText(trimNumber(f), left - 5, y);
    }
    ctx.textAlign = 'center';
    ctx.textBaseline = 'top';
    for (let k = 0; k <= PLOT_WINDOW_S; k += 2) {
      const x = X(t0 + k);
      ctx.fillText(k === PLOT_WINDOW_S ? 'now' : '−' + (PLOT_WINDOW_S - k) + ' s', x, top + ph + 5);
    }
    ctx.save();
    ctx.translate(12, top + ph / 2);
    ctx.rotate(-Math.PI / 2);
    ctx.textAlign = 'center';
    ctx.textBaseline = 'middle';
    ctx.fillText('force (N)', 0, 0);
    ctx.restore();
    ctx.strokeStyle = '#7d8793';
    ctx.strokeRect(left - 0.5, top - 0.5, pw + 1, ph + 1);

    ctx.save();
    ctx.beginPath();
    ctx.rect(left, top, pw, ph);
    ctx.clip();
    const series = [
      { key: 'fx', colour: COLOURS.fx, width: 1.25, dash: [] },
      { key: 'fy', colour: COLOURS.fy, width: 1.25, dash: [6, 4] },
      { key: 'fz', colour: COLOURS.fz, width: 1.5, dash: [1.5, 3] },
      { key: 'mag', colour: COLOURS.mag, width: 2.5, dash: [] },
    ];
    for (const line of series) {
      ctx.beginPath();
      let started = false;
      for (const d of data) {
        if (d.t < t0 - 0.1) continue;
        const x = X(d.t);
        const y = Y(d[line.key]);
        if (started) ctx.lineTo(x, y);
        else ctx.moveTo(x, y);
        started = true;
      }
      ctx.setLineDash(line.dash);
      ctx.lineWidth = line.width;
      ctx.strokeStyle = line.colour;
      ctx.stroke();
    }
    ctx.setLineDash([]);
    ctx.restore();
  }

  // ---------------------------------------------------------------- frame loop

  function frame() {
    if (app.dirty) {
      app.dirty = false;
      updateForceScale();
      setText($('force-scale'), '1 px = ' + trimNumber(app.forceScale) + ' N');
      for (const view of views) drawView(view);
      drawPlot();
    }
    requestAnimationFrame(frame);
  }

  // ---------------------------------------------------------------- virtual hand

  const hand = { dragging: null, local: null, pending: undefined, inflight: false, lastSent: 0, timer: null };

  function queueHand(position) {
    const problem = tokenProblem();
    if (problem) {
      // Say why once per drag; send nothing (issue 17: a drag without a token fired ~12 refused requests).
      showMsg($('hand-msg'), 'hand not moved: ' + problem, true);
      return;
    }
    hand.pending = position;
    pumpHand();
  }

  function pumpHand() {
    if (hand.inflight || hand.pending === undefined) return;
    const wait = HAND_PERIOD_MS - (performance.now() - hand.lastSent);
    if (wait > 0) {
      if (!hand.timer) {
        hand.timer = setTimeout(() => {
          hand.timer = null;
          pumpHand();
        }, wait);
      }
      return;
    }
    const position = hand.pending;
    hand.pending = undefined;
    hand.inflight = true;
    hand.lastSent = performance.now();
    post('api/hand', { position_m: position })
      .then(
        () => {
          if (position === null) showMsg($('hand-msg'), 'hand released: it follows its path again', false);
          else showMsg($('hand-msg'), 'pulling the hand to (' + position.map((x) => mm(x)).join(', ') + ') mm', false);
        },
        (e) => showMsg($('hand-msg'), e.message, true)
      )
      .finally(() => {
        hand.inflight = false;
        pumpHand();
      });
  }

  function eventToWorld(view, event, fixed) {
    const frame = view.frame;
    if (!frame) return null;
    const rect = view.canvas.getBoundingClientRect();
    const [a, b] = fromPx(frame, event.clientX - rect.left, event.clientY - rect.top);
    const position = [0, 0, 0];
    position[view.h] = a;
    position[view.v] = b;
    position[view.w] = fixed;
    return position;
  }

  function bindHand(view) {
    const canvas = view.canvas;
    canvas.addEventListener('pointerdown', (event) => {
      if (!app.simulated || !app.state || event.button !== 0) return;
      try {
        canvas.setPointerCapture(event.pointerId);
      } catch (e) {
        /* ignore */
      }
      // The coordinate this view does not show stays where the probe is now.
      hand.dragging = { view: view, pointerId: event.pointerId, fixed: app.state.probe_m[view.w] };
      moveHand(event);
    });
    canvas.addEventListener('pointermove', (event) => {
      if (hand.dragging && hand.dragging.pointerId === event.pointerId) moveHand(event);
    });
    const end = (event) => {
      if (!hand.dragging || hand.dragging.pointerId !== event.pointerId) return;
      hand.dragging = null;
      hand.local = null;
      queueHand(null);
      app.dirty = true;
    };
    canvas.addEventListener('pointerup', end);
    canvas.addEventListener('pointercancel', end);
    canvas.addEventListener('lostpointercapture', end);

    canvas.addEventListener('keydown', (event) => {
      if (!app.simulated || !app.state) return;
      const steps = { ArrowLeft: [-1, 0], ArrowRight: [1, 0], ArrowUp: [0, 1], ArrowDown: [0, -1] };
      if (event.key === 'Escape') {
        queueHand(null);
        event.preventDefault();
        return;
      }
      const step = steps[event.key];
      if (!step) return;
      event.preventDefault();
      const size = event.shiftKey ? 0.005 : 0.001;
      const start = isVec3(app.state.hand_target_m) ? app.state.hand_target_m : app.state.probe_m;
      const base = hand.keyTarget && performance.now() - hand.keyTime < 1500 ? hand.keyTarget : start;
      const position = base.slice();
      position[view.h] += step[0] * size;
      position[view.v] += step[1] * size;
      hand.keyTarget = position;
      hand.keyTime = performance.now();
      queueHand(position);
    });
  }

  function moveHand(event) {
    const position = eventToWorld(hand.dragging.view, event, hand.dragging.fixed);
    if (!position) return;
    hand.local = position;
    app.dirty = true;
    queueHand(position);
  }

  $('hand-release').addEventListener('click', () => {
    hand.keyTarget = null;
    queueHand(null);
  });

  // ---------------------------------------------------------------- start

  for (const view of views) bindHand(view);
  if (window.ResizeObserver) {
    const ro = new ResizeObserver(() => {
      app.dirty = true;
    });
    for (const view of views) ro.observe(view.canvas);
    ro.observe($('force-plot'));
  } else {
    window.addEventListener('resize', () => {
      app.dirty = true;
    });
  }
  setInterval(pollStats, 1000);
  setInterval(measureRates, 1000);
  pollStats();
  getJson('api/scene')
    .then((scene) => {
      if (!app.scene) setScene(scene);
    })
    .catch(() => {
      /* the hello brings it */
    });
  // For the headless browser test (.ci/browser-e2e.js): what the last draw of each view put where.
  window.voxhapPage = {
    markerLayout: markerLayout,
    // Closes the WebSocket as a lost connection would (the page then reconnects by itself).
    dropConnection: () => {
      if (conn.ws) conn.ws.close();
    },
    markers: () => views.map((view) => ({ axis: view.axis, markers: view.markers || null })),
  };
  connect();
  requestAnimationFrame(frame);
})();
