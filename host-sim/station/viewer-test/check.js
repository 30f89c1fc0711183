// An independent Foxglove WebSocket client (@foxglove/ws-protocol) that checks the base station's live view.
//
// Usage: node check.js --url ws://127.0.0.1:PORT --expect expect.json [--timeout SECONDS] [--name NAME]
//        [--subprotocol foxglove.sdk.v1|foxglove.websocket.v1]
//
// It offers only the named subprotocol (default `foxglove.sdk.v1`; `foxglove.websocket.v1` is the published
// protocol's name, the only one older clients offer), subscribes to every advertised topic, decodes each
// message with the schema the server advertises (protobuf FileDescriptorSet through protobufjs, or JSON),
// applies scene updates as Foxglove does (entities replace entities of the same id; deletions by id or
// all), and waits until `--expect` exists (the test writes it once the stream is in: `count` and `phrase`
// always; from `map-info` / `map-query`, `classes`, `class_counts` and `top_keys`). Then it checks,
// retrying until the timeout while updates still arrive:
//   1. the scene holds `count` voxels on every layer (and, given `classes`, exactly the map's keys, each
//      with map-query's class);
//   2. every classes cube has its class's colour from the legend, the legend names every class, and the
//      layer shows as many distinct colours as classes that have voxels;
//   3. after it sets the `query` parameter to the phrase, the heat layer is re-sent whole with a score for
//      every voxel (given `top_keys`: its top voxels are the ones `map-query --query` ranks top);
//   4. the centre frame (`/tf`, map → map_centre) has arrived, and the heat cloud (`/map/heat_cloud`) holds
//      every voxel with a score after the phrase.
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
const subprotocol = arg("subprotocol", "foxglove.sdk.v1");
if (!url || !expectPath) {
  console.error("usage: node check.js --url ws://HOST:PORT --expect expect.json");
  process.exit(2);
}

const subscriptions = new Map(); // subscription id -> {topic, decode(bytes) -> object}
const layers = new Map(); // topic -> Map(entity id -> {keys, values})
let legend = null;
let status = null;
let centre = null;
let cloud = null; // the heat cloud: {points, scored, afterPhrase}
let phraseSentAt = 0;
let heatAfterPhraseMs = null;
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
    const byte = (v) => Math.round((v || 0) * 255);
    const colours = e.cubes.map((c) => `${byte(c.color.r)},${byte(c.color.g)},${byte(c.color.b)}`);
    entities.set(e.id, { keys, values, colours });
  }
  if (topic === "/map/heat" && full && phraseSent) {
    heatFullsAfterPhrase += 1;
    if (heatAfterPhraseMs === null) heatAfterPhraseMs = Date.now() - phraseSentAt;
  }
}

function voxels(topic) {
  const out = new Map();
  for (const { keys, values } of (layers.get(topic) || new Map()).values()) {
    keys.forEach((k, i) => out.set(k, values[i]));
  }
  return out;
}

let distinctColours = 0;
let classesWithVoxels = 0;

// Every classes cube in its class's legend colour; as many distinct colours as classes with voxels.
function checkColours() {
  if (!legend || !Array.isArray(legend.classes) || legend.classes.length === 0) return "the legend lists no classes";
  const named = legend.classes.filter((c) => typeof c.class === "string" && c.class.length > 0);
  if (named.length !== legend.classes.length) return `legend entries without a name: ${JSON.stringify(legend.classes)}`;
  const colourOf = new Map(legend.classes.map((c) => [String(c.index), c.rgb.join(",")]));
  const seen = new Set();
  const perClass = new Map();
  for (const { values, colours } of (layers.get("/map/classes") || new Map()).values()) {
    for (let i = 0; i < values.length; i++) {
      const want = colourOf.get(values[i]);
      if (want === undefined) return `a voxel without a class (${values[i]}) on /map/classes`;
      if (want !== colours[i]) return `a class ${values[i]} cube is ${colours[i]}, the legend says ${want}`;
      seen.add(colours[i]);
      perClass.set(values[i], (perClass.get(values[i]) || 0) + 1);
    }
  }
  distinctColours = seen.size;
  classesWithVoxels = perClass.size;
  if (seen.size < perClass.size) return `${seen.size} distinct colours for ${perClass.size} classes`;
  return null;
}

