// The recordings tendril writes (record/, through tendril-record-selftest), read by an independent
// reader: @mcap/core, Foxglove's TypeScript MCAP library, with Foxglove's zstd and lz4 decompressors.
// For each chunk compression: the indexed reader (summary, chunk indexes, message indexes) and the
// streaming reader (every record from the start, chunk CRCs checked) both find exactly the messages
// sent, per channel, in log-time order, byte for byte. And a recording cut by SIGKILL is read by the
// streaming reader up to its last complete chunk.
//
// Run: TENDRIL_RECORD_SELFTEST=build/tests/record/tendril-record-selftest node --test tests/record/
import { test } from "node:test";
import assert from "node:assert/strict";
import { spawn, spawnSync } from "node:child_process";
import { mkdtempSync, readFileSync, rmSync, readdirSync } from "node:fs";
import { tmpdir } from "node:os";
import { join } from "node:path";
import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import zstd from "@foxglove/wasm-zstd";
import lz4 from "@foxglove/wasm-lz4";

const selftest = process.env.TENDRIL_RECORD_SELFTEST;
if (!selftest) throw new Error("set TENDRIL_RECORD_SELFTEST to the tendril-record-selftest binary");

await zstd.isLoaded;
await lz4.isLoaded;
const decompressHandlers = {
  zstd: (data, size) => zstd.decompress(data, Number(size)),
  lz4: (data, size) => lz4(data, Number(size)),
};

const T0 = 1_700_000_000_000_000_000n;
const IMAGE_BYTES = 150_000;

// What the selftest sends as message `seq` on each topic (tests/record/record_selftest.cpp).
function expectedImage(seq) {
  const v = new Uint8Array(IMAGE_BYTES);
  v[0] = 0xff;
  v[1] = 0xd8;
  for (let i = 0; i < 4; i++) v[2 + i] = (seq >>> (8 * i)) & 0xff;
  let x = (Math.imul(seq, 2654435761) + 1) >>> 0;
  for (let k = 6; k + 2 < v.length; k++) {
    x = (Math.imul(x, 1664525) + 1013904223) >>> 0;
    v[k] = x >>> 24;
  }
  v[v.length - 2] = 0xff;
  v[v.length - 1] = 0xd9;
  return v;
}
const decoder = new TextDecoder();
// Checks one message against what was sent with its sequence number and returns its topic.
function checkMessage(channelsById, message) {
  const channel = channelsById.get(message.channelId);
  assert.ok(channel, `message on unknown channel ${message.channelId}`);
  const seq = message.sequence;
  if (channel.topic === "/imaging/ap") {
    assert.equal(message.data.byteLength, IMAGE_BYTES);
    assert.ok(Buffer.from(message.data).equals(Buffer.from(expectedImage(seq))), `image ${seq} differs`);
    assert.equal(message.logTime, T0 + BigInt(seq * 33) * 1_000_000n);
  } else {
    const body = JSON.parse(decoder.decode(message.data));
    assert.equal(body.seq, seq);
    const step = channel.topic === "/robot/events" ? 100 : 1;
    assert.equal(message.logTime, T0 + BigInt(seq * step) * 1_000_000n);
  }
  assert.equal(message.publishTime, message.logTime);
  return channel.topic;
}

function runSelftest(args) {
  const dir = mkdtempSync(join(tmpdir(), "tendril-mcap-"));
  const run = spawnSync(selftest, ["--out", dir, ...args], { encoding: "utf8" });
  assert.equal(run.status, 0, `selftest failed: ${run.stderr}`);
  return { dir, result: JSON.parse(run.stdout.trim().split("\n").pop()) };
}

function readable(bytes) {
  return {
    size: async () => BigInt(bytes.byteLength),
    read: async (offset, size) => bytes.subarray(Number(offset), Number(offset + size)),
  };
}

// Reads a whole file with the streaming reader; returns its records by type.
function streamRecords(bytes) {
  const reader = new McapStreamReader({ includeChunks: true, decompressHandlers, validateCrcs: true });
  reader.append(bytes);
  const records = [];
  for (let r; (r = reader.nextRecord()); ) records.push(r);
  return { records, done: reader.done() };
}

