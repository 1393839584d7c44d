// A live-view client written against the Foxglove WebSocket protocol's
// published library (npm @foxglove/ws-protocol, installed by
// deploy/setup-tools.sh into .node/). It subscribes to one robot's topics,
// stops once every topic has delivered `min` messages (or after `seconds`),
// and prints one JSON object: per topic, its schema, encoding, message count
// and bytes, plus the last mission status (a JSON topic) it decoded.
//
//   node client.cjs ws://127.0.0.1:8765 husky-1 60 5
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");

const [url, robot, seconds = "60", min = "5"] = process.argv.slice(2);
const topics = [
  "camera/image",
  "camera/annotations",
  "camera/depth",
  "segmenter/no_go",
  "scene",
  "tf",
  "cmd_vel",
  "mission/status",
].map((t) => `/${robot}/${t}`);

// The SDK's servers speak "foxglove.sdk.v1", the same messages as the
// library's "foxglove.websocket.v1"; offer both, as Foxglove's apps do.
const ws = new WebSocket(url, ["foxglove.sdk.v1", FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
const client = new FoxgloveClient({ ws });
const bySubscription = new Map();
const seen = {};
let status = null;
let serverName = null;

function done(code) {
  console.log(JSON.stringify({ server: serverName, topics: seen, status }));
  process.exit(code);
}

client.on("serverInfo", (info) => {
  serverName = info.name;
});
client.on("advertise", (channels) => {
  for (const c of channels) {
    if (topics.includes(c.topic) && !seen[c.topic]) {
      seen[c.topic] = { schema: c.schemaName, encoding: c.encoding, count: 0, bytes: 0 };
      bySubscription.set(client.subscribe(c.id), c.topic);
    }
  }
});
client.on("message", ({ subscriptionId, data }) => {
  const topic = bySubscription.get(subscriptionId);
  if (!topic) return;
  seen[topic].count += 1;
  seen[topic].bytes += data.byteLength;
  if (topic.endsWith("/mission/status")) {
    const text = new TextDecoder().decode(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));
    const s = JSON.parse(text);
    if (s.mission_id) status = s;
  }
  if (topics.every((t) => seen[t] && seen[t].count >= Number(min)) && status) done(0);
});
client.on("error", (e) => {
  console.error(`live view client: ${e && e.message ? e.message : e}`);
  done(1);
});
client.on("close", () => done(2));
setTimeout(() => done(3), Number(seconds) * 1000);
