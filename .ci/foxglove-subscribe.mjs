// An independent Foxglove WebSocket client for .ci/check-foxglove-node.sh: the npm packages
// @foxglove/ws-protocol (FoxgloveClient), ws and protobufjs connect to `voxhap serve`'s live view and check:
//
// - /voxhap/setpoint_cf: at least N messages within the time limit, each a foxglove.Vector3 with finite
//   components (decoded by hand: fields 1..3 are doubles);
// - /voxhap/volume: a foxglove.SceneUpdate with the volume's bounding box (12 edges) and an iso-surface mesh
//   (indexed triangles), decoded with protobufjs from the schema the server advertises;
// - /voxhap/volume/slice_x, _y, _z: foxglove.Grid slices whose data holds column_count x rows cells;
// - /voxhap/volume_frame: foxglove.FrameTransform messages for the frames `volume` (the volume's centre) and
//   `volume_view` (the camera framing), among them the frame the layout's 3D panel follows (followTf);
// - the shipped Foxglove layout (contrib/foxglove/voxhap-layout.json) refers only to advertised topics.
//
// Usage: node foxglove-subscribe.mjs ws://127.0.0.1:PORT LAYOUT.json [N=60] [TIMEOUT_MS=15000]
// Exit 0 on success, 1 with a message saying what was missing. Run from a directory whose node_modules
// holds the packages (the check script copies it into its temporary install).

import fs from "node:fs";
import protocol from "@foxglove/ws-protocol";
import protobuf from "protobufjs";
import descriptor from "protobufjs/ext/descriptor/index.js";
import WebSocket from "ws";

const { FoxgloveClient } = protocol;
const url = process.argv[2];
const layoutPath = process.argv[3];
const wanted = Number(process.argv[4] ?? 60);
const timeoutMs = Number(process.argv[5] ?? 15000);
const FORCE = "/voxhap/setpoint_cf";
const VOLUME = "/voxhap/volume";
const VOLUME_FRAME = "/voxhap/volume_frame";
const SLICES = ["/voxhap/volume/slice_x", "/voxhap/volume/slice_y", "/voxhap/volume/slice_z"];
// The subprotocol @foxglove/ws-protocol's client offers by default (`foxglove.websocket.v1`, the older name of
// the protocol the foxglove SDK calls `foxglove.sdk.v1`): voxhap accepts both and answers with the name asked.
const SUBPROTOCOL = FoxgloveClient.SUPPORTED_SUBPROTOCOL;

/** What Lichtblick's / Foxglove Studio's parseJsonSchema (packages/mcap-support) refuses in a JSON schema, or
 * null: the root and every nested object is "type": "object" with "properties"; each field's type is one of
 * boolean, string, number, integer, object, array (a list such as ["number", "null"] or no type is refused, and
 * the viewer drops the topic); array items likewise. */
function jsonSchemaProblem(schema, path) {
  const scalars = ["boolean", "string", "number", "integer"];
  if (schema.type !== "object") return `${path}: type ${JSON.stringify(schema.type)}, not "object"`;
  if (!schema.properties || typeof schema.properties !== "object") return `${path}: an object without properties`;
  for (const [name, field] of Object.entries(schema.properties)) {
    const at = `${path}.${name}`;
    if (field.type === "object") {
      const problem = jsonSchemaProblem(field, at);
      if (problem) return problem;
    } else if (field.type === "array") {
      const items = field.items ?? {};
      if (items.type === "object") {
        const problem = jsonSchemaProblem(items, at);
        if (problem) return problem;
      } else if (!scalars.includes(items.type)) {
        return `${at}: array item type ${JSON.stringify(items.type)}`;
      }
    } else if (!scalars.includes(field.type)) {
      return `${at}: field type ${JSON.stringify(field.type)}`;
    }
  }
  return null;
}

if (!url || !layoutPath) {
  console.error("usage: node foxglove-subscribe.mjs ws://HOST:PORT LAYOUT.json [N] [TIMEOUT_MS]");
  process.exit(2);
}

