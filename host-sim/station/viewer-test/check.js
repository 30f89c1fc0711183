// An independent Foxglove WebSocket client (@foxglove/ws-protocol) that checks the base station's live view.
//
// Usage: node check.js --url ws://127.0.0.1:PORT --expect expect.json [--timeout SECONDS] [--name NAME]
//
// It subscribes to every advertised topic, decodes each message with the schema the server advertises
// (protobuf FileDescriptorSet through protobufjs, or JSON), applies scene updates as Foxglove does (entities
// replace entities of the same id; deletions by id or all), and waits until `--expect` exists (the test
// writes it from `map-info` / `map-query` once the stream is in). Then it checks, retrying until the
// timeout while updates still arrive:
//   1. the scene's voxels are exactly the map's (count and keys) and each voxel's class is map-query's;
//   2. after it sets the `query` parameter to the expected phrase, the heat layer's top voxels are the
//      ones `map-query --query` ranks top.
// Exit 0 with one line "viewer-check NAME: ok ..." or 1 with what differs.
"use strict";
const fs = require("fs");
const WebSocket = require("ws");
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const protobuf = require("protobufjs");
const descriptor = require("protobufjs/ext/descriptor");

function arg(name, fallback) {
  const i = process.argv.indexOf(`--${name}`);
  return i >= 0 ? process.argv[i + 1] : fallback;
}
const url = arg("url");
const expectPath = arg("expect");
const timeoutMs = Number(arg("timeout", "60")) * 1000;
const name = arg("name", "client");
if (!url || !expectPath) {
  console.error("usage: node check.js --url ws://HOST:PORT --expect expect.json");
  process.exit(2);
}

const subscriptions = new Map(); // subscription id -> {topic, decode(bytes) -> object}
const layers = new Map(); // topic -> Map(entity id -> {keys, values})
let legend = null;
let status = null;
let heatFullsAfterPhrase = 0;
let phraseSent = false;
let messages = 0;

function decoderFor(channel) {
  if (channel.encoding === "json") {
    const td = new TextDecoder();
    return (data) => JSON.parse(td.decode(data));
  }
  if (channel.encoding === "protobuf" && channel.schemaEncoding === "protobuf") {
    const fds = descriptor.FileDescriptorSet.decode(Buffer.from(channel.schema, "base64"));
    const root = protobuf.Root.fromDescriptor(fds);
    const type = root.lookupType(channel.schemaName);
    return (data) => type.toObject(type.decode(data), { longs: Number, enums: Number, defaults: true });
  }
  throw new Error(`${channel.topic}: unsupported encoding ${channel.encoding}/${channel.schemaEncoding}`);
}

function applySceneUpdate(topic, msg) {
  let entities = layers.get(topic);
  if (!entities) layers.set(topic, (entities = new Map()));
  let full = false;
  for (const d of msg.deletions) {
    if (d.type === 1) {
      entities.clear();
      full = true;
    } else {
      entities.delete(d.id);
    }
  }
  for (const e of msg.entities) {
    const meta = Object.fromEntries(e.metadata.map((kv) => [kv.key, kv.value]));
    const keys = meta.voxels ? meta.voxels.split(",") : [];
    const valueKey = e.metadata.find((kv) => kv.key !== "voxels");
    const values = valueKey && valueKey.value !== "" ? valueKey.value.split(",") : keys.map(() => "");
    if (keys.length !== e.cubes.length || values.length !== keys.length) {
      throw new Error(`${topic} ${e.id}: ${e.cubes.length} cubes, ${keys.length} keys, ${values.length} values`);
    }
    entities.set(e.id, { keys, values });
  }
  if (topic === "/map/heat" && full && phraseSent) heatFullsAfterPhrase += 1;
}

function voxels(topic) {
  const out = new Map();
  for (const { keys, values } of (layers.get(topic) || new Map()).values()) {
    keys.forEach((k, i) => out.set(k, values[i]));
  }
  return out;
}

