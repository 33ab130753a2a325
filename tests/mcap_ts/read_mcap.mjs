// Reads an MCAP file with @mcap/core twice, with the indexed reader (what Foxglove opens files
// with) and with the stream reader (every record in file order, CRCs checked), and prints one JSON
// object: per topic its encodings, schema, message count and a digest of its messages in sequence
// order; metadata; attachment digests. Exits 1 if the two readings differ.
import { createHash } from "node:crypto";
import { open, readFile } from "node:fs/promises";
import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { FileHandleReadable } from "@mcap/nodejs";
import { loadDecompressHandlers } from "@mcap/support";

// digest input per message: log time (u64 LE), sequence (u32 LE), data length (u32 LE), data
function digest(messages) {
  const hash = createHash("sha256");
  messages.sort((a, b) => a.sequence - b.sequence);
  for (const m of messages) {
    const head = Buffer.alloc(16);
    head.writeBigUInt64LE(m.logTime, 0);
    head.writeUInt32LE(m.sequence, 8);
    head.writeUInt32LE(m.data.byteLength, 12);
    hash.update(head);
    hash.update(m.data);
  }
  return hash.digest("hex");
}

function sha256(data) {
  return createHash("sha256").update(data).digest("hex");
}

function describe(channels, schemas, byChannel) {
  const topics = {};
  for (const [id, channel] of channels) {
    const schema = schemas.get(channel.schemaId);
    const messages = byChannel.get(id) ?? [];
    topics[channel.topic] = {
      messageEncoding: channel.messageEncoding,
      schemaName: schema?.name ?? null,
      schemaEncoding: schema?.encoding ?? null,
      schema: schema ? JSON.parse(new TextDecoder().decode(schema.data)) : null,
      count: messages.length,
      digest: digest(messages),
    };
  }
  return topics;
}

const path = process.argv[2];
const decompressHandlers = await loadDecompressHandlers();

const handle = await open(path, "r");
const indexed = await McapIndexedReader.Initialize({ readable: new FileHandleReadable(handle), decompressHandlers });
const byChannel = new Map();
for await (const m of indexed.readMessages({ validateCrcs: true })) {
  if (!byChannel.has(m.channelId)) byChannel.set(m.channelId, []);
  byChannel.get(m.channelId).push(m);
}
const metadata = {};
for await (const m of indexed.readMetadata()) metadata[m.name] = Object.fromEntries(m.metadata);
const attachments = {};
for await (const a of indexed.readAttachments({ validateCrcs: true })) attachments[a.name] = { mediaType: a.mediaType, sha256: sha256(a.data) };
const result = {
  library: indexed.header.library,
  profile: indexed.header.profile,
  messageCount: Number(indexed.statistics?.messageCount ?? -1),
  chunks: indexed.chunkIndexes.length,
  compression: [...new Set(indexed.chunkIndexes.map((c) => c.compression))],
  topics: describe(indexed.channelsById, indexed.schemasById, byChannel),
  metadata,
  attachments,
};
await handle.close();

const stream = new McapStreamReader({ decompressHandlers, validateCrcs: true });
stream.append(await readFile(path));
const channels = new Map(), schemas = new Map(), streamed = new Map();
let record, sawFooter = false;
while ((record = stream.nextRecord())) {
  if (record.type === "Schema") schemas.set(record.id, record);
  else if (record.type === "Channel") channels.set(record.id, record);
  else if (record.type === "Message") {
    if (!streamed.has(record.channelId)) streamed.set(record.channelId, []);
    streamed.get(record.channelId).push(record);
  } else if (record.type === "Footer") sawFooter = true;
}
const again = describe(channels, schemas, streamed);
if (!stream.done() || !sawFooter || JSON.stringify(again) !== JSON.stringify(result.topics)) {
  console.error("the stream reader and the indexed reader disagree, or the file does not end with a footer");
  process.exit(1);
}
console.log(JSON.stringify(result));