/** The topics a Foxglove layout refers to: 3D panel topics, plot/state paths, raw-message topic paths. */
function layoutTopics(layout) {
  const topics = new Set();
  for (const config of Object.values(layout.configById ?? {})) {
    for (const topic of Object.keys(config.topics ?? {})) topics.add(topic);
    for (const path of config.paths ?? []) topics.add(path.value.split(".")[0]);
    if (config.topicPath) topics.add(config.topicPath.split(".")[0]);
  }
  return [...topics];
}

const layout = JSON.parse(fs.readFileSync(layoutPath, "utf8"));
// The frames the layout's 3D panels follow.
const followed = Object.values(layout.configById ?? {})
  .map((config) => config.followTf)
  .filter((frame) => typeof frame === "string");
const started = Date.now();
let serverName = null;
const channelsByTopic = new Map();
const channelsById = new Map();
const decoders = new Map();
let forces = 0;
let firstForceAt = null;
let lastForce = null;
let mesh = null;
const frames = new Map();
const slices = new Map();
let layoutChecked = false;
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

/** A protobufjs type for a channel, from the FileDescriptorSet the server advertised. */
function decoderFor(channel) {
  if (!decoders.has(channel.id)) {
    if (channel.encoding !== "protobuf") throw new Error(`${channel.topic} is ${channel.encoding}, not protobuf`);
    const set = descriptor.FileDescriptorSet.decode(Buffer.from(channel.schema, "base64"));
    const root = protobuf.Root.fromDescriptor(set);
    decoders.set(channel.id, root.lookupType(channel.schemaName));
  }
  return decoders.get(channel.id);
}

