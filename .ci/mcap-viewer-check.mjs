// Reads one MCAP file with @mcap/core's McapIndexedReader (installed by .ci/check-mcap-viewers.sh at the version
// Lichtblick pins) and checks what Foxglove Studio and Lichtblick need to open and play it (see that script).
// Usage: node mcap-viewer-check.mjs FILE.mcap. Exit 0 and one report line, or 1 with the problem.
import fs from "node:fs/promises";
import { McapIndexedReader } from "@mcap/core";

const path = process.argv[2];
function fail(message) {
  console.error(`mcap-viewer-check: ${path}: FAILED: ${message}`);
  process.exit(1);
}

/** Lichtblick's / Foxglove Studio's parseJsonSchema rules (packages/mcap-support/src/parseJsonSchema.ts): the
 * problem it throws on, or null. */
function jsonSchemaProblem(schema, at) {
  const scalars = ["boolean", "string", "number", "integer"];
  if (schema.type !== "object") return `${at}: type ${JSON.stringify(schema.type)}, not "object"`;
  if (!schema.properties || typeof schema.properties !== "object") return `${at}: an object without properties`;
  for (const [name, field] of Object.entries(schema.properties)) {
    const key = `${at}.${name}`;
    if (field.type === "object") {
      const problem = jsonSchemaProblem(field, key);
      if (problem) return problem;
    } else if (field.type === "array") {
      const items = field.items ?? {};
      if (items.type === "object") {
        const problem = jsonSchemaProblem(items, key);
        if (problem) return problem;
      } else if (!scalars.includes(items.type)) {
        return `${key}: array item type ${JSON.stringify(items.type)}`;
      }
    } else if (!scalars.includes(field.type)) {
      return `${key}: field type ${JSON.stringify(field.type)}`;
    }
  }
  return null;
}

const handle = await fs.open(path, "r");
const readable = {
  size: async () => BigInt((await handle.stat()).size),
  read: async (offset, length) => {
    const buffer = new Uint8Array(Number(length));
    await handle.read(buffer, 0, Number(length), Number(offset));
    return buffer;
  },
};
let reader;
try {
  reader = await McapIndexedReader.Initialize({ readable });
} catch (error) {
  fail(`the indexed reader refuses it: ${error.message}`);
}
if (reader.chunkIndexes.length === 0) fail("no chunks");
for (const [i, chunk] of reader.chunkIndexes.entries()) {
  if (chunk.messageIndexOffsets.size === 0) fail(`chunk ${i} has no message indexes`);
}
const stats = reader.statistics;
if (!stats) fail("no statistics in the summary");
let count = 0;
let first;
let last;
try {
  for await (const message of reader.readMessages()) {
    if (first === undefined) first = message.logTime;
    if (last !== undefined && message.logTime < last) fail("messages out of log-time order");
    last = message.logTime;
    count += 1;
  }
} catch (error) {
  fail(`reading the messages: ${error.message}`);
}
if (count === 0) fail("no messages");
if (stats.messageStartTime !== first) fail(`statistics start ${stats.messageStartTime}, first message ${first}`);
if (stats.messageEndTime !== last) fail(`statistics end ${stats.messageEndTime}, last message ${last}`);
if (BigInt(count) !== stats.messageCount) fail(`${count} messages read, the statistics say ${stats.messageCount}`);
// Wall-clock UTC: after 2020-01-01, not 1970.
if (first < 1577836800n * 1000000000n) fail(`the recording starts at ${first} ns, before 2020`);
for (const schema of reader.schemasById.values()) {
  if (schema.encoding !== "jsonschema") continue;
  const problem = jsonSchemaProblem(JSON.parse(new TextDecoder().decode(schema.data)), schema.name);
  if (problem) fail(`Foxglove and Lichtblick refuse the JSON schema: ${problem}`);
}
await handle.close();
console.log(
  `mcap-viewer-check: ${path}: ok: ${reader.chunkIndexes.length} chunks, all indexed; ${count} messages from ` +
    `${new Date(Number(first / 1000000n)).toISOString()}; ${reader.schemasById.size} schemas`,
);
