// Feeds the relay with the messages tendril published (recorded by bench.mjs): joint states at
// STATE_HZ and both image streams at FPS, each image re-stamped with the time it is sent (its
// "capture" time here), as {"topic":…,"message":<the tendril payload>}.
//   node feeder.mjs ws://127.0.0.1:PORT recorded.json STATE_HZ FPS
import fs from 'node:fs';
import {performance} from 'node:perf_hooks';
import WebSocket from 'ws';

const [url, file, stateHzArg, fpsArg] = process.argv.slice(2);
const recorded = JSON.parse(fs.readFileSync(file, 'utf8'));
const nowMs = () => performance.timeOrigin + performance.now();
const stampPattern = /"timestamp":\{"sec":\d+,"nsec":\d+\}/;

function restamp(payload) {
  const ns = BigInt(Math.round(nowMs() * 1e6));
  return payload.replace(stampPattern,
                         `"timestamp":{"sec":${ns / 1000000000n},"nsec":${ns % 1000000000n}}`);
}

const ws = new WebSocket(url);
ws.on('error', (e) => {
  console.error('feeder:', e.message);
  process.exit(1);
});
ws.on('open', () => {
  const streams = [
    {topic: '/srmc/joint_states', messages: recorded['/srmc/joint_states'], period: 1000 / Number(stateHzArg)},
    {topic: '/imaging/ap', messages: recorded['/imaging/ap'], period: 1000 / Number(fpsArg), image: true},
    {topic: '/imaging/lateral', messages: recorded['/imaging/lateral'], period: 1000 / Number(fpsArg), image: true},
  ];
  const start = performance.now();
  for (const s of streams) {
    let k = 0;
    const tick = () => {
      const raw = s.messages[k % s.messages.length];
      const message = s.image ? restamp(raw) : raw;
      ws.send(`{"topic":"${s.topic}","message":${message}}`);
      ++k;
      // Absolute schedule: the next message is due at start + k·period.
      setTimeout(tick, Math.max(0, start + k * s.period - performance.now()));
    };
    tick();
  }
  console.log('feeder running');
});