function checkMap(expect) {
  const classes = voxels("/map/classes");
  if (classes.size !== expect.count) return `scene has ${classes.size} voxels, expected ${expect.count}`;
  if (expect.classes) {
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
  if (heat.length !== expect.count) return `${heat.length} of ${expect.count} voxels have a score`;
  if (!expect.top_keys) return null;
  heat.sort((a, b) => b[1] - a[1]);
  const top = heat.slice(0, expect.top_keys.length).map(([k]) => k);
  const want = expect.top_keys;
  if (JSON.stringify([...top].sort()) !== JSON.stringify([...want].sort())) {
    return `heat top ${JSON.stringify(top)} but map-query --query ranks ${JSON.stringify(want)}`;
  }
  return null;
}

const started = Date.now();
const ws = new WebSocket(url, [subprotocol]);
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
  else if (topic === "/tf") centre = msg.transforms.find((t) => t.childFrameId === "map_centre") || centre;
  else if (topic === "/map/heat_cloud") {
    const view = new DataView(msg.data.buffer, msg.data.byteOffset, msg.data.byteLength);
    const points = msg.data.byteLength / msg.pointStride;
    const at = msg.fields.find((f) => f.name === "score").offset;
    let scored = 0;
    for (let i = 0; i < points; i++) scored += Number.isNaN(view.getFloat32(i * msg.pointStride + at, true)) ? 0 : 1;
    const afterMs = phraseSent ? (cloud && cloud.afterMs != null ? cloud.afterMs : Date.now() - phraseSentAt) : null;
    cloud = { points, scored, afterPhrase: phraseSent, afterMs };
  }
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
  const colourProblem = checkColours();
  if (colourProblem) {
    lastProblem = colourProblem;
    return;
  }
  if (!phraseSent) {
    client.setParameters([{ name: "query", value: expect.phrase }], "set-query");
    phraseSent = true;
    phraseSentAt = Date.now();
    lastProblem = "phrase sent";
    return;
  }
  const heatProblem = checkHeat(expect);
  if (heatProblem) {
    lastProblem = heatProblem;
    return;
  }
  const classCount = expect.class_counts ? expect.class_counts.length : legend.classes.length;
  if (legend.classes.length !== classCount || legend.query !== expect.phrase || legend.query_error) {
    lastProblem = `legend ${JSON.stringify(legend)}`;
    return;
  }
  if (!centre) {
    lastProblem = "no centre frame on /tf";
    return;
  }
  if (!cloud || !cloud.afterPhrase || cloud.points !== expect.count || cloud.scored !== expect.count) {
    lastProblem = `heat cloud ${JSON.stringify(cloud)}, expected ${expect.count} scored points after the phrase`;
    return;
  }
  if (!status || typeof status.frames !== "number") {
    lastProblem = "no link status";
    return;
  }
  clearInterval(tick);
  const names = legend.classes.map((c) => c.class).join(", ");
  console.log(
    `viewer-check ${name}: ok over ${ws.protocol}: ${expect.count} voxels` +
      (expect.classes ? " and their classes equal map-info/map-query" : "") +
      `; ${distinctColours} distinct class colours for ${classesWithVoxels} classes with voxels, legend names ${legend.classes.length} (${names}); ` +
      `heat for "${expect.phrase}" re-sent whole ${heatAfterPhraseMs} ms after the phrase was set ` +
      `(as a point cloud: ${cloud.afterMs} ms)` +
      (expect.top_keys ? `, top ${expect.top_keys.length} equal map-query --query` : "") +
      `; ${messages} messages; link frames ${status.frames}`,
  );
  client.close();
  process.exit(0);
}, 200);
