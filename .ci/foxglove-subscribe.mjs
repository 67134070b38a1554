// An independent Foxglove WebSocket client for .ci/check-foxglove-node.sh: the npm packages
// @foxglove/ws-protocol (FoxgloveClient) and ws connect to `voxhap serve`'s live view, subscribe to
// /voxhap/force and require at least N messages within a time limit, each a foxglove.Vector3 protobuf
// with finite components (decoded by hand: fields 1..3 are doubles).
//
// Usage: node foxglove-subscribe.mjs ws://127.0.0.1:PORT [N=60] [TIMEOUT_MS=10000]
// Exit 0 on success, 1 with a message saying what was missing. Run from a directory whose node_modules
// holds the two packages (the check script copies it into its temporary install).

import protocol from "@foxglove/ws-protocol";
import WebSocket from "ws";

const { FoxgloveClient } = protocol;
const url = process.argv[2];
const wanted = Number(process.argv[3] ?? 60);
const timeoutMs = Number(process.argv[4] ?? 10000);
const TOPIC = "/voxhap/force";
// The foxglove SDK's server speaks `foxglove.sdk.v1` (the same messages as the older
// `foxglove.websocket.v1`, which @foxglove/ws-protocol names as its default and the SDK refuses).
const SUBPROTOCOL = "foxglove.sdk.v1";

if (!url) {
  console.error("usage: node foxglove-subscribe.mjs ws://HOST:PORT [N] [TIMEOUT_MS]");
  process.exit(2);
}

const started = Date.now();
let serverName = null;
let forceChannel = null;
let received = 0;
let firstAt = null;
let last = null;
let done = false;

function finish(ok, message) {
  if (done) return;
  done = true;
  (ok ? console.log : console.error)(`foxglove-subscribe: ${ok ? "OK" : "FAILED"}: ${message}`);
  try {
    client.close();
  } catch {
    // already closed
  }
  process.exit(ok ? 0 : 1);
}

/** Decodes a foxglove.Vector3 (proto3: double x = 1, y = 2, z = 3; zero fields are omitted). */
function decodeVector3(view) {
  const vector = { x: 0, y: 0, z: 0 };
  let at = 0;
  while (at < view.byteLength) {
    const tag = view.getUint8(at);
    at += 1;
    const field = tag >> 3;
    const wireType = tag & 7;
    if (wireType !== 1 || field < 1 || field > 3 || at + 8 > view.byteLength) {
      throw new Error(`unexpected protobuf tag 0x${tag.toString(16)} at byte ${at - 1}`);
    }
    vector["xyz"[field - 1]] = view.getFloat64(at, true);
    at += 8;
  }
  return vector;
}

const ws = new WebSocket(url, [SUBPROTOCOL]);
const client = new FoxgloveClient({ ws });

client.on("open", () => {
  if (ws.protocol !== SUBPROTOCOL) {
    finish(false, `server chose subprotocol ${JSON.stringify(ws.protocol)}, expected ${SUBPROTOCOL}`);
  }
});
client.on("error", (error) => finish(false, `connection error: ${error?.message ?? error}`));
client.on("close", (event) =>
  finish(false, `connection closed after ${received} messages (code ${event?.code ?? "?"})`),
);
client.on("serverInfo", (info) => {
  serverName = info.name;
});
client.on("advertise", (channels) => {
  if (forceChannel !== null) return;
  const channel = channels.find((c) => c.topic === TOPIC);
  if (!channel) return;
  if (channel.schemaName !== "foxglove.Vector3" || channel.encoding !== "protobuf") {
    finish(false, `${TOPIC} advertised as ${channel.schemaName} (${channel.encoding}), expected foxglove.Vector3 (protobuf)`);
    return;
  }
  forceChannel = channel;
  client.subscribe(channel.id);
});
client.on("message", ({ data }) => {
  let force;
  try {
    force = decodeVector3(data);
  } catch (error) {
    finish(false, `message ${received + 1} on ${TOPIC}: ${error.message}`);
    return;
  }
  if (![force.x, force.y, force.z].every(Number.isFinite)) {
    finish(false, `non-finite force ${JSON.stringify(force)}`);
    return;
  }
  received += 1;
  firstAt ??= Date.now();
  last = force;
  if (received >= wanted) {
    const seconds = (Date.now() - firstAt) / 1000;
    const rate = seconds > 0 ? ((received - 1) / seconds).toFixed(1) : "n/a";
    finish(
      true,
      `${received} messages on ${TOPIC} from ${JSON.stringify(serverName)} in ${seconds.toFixed(2)} s ` +
        `(about ${rate} Hz); last force [${last.x.toFixed(4)}, ${last.y.toFixed(4)}, ${last.z.toFixed(4)}] N`,
    );
  }
});

setTimeout(() => {
  const what =
    serverName === null
      ? "no serverInfo"
      : forceChannel === null
        ? `${TOPIC} was not advertised`
        : `only ${received} of ${wanted} messages on ${TOPIC}`;
  finish(false, `${what} within ${timeoutMs} ms (connected for ${Date.now() - started} ms)`);
}, timeoutMs);
