// One benchmark client. Prints one JSON line with what it received during the measurement window.
//   node client.mjs foxglove ws://127.0.0.1:PORT/ws?token=T WARMUP_S DURATION_S
//   node client.mjs relay    ws://127.0.0.1:PORT             WARMUP_S DURATION_S
//   node client.mjs foxglove-protobuf …: as foxglove, with the images from /imaging/{view}/compressed
//   (protobuf foxglove.CompressedImage) instead of the JSON /imaging/{view}.
// foxglove: subscribes with @foxglove/ws-protocol to /srmc/joint_states, /imaging/ap, /imaging/lateral.
// relay: plain `ws`; every message is {"topic":…,"message":{…}} as the feeder sends it.
// Image latency = receive time − the capture timestamp inside the message (same machine, same clock).
import {performance} from 'node:perf_hooks';
import wsProtocol from '@foxglove/ws-protocol';
import WebSocket from 'ws';

const {FoxgloveClient} = wsProtocol;
const [mode, url, warmupArg, durationArg] = process.argv.slice(2);
const warmup = Number(warmupArg) * 1000;
const duration = Number(durationArg) * 1000;
const IMAGE_TOPICS = ['/imaging/ap', '/imaging/lateral'];
const STATE_TOPIC = '/srmc/joint_states';
const stampPattern = /"timestamp":\{"sec":(\d+),"nsec":(\d+)\}/;
const topicPattern = /"topic":"([^"]+)"/;

const nowMs = () => performance.timeOrigin + performance.now();
let measuring = false;
const counts = {};
const bytes = {value: 0};
const latencies = [];
const publishLatencies = [];
const decoder = new TextDecoder('latin1');

// logTimeMs: when the server had the message ready (Foxglove message header); for the relay, the
// feeder's send time, which is also its capture stamp.
function received(topic, prefix, size, logTimeMs) {
  if (!measuring) return;
  counts[topic] = (counts[topic] || 0) + 1;
  bytes.value += size;
  if (IMAGE_TOPICS.includes(topic)) {
    const now = nowMs();
    const m = stampPattern.exec(prefix);
    if (m) {
      const captured = Number(m[1]) * 1000 + Number(m[2]) / 1e6;
      latencies.push(now - captured);
      publishLatencies.push(now - (logTimeMs ?? captured));
    }
  }
}

function quantile(sorted, q) {
  if (sorted.length === 0) return null;
  return sorted[Math.min(sorted.length - 1, Math.floor(q * sorted.length))];
}

function finish(close) {
  measuring = false;
  latencies.sort((a, b) => a - b);
  publishLatencies.sort((a, b) => a - b);
  const seconds = duration / 1000;
  const rate = (t) => (counts[t] || 0) / seconds;
  console.log(JSON.stringify({
    pid: process.pid,
    ap_fps: rate('/imaging/ap'),
    lateral_fps: rate('/imaging/lateral'),
    state_hz: rate(STATE_TOPIC),
    latency_ms: {p50: quantile(latencies, 0.5), p95: quantile(latencies, 0.95), max: latencies.at(-1) ?? null,
                 n: latencies.length},
    publish_latency_ms: {p50: quantile(publishLatencies, 0.5), p95: quantile(publishLatencies, 0.95)},
    mbit_s: (bytes.value * 8) / 1e6 / seconds,
  }));
  close();
  setTimeout(() => process.exit(0), 200);
}

function schedule(close) {
  setTimeout(() => {
    measuring = true;
    setTimeout(() => finish(close), duration);
  }, warmup);
}

// The capture stamp of a protobuf foxglove.CompressedImage: field 1 (Timestamp) comes first, and
// inside it seconds (field 1) and nanos (field 2) as varints.
function protobufStamp(bytes) {
  if (bytes[0] !== 0x0a) return null;
  const end = 2 + bytes[1];
  let pos = 2;
  const out = {sec: 0, nsec: 0};
  while (pos < end) {
    const key = bytes[pos++];
    let value = 0;
    for (let scale = 1; pos < end; scale *= 128) {
      const b = bytes[pos++];
      value += (b & 0x7f) * scale;
      if (b < 0x80) break;
    }
    if (key === 0x08) out.sec = value;
    if (key === 0x10) out.nsec = value;
  }
  return out;
}

if (mode === 'foxglove' || mode === 'foxglove-protobuf') {
  const binaryImages = mode === 'foxglove-protobuf';
  const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
  const client = new FoxgloveClient({ws});
  const topicsBySubscription = new Map();
  client.on('advertise', (channels) => {
    for (const channel of channels) {
      const image = IMAGE_TOPICS.find((t) => channel.topic === (binaryImages ? `${t}/compressed` : t));
      if (channel.topic === STATE_TOPIC || image) topicsBySubscription.set(client.subscribe(channel.id), image ?? channel.topic);
    }
  });
  client.on('message', ({subscriptionId, timestamp, data}) => {
    const topic = topicsBySubscription.get(subscriptionId);
    if (!topic) return;
    const head = new Uint8Array(data.buffer, data.byteOffset, Math.min(96, data.byteLength));
    let prefix;
    if (binaryImages && topic !== STATE_TOPIC) {
      const t = protobufStamp(head);
      prefix = t ? `"timestamp":{"sec":${t.sec},"nsec":${t.nsec}}` : '';
    } else {
      prefix = decoder.decode(head);
    }
    received(topic, prefix, data.byteLength, Number(timestamp) / 1e6);
  });
  client.on('error', (e) => console.error('client error', e?.message ?? e));
  ws.on('open', () => schedule(() => client.close()));
} else if (mode === 'relay') {
  const ws = new WebSocket(url);
  ws.on('message', (data) => {
    const prefix = data.toString('latin1', 0, Math.min(140, data.length));
    const m = topicPattern.exec(prefix);
    if (m) received(m[1], prefix, data.length);
  });
  ws.on('open', () => schedule(() => ws.close()));
  ws.on('error', (e) => console.error('relay client error', e.message));
} else {
  console.error('usage: node client.mjs foxglove|relay URL WARMUP_S DURATION_S');
  process.exit(2);
}