function checkAll() {
  const framed = ["volume", "volume_view", ...followed].every((frame) => frames.has(frame));
  if (forces >= wanted && mesh && slices.size === SLICES.length && framed && layoutChecked) {
    const seconds = (Date.now() - firstForceAt) / 1000;
    const rate = seconds > 0 ? ((forces - 1) / seconds).toFixed(1) : "n/a";
    finish(
      true,
      `${forces} messages on ${FORCE} from ${JSON.stringify(serverName)} in ${seconds.toFixed(2)} s ` +
        `(about ${rate} Hz), last force [${lastForce.x.toFixed(4)}, ${lastForce.y.toFixed(4)}, ${lastForce.z.toFixed(4)}] N; ` +
        `volume mesh of ${mesh.triangles} triangles in a box of ${mesh.edges} edges; slices ` +
        [...slices.entries()].map(([topic, size]) => `${topic.split("_").pop()} ${size}`).join(", ") +
        `; frames ${[...frames.entries()].map(([frame, at]) => `${frame} at [${at.map((v) => v.toFixed(3)).join(", ")}] m`).join(", ")}` +
        ` (the layout follows ${followed.join(", ")})` +
        `; the layout's ${layoutTopics(layout).length} topics are all advertised`,
    );
  }
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
  finish(false, `connection closed after ${forces} force messages (code ${event?.code ?? "?"})`),
);
client.on("serverInfo", (info) => {
  serverName = info.name;
});
client.on("advertise", (channels) => {
  for (const channel of channels) {
    if (channelsByTopic.has(channel.topic)) continue;
    channelsByTopic.set(channel.topic, channel);
    if (channel.schemaEncoding === "jsonschema") {
      const problem = jsonSchemaProblem(JSON.parse(channel.schema), channel.schemaName);
      if (problem) {
        finish(false, `${channel.topic}: Foxglove and Lichtblick refuse its JSON schema: ${problem}`);
        return;
      }
    }
    if (channel.topic === FORCE && (channel.schemaName !== "foxglove.Vector3" || channel.encoding !== "protobuf")) {
      finish(false, `${FORCE} advertised as ${channel.schemaName} (${channel.encoding}), expected foxglove.Vector3`);
      return;
    }
    if ([FORCE, VOLUME, VOLUME_FRAME, ...SLICES].includes(channel.topic)) {
      const id = client.subscribe(channel.id);
      channelsById.set(id, channel);
    }
  }
  const missing = layoutTopics(layout).filter((topic) => !channelsByTopic.has(topic));
  if (missing.length === 0) {
    layoutChecked = true;
  } else if (Date.now() - started > 3000) {
    finish(false, `the layout refers to topics the server does not advertise: ${missing.join(", ")}`);
  }
});
client.on("message", ({ subscriptionId, data }) => {
  const channel = channelsById.get(subscriptionId);
  if (!channel) return;
  try {
    if (channel.topic === FORCE) {
      const force = decodeVector3(data);
      if (![force.x, force.y, force.z].every(Number.isFinite)) throw new Error(`non-finite force ${JSON.stringify(force)}`);
      forces += 1;
      firstForceAt ??= Date.now();
      lastForce = force;
    } else if (channel.topic === VOLUME) {
      const type = decoderFor(channel);
      const update = type.toObject(type.decode(new Uint8Array(data.buffer, data.byteOffset, data.byteLength)));
      const entities = update.entities ?? [];
      const bounds = entities.find((e) => e.id === "volume/bounds");
      const surface = entities.find((e) => e.id === "volume/surface");
      if (!bounds || (bounds.lines?.[0]?.points?.length ?? 0) !== 24) throw new Error("no 12-edge bounding box");
      const triangles = surface?.triangles?.[0];
      const indices = triangles?.indices ?? [];
      if (indices.length < 3 || indices.length % 3 !== 0) throw new Error(`mesh with ${indices.length} indices`);
      if (!indices.every((i) => i < triangles.points.length)) throw new Error("mesh index out of range");
      mesh = { triangles: indices.length / 3, edges: bounds.lines[0].points.length / 2 };
    } else if (channel.topic === VOLUME_FRAME) {
      const type = decoderFor(channel);
      const frame = type.toObject(type.decode(new Uint8Array(data.buffer, data.byteOffset, data.byteLength)));
      const t = frame.translation ?? {};
      const at = [t.x ?? 0, t.y ?? 0, t.z ?? 0];
      if (frame.parentFrameId !== "world" || !at.every(Number.isFinite)) {
        throw new Error(`frame ${frame.childFrameId} in ${frame.parentFrameId} at ${at}`);
      }
      frames.set(frame.childFrameId, at);
    } else {
      const type = decoderFor(channel);
      const grid = type.toObject(type.decode(new Uint8Array(data.buffer, data.byteOffset, data.byteLength)), { bytes: Array });
      const cells = grid.data.length / grid.cellStride;
      const rows = cells / grid.columnCount;
      if (!Number.isInteger(rows) || rows < 2 || grid.rowStride !== grid.columnCount * grid.cellStride) {
        throw new Error(`grid of ${grid.data.length} bytes, ${grid.columnCount} columns, stride ${grid.cellStride}`);
      }
      slices.set(channel.topic, `${grid.columnCount}x${rows}`);
    }
  } catch (error) {
    finish(false, `${channel.topic}: ${error.message}`);
    return;
  }
  checkAll();
});

setTimeout(() => {
  const missing = [];
  if (serverName === null) missing.push("no serverInfo");
  if (forces < wanted) missing.push(`only ${forces} of ${wanted} messages on ${FORCE}`);
  if (!mesh) missing.push(`no volume mesh on ${VOLUME}`);
  if (slices.size < SLICES.length) missing.push(`slices only on [${[...slices.keys()].join(", ")}]`);
  const absentFrames = ["volume", "volume_view", ...followed].filter((frame) => !frames.has(frame));
  if (absentFrames.length > 0) missing.push(`no frame ${absentFrames.join(", ")} on ${VOLUME_FRAME}`);
  if (!layoutChecked) {
    const absent = layoutTopics(layout).filter((topic) => !channelsByTopic.has(topic));
    missing.push(`layout topics not advertised: ${absent.join(", ")}`);
  }
  finish(false, `${missing.join("; ")} within ${timeoutMs} ms (connected for ${Date.now() - started} ms)`);
}, timeoutMs);
