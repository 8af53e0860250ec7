// The session recording of the API test run, read after tendrild stopped (SIGTERM) by an independent
// reader (@mcap/core): every file finalised (footer, summary, CRCs), the robots' topics and the safety
// events in log-time order with no message missing (continuous sequences, no drops), and every command
// the suites sent on /commands with who sent it and how it ended — executed and refused ones alike.
// Run by tests/api/run.sh after check_clean_shutdown, with TENDRIL_RECORDING_DIR set.
import { test } from "node:test";
import assert from "node:assert/strict";
import { readFileSync, readdirSync } from "node:fs";
import { join } from "node:path";
import { McapIndexedReader } from "@mcap/core";
import zstd from "@foxglove/wasm-zstd";
import lz4 from "@foxglove/wasm-lz4";
import protobuf from "protobufjs";
import descriptor from "protobufjs/ext/descriptor/index.js";

const dir = process.env.TENDRIL_RECORDING_DIR;
if (!dir) throw new Error("set TENDRIL_RECORDING_DIR to the server's recording folder");
await zstd.isLoaded;
const decompressHandlers = {
  zstd: (data, size) => zstd.decompress(data, Number(size)),
  lz4: (data, size) => lz4(data, Number(size)),
};
const decoder = new TextDecoder();

function readable(bytes) {
  return {
    size: async () => BigInt(bytes.byteLength),
    read: async (offset, size) => bytes.subarray(Number(offset), Number(offset + size)),
  };
}

test("the session recording holds every published topic and every command, finalised", async () => {
  const files = readdirSync(dir).filter((f) => f.endsWith(".mcap")).sort();
  assert.ok(files.length >= 1, `no recording in ${dir}`);
  const counts = {};
  const nextSeq = {};
  const lastTime = {};
  const commands = [];
  const schemas = {};
  const protobufTypes = {};  // topic → the type decoded from the recorded FileDescriptorSet
  let protobufImages = 0;
  let protobufAnnotations = 0;
  const segmentation = [];
  for (const file of files) {
    const bytes = new Uint8Array(readFileSync(join(dir, file)));
    // Indexed reading needs the footer and summary: the file was finalised at SIGTERM.
    const reader = await McapIndexedReader.Initialize({ readable: readable(bytes), decompressHandlers });
    for await (const meta of reader.readMetadata({ name: "tendril.recorder" }))
      assert.equal(meta.metadata.get("dropped_total"), "0", `${file}: messages were dropped`);
    for (const [, channel] of reader.channelsById) {
      const schema = reader.schemasById.get(channel.schemaId);
      if (schema) schemas[channel.topic] = schema.name;
      if (channel.messageEncoding === "protobuf") {
        // The binary images: the schema is the FileDescriptorSet the live stream advertises.
        assert.equal(schema?.encoding, "protobuf", channel.topic);
        const set = descriptor.FileDescriptorSet.decode(schema.data);
        protobufTypes[channel.topic] = protobuf.Root.fromDescriptor(set).lookupType(schema.name);
      } else {
        assert.equal(channel.messageEncoding, "json", channel.topic);
      }
    }
    for await (const message of reader.readMessages({ validateCrcs: true })) {
      const topic = reader.channelsById.get(message.channelId).topic;
      assert.ok(message.logTime >= (lastTime[topic] ?? 0n), `${topic}: out of log-time order`);
      lastTime[topic] = message.logTime;
      assert.equal(message.sequence, nextSeq[topic] ?? 0, `${topic}: a message missing or repeated`);
      nextSeq[topic] = message.sequence + 1;
      counts[topic] = (counts[topic] ?? 0) + 1;
      if (protobufTypes[topic]) {
        const decoded = protobufTypes[topic].decode(message.data);
        if (schemas[topic] === "foxglove.ImageAnnotations") {
          // The overlay of a frame: at least the model backbone as a line strip, stamped.
          assert.ok(decoded.points.length >= 1 && decoded.points[0].timestamp, `${topic}: annotations`);
          ++protobufAnnotations;
          continue;
        }
        assert.deepEqual([...decoded.data.subarray(0, 2)], [0xff, 0xd8], `${topic}: a JPEG`);
        ++protobufImages;
        continue;
      }
      const body = JSON.parse(decoder.decode(message.data));  // every message is the JSON clients got
      if (topic === "/commands") commands.push(body);
      if (topic === "/imaging/segmentation") segmentation.push(body);
    }
  }
  console.log(`recorded: ${JSON.stringify(counts)} in ${files.length} file(s); ${protobufImages} protobuf images ` +
              `and ${protobufAnnotations} protobuf image annotations decoded`);
  for (const topic of ["/srmc/joint_states", "/srmc/operating_state", "/safety/events", "/commands"])
    assert.ok(counts[topic] > 0, `nothing recorded on ${topic}: ${JSON.stringify(counts)}`);
  assert.ok(counts["/srmc/joint_states"] >= 50, `only ${counts["/srmc/joint_states"]} joint states`);
  assert.equal(schemas["/commands"], "tendril.Command");
  assert.equal(schemas["/srmc/joint_states"], "tendril.JointState", "the channel's own JSON schema");

  // The segmentation's parameters, kept although no image was recorded: the start-up ones and the
  // change imaging.test.mjs made (lateral canny_high 110), once the plane applied it.
  assert.equal(schemas["/imaging/segmentation"], "tendril.SegmentationParameters");
  assert.ok(segmentation.length >= 2, `segmentation messages: ${segmentation.length}`);
  assert.ok(segmentation.some((m) => m.planes.lateral.parameters.canny_high === 110),
            "the applied segmentation change is in the recording");

  // The commands the suites sent: a move that was executed, commands refused with their reason, the
  // e-stop, each with the sender's label.
  const executedMove = commands.find((c) => c.command === "move_jp" && c.status === 202 && c.robot === "srmc");
  assert.ok(executedMove, "no executed move_jp recorded");
  assert.ok(Array.isArray(executedMove.body.goal), JSON.stringify(executedMove));
  assert.equal(executedMove.error, "");
  const refused = commands.filter((c) => c.status >= 400);
  assert.ok(refused.length > 0, "no refused command recorded");
  for (const c of refused) assert.match(c.error, /^[a-z_]+: ./, JSON.stringify(c));
  assert.ok(commands.some((c) => c.command === "estop" && c.robot === ""), "no e-stop recorded");
  assert.ok(commands.every((c) => typeof c.who === "string"), "a command without its sender");
});
