// Mounts Foxglove Studio's App (the @foxglove/studio-base 1.48.0 web bundle, loaded by index.html as globals) the way
// Foxglove's own web app does (packages/studio-web/src/Root.tsx at v1.48.0), with the two data sources this check
// uses (a recording by URL, the Foxglove WebSocket live view) and, instead of IndexedDB/localStorage, in-memory
// settings and a layout store holding only the layout under test (fetched from /layout.json, id "voxhap").
// Everything the viewer reports through studio-base's reportError hook is kept in window.__viewerErrors for
// the driver (.ci/viewer/check.mjs).
"use strict";
(async function main() {
  const S = window; // the bundle's exports: App, RemoteDataSourceFactory, ...
  window.__viewerErrors = [];
  S.setReportErrorHandler((error, type) => {
    window.__viewerErrors.push(`reportError (${type}): ${error && error.stack ? error.stack : error}`);
  });

  const settings = new Map();
  const listeners = new Map();
  const appConfiguration = {
    get: (key) => settings.get(key),
    set: async (key, value) => {
      settings.set(key, value);
      for (const l of listeners.get(key) || []) l(value);
    },
    addChangeListener: (key, l) => listeners.set(key, [...(listeners.get(key) || []), l]),
    removeChangeListener: (key, l) => listeners.set(key, (listeners.get(key) || []).filter((x) => x !== l)),
  };

  const data = await (await fetch("/layout.json")).json();
  const layouts = new Map();
  layouts.set("voxhap", {
    id: "voxhap",
    name: "voxhap",
    permission: "CREATOR_WRITE",
    baseline: { data, savedAt: new Date().toISOString() },
    working: undefined,
    syncInfo: undefined,
  });
  const layoutStorage = {
    list: async () => [...layouts.values()],
    get: async (_ns, id) => layouts.get(id),
    put: async (_ns, layout) => (layouts.set(layout.id, layout), layout),
    delete: async (_ns, id) => void layouts.delete(id),
    importLayouts: async () => {},
    migrateUnnamespacedLayouts: async () => {},
  };

  const app = React.createElement(S.App, {
    deepLinks: [window.location.href],
    dataSources: [new S.RemoteDataSourceFactory(), new S.FoxgloveWebSocketDataSourceFactory()],
    appConfiguration,
    layoutStorage,
    extensionLoaders: [],
    enableGlobalCss: true,
  });
  ReactDOM.render(app, document.getElementById("root"));
})().catch((e) => {
  window.__viewerErrors = window.__viewerErrors || [];
  window.__viewerErrors.push(`mounting the app failed: ${e && e.stack ? e.stack : e}`);
});