function checkMap(expect) {
  const classes = voxels("/map/classes");
  if (classes.size !== expect.count) return `scene has ${classes.size} voxels, map-info says ${expect.count}`;
  const counts = new Array(expect.class_counts.length).fill(0);
  for (const [k, v] of classes) {
    const want = expect.classes[k];
    if (want === undefined) return `voxel ${k} is in the scene but not in the map`;
    if (String(want) !== v) return `voxel ${k}: class ${v} in the scene, ${want} from map-query`;
    counts[Number(v)] += 1;
  }
  if (JSON.stringify(counts) !== JSON.stringify(expect.class_counts)) {
    return `class counts ${counts} in the scene, ${expect.class_counts} from map-query`;
  }
  for (const t of ["/map/heat", "/map/uncertainty", "/map/robots"]) {
    const n = voxels(t).size;
    if (n !== expect.count) return `${t} has ${n} voxels, expected ${expect.count}`;
  }
  return null;
}

function checkHeat(expect) {
  if (heatFullsAfterPhrase === 0) return "the heat layer has not followed the phrase yet";
  const heat = [...voxels("/map/heat")].filter(([, s]) => s !== "").map(([k, s]) => [k, Number(s)]);
  heat.sort((a, b) => b[1] - a[1]);
  const top = heat.slice(0, expect.top_keys.length).map(([k]) => k);
  const want = expect.top_keys;
  if (JSON.stringify([...top].sort()) !== JSON.stringify([...want].sort())) {
    return `heat top ${JSON.stringify(top)} but map-query --query ranks ${JSON.stringify(want)}`;
  }
  return null;
}

const started = Date.now();
const ws = new WebSocket(url, ["foxglove.sdk.v1"]);
const client = new FoxgloveClient({ ws });
client.on("error", (e) => {
  console.error(`viewer-check ${name}: connection error: ${e && e.message}`);
  process.exit(1);
});
client.on("advertise", (channels) => {
  for (const ch of channels) {
    subscriptions.set(client.subscribe(ch.id), { topic: ch.topic, decode: decoderFor(ch) });
  }
});
client.on("message", ({ subscriptionId, data }) => {
  messages += 1;
  const { topic, decode } = subscriptions.get(subscriptionId);
  const msg = decode(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));
  if (topic === "/map/legend") legend = msg;
  else if (topic === "/link/status") status = msg;
  else applySceneUpdate(topic, msg);
});

let lastProblem = "nothing checked yet";
const tick = setInterval(() => {
  if (Date.now() - started > timeoutMs) {
    console.error(`viewer-check ${name}: FAILED after ${timeoutMs / 1000} s: ${lastProblem}`);
    process.exit(1);
  }
  if (!fs.existsSync(expectPath)) {
    lastProblem = `waiting for ${expectPath}`;
    return;
  }
  const expect = JSON.parse(fs.readFileSync(expectPath, "utf8"));
  const mapProblem = checkMap(expect);
  if (mapProblem) {
    lastProblem = mapProblem;
    return;
  }
  if (!phraseSent) {
    client.setParameters([{ name: "query", value: expect.phrase }], "set-query");
    phraseSent = true;
    lastProblem = "phrase sent";
    return;
  }
  const heatProblem = checkHeat(expect);
  if (heatProblem) {
    lastProblem = heatProblem;
    return;
  }
  if (!legend || legend.classes.length !== expect.class_counts.length || legend.query !== expect.phrase) {
    lastProblem = `legend ${JSON.stringify(legend)}`;
    return;
  }
  if (!status || typeof status.frames !== "number") {
    lastProblem = "no link status";
    return;
  }
  clearInterval(tick);
  console.log(
    `viewer-check ${name}: ok: ${expect.count} voxels and their classes equal map-info/map-query; ` +
      `heat top ${expect.top_keys.length} for "${expect.phrase}" equal map-query --query; ` +
      `${messages} messages; link frames ${status.frames}`,
  );
  client.close();
  process.exit(0);
}, 200);
