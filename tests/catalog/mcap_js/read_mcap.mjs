// Reads a Dyana shard's MCAP with the MCAP project's TypeScript library (@mcap/core) and
// protobufjs, and prints what the Python test compares with the shard's tables, as JSON.
// Usage: node read_mcap.mjs NODE_MODULES_PARENT FILE.mcap
import { open } from "node:fs/promises";
import { createRequire } from "node:module";
import { join } from "node:path";

const [modulesParent, path] = process.argv.slice(2);
const require = createRequire(join(modulesParent, "package.json"));
const { McapIndexedReader } = require("@mcap/core");
const protobuf = require("protobufjs");
const descriptor = require("protobufjs/ext/descriptor");

const handle = await open(path, "r");
const readable = {
  size: async () => BigInt((await handle.stat()).size),
  read: async (offset, length) => {
    const buffer = new Uint8Array(Number(length));
    const { bytesRead } = await handle.read(buffer, 0, Number(length), Number(offset));
    if (bytesRead !== Number(length)) throw new Error(`short read at ${offset}`);
    return buffer;
  },
};
const reader = await McapIndexedReader.Initialize({ readable });

const metadata = [];
for (const index of reader.metadataIndexes) {
  const records = [];
  for await (const record of reader.readMetadata({ name: index.name })) records.push(record);
  if (records.length !== 1) throw new Error(`${records.length} metadata records named ${index.name}`);
  metadata.push({ name: index.name, data: Object.fromEntries(records[0].metadata) });
}

const types = new Map();
function typeOf(schemaId) {
  if (!types.has(schemaId)) {
    const schema = reader.schemasById.get(schemaId);
    if (schema.encoding !== "protobuf") throw new Error(`schema ${schema.name} is ${schema.encoding}`);
    const root = protobuf.Root.fromDescriptor(descriptor.FileDescriptorSet.decode(schema.data));
    types.set(schemaId, root.lookupType(schema.name));
  }
  return types.get(schemaId);
}
const xyz = (v) => [v.x, v.y, v.z];
const stamp = (t) => (BigInt(t.seconds) * 1000000000n + BigInt(t.nanos)).toString();

const topics = {};
const tf = [];
const skeleton = [];
for await (const message of reader.readMessages({ validateCrcs: true })) {
  const channel = reader.channelsById.get(message.channelId);
  const schema = reader.schemasById.get(channel.schemaId);
  const entry = (topics[channel.topic] ??= { schema: schema.name, log_times: [], publish_times: [] });
  entry.log_times.push(message.logTime.toString());
  entry.publish_times.push(message.publishTime.toString());
  if (channel.topic !== "/tf" && channel.topic !== "/hand/skeleton") continue;
  const type = typeOf(channel.schemaId);
  const decoded = type.toObject(type.decode(message.data), { longs: String, defaults: true });
  if (channel.topic === "/tf") {
    tf.push(decoded.transforms.map((t) => ({
      parent: t.parent_frame_id, child: t.child_frame_id, stamp: stamp(t.timestamp),
      translation: xyz(t.translation), rotation: [...xyz(t.rotation), t.rotation.w],
    })));
  } else {
    skeleton.push(decoded.entities.map((e) => ({
      id: e.id, frame_id: e.frame_id, stamp: stamp(e.timestamp),
      lines: e.lines.map((l) => ({ type: l.type, points: l.points.map(xyz), indices: l.indices })),
    })));
  }
}
await handle.close();
process.stdout.write(JSON.stringify({
  library: reader.header.library, profile: reader.header.profile,
  message_count: reader.statistics.messageCount.toString(), metadata, topics, tf, skeleton,
}));
