// placeholder: the page script comes from branch `web` (web/app.js); served at /app.js by src/server/assets.rs