for (const compression of ["zstd", "lz4", "none"]) {
  test(`${compression}: @mcap/core reads every message sent, in log-time order`, async () => {
    // 2 s of log time; 1 MB files, so the recording is rotated and every file is read on its own.
    const { dir, result } = runSelftest(["--compression", compression, "--seconds", "2", "--max-file-bytes", "1000000"]);
    try {
      assert.equal(result.dropped, 0);
      assert.deepEqual(result.sent, { "/imaging/ap": 61, "/robot/events": 20, "/robot/joint_states": 2000 });
      assert.ok(result.files.length >= 3, `expected rotation into several files, got ${result.files.length}`);
      assert.deepEqual(readdirSync(dir).sort(), result.files.map((f) => f.split("/").pop()).sort());

      const counts = {};
      const nextSeq = {};
      let lastTime = -1n;
      const compressions = new Set();
      for (const path of result.files) {
        const bytes = new Uint8Array(readFileSync(path));
        // Indexed: footer, summary, chunk and message indexes.
        const indexed = await McapIndexedReader.Initialize({ readable: readable(bytes), decompressHandlers });
        assert.equal(indexed.header.library, "tendril-record");
        const fileCounts = {};
        let fileLast = -1n;
        for await (const message of indexed.readMessages({ validateCrcs: true })) {
          const topic = checkMessage(indexed.channelsById, message);
          assert.ok(message.logTime >= fileLast, "indexed reader out of log-time order");
          fileLast = message.logTime;
          assert.ok(message.logTime >= lastTime, "files out of log-time order");
          lastTime = message.logTime;
          assert.equal(message.sequence, nextSeq[topic] ?? 0, `${topic}: a message missing or repeated`);
          nextSeq[topic] = message.sequence + 1;
          counts[topic] = (counts[topic] ?? 0) + 1;
          fileCounts[topic] = (fileCounts[topic] ?? 0) + 1;
        }
        // The Statistics record agrees with what was read.
        const stats = indexed.statistics;
        for (const [id, n] of stats.channelMessageCounts) {
          assert.equal(Number(n), fileCounts[indexed.channelsById.get(id).topic] ?? 0);
        }
        assert.equal(Number(stats.chunkCount), indexed.chunkIndexes.length);
        for (const ci of indexed.chunkIndexes) compressions.add(ci.compression);

        // Streaming: every record from the start, chunk CRCs validated, up to the footer.
        const { records, done } = streamRecords(bytes);
        assert.ok(done, "the streaming reader did not reach the footer");
        const streamed = records.filter((r) => r.type === "Message").length;
        assert.equal(streamed, Object.values(fileCounts).reduce((a, b) => a + b, 0));
        assert.equal(records.filter((r) => r.type === "DataEnd").length, 1);
        const meta = records.find((r) => r.type === "Metadata" && r.name === "tendril.recorder");
        assert.equal(meta.metadata.get("dropped_total"), "0");
      }
      assert.deepEqual(counts, result.sent);
      // With a compressor, chunks are compressed (a chunk that would not shrink is stored plain).
      if (compression === "none") assert.deepEqual([...compressions], [""]);
      else assert.ok(compressions.has(compression), `no ${compression} chunk among ${[...compressions]}`);
    } finally {
      rmSync(dir, { recursive: true, force: true });
    }
  });
}

test("a recording cut by SIGKILL reads up to its last complete chunk", async () => {
  const dir = mkdtempSync(join(tmpdir(), "tendril-mcap-kill-"));
  try {
    const child = spawn(selftest, ["--out", dir, "--until-killed", "--compression", "zstd"], {
      stdio: ["ignore", "pipe", "inherit"],
    });
    // Wait until several chunks are on disk, then kill without warning.
    let flushed = 0;
    let written = 0;
    await new Promise((resolve, reject) => {
      let buffered = "";
      child.on("exit", (code) => reject(new Error(`selftest exited (${code}) before it was killed`)));
      child.stdout.on("data", (data) => {
        buffered += data;
        const lines = buffered.split("\n");
        buffered = lines.pop();
        for (const line of lines) {
          const m = /^flushed (\d+) written (\d+)$/.exec(line);
          if (!m) continue;
          flushed = Number(m[1]);
          written = Number(m[2]);
          if (flushed >= 1500) {
            child.removeAllListeners("exit");
            child.stdout.removeAllListeners("data");
            child.on("exit", (code, signal) => resolve(signal));
            child.kill("SIGKILL");
            return;
          }
        }
      });
    }).then((signal) => assert.equal(signal, "SIGKILL"));

    const files = readdirSync(dir);
    assert.equal(files.length, 1);
    const bytes = new Uint8Array(readFileSync(join(dir, files[0])));
    const { records, done } = streamRecords(bytes);
    assert.equal(done, false, "a killed recording has no footer");
    assert.equal(records.some((r) => r.type === "Footer" || r.type === "DataEnd"), false);
    const channelsById = new Map(records.filter((r) => r.type === "Channel").map((c) => [c.id, c]));
    const messages = records.filter((r) => r.type === "Message");
    // Everything reported flushed before the kill is there (the writer went on until the kill came,
    // so more may be).
    assert.ok(messages.length >= flushed, `${messages.length} messages read, ${flushed} were flushed`);
    assert.ok(written >= flushed);
    // What is there is exactly the first messages of each channel, intact: whole chunks only.
    const nextSeq = {};
    for (const message of messages) {
      const topic = checkMessage(channelsById, message);
      assert.equal(message.sequence, nextSeq[topic] ?? 0);
      nextSeq[topic] = message.sequence + 1;
    }
    assert.ok(nextSeq["/imaging/ap"] > 0 && nextSeq["/robot/joint_states"] > 0 && nextSeq["/robot/events"] > 0);
    const chunks = records.filter((r) => r.type === "Chunk");
    assert.ok(chunks.length >= 3, `${chunks.length} chunks`);
    assert.equal(new Set(chunks.map((c) => c.compression)).has("zstd"), true);
  } finally {
    rmSync(dir, { recursive: true, force: true });
  }
});
