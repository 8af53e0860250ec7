// Live data discipline of the console (issue 12, "stale data labelled live"):
// - LatestByTopic keeps only the newest message of each topic, undecoded, with its server time stamp;
//   the page decodes and renders it once per animation frame, so a slow page drops old messages instead
//   of working through a backlog and showing the past as the present.
// - ServerClock compares the browser's clock with the server's (NTP-style, from a REST time stamp), so
//   that the age of a message is "browser now - server stamp" even when the two clocks differ.
// - Backoff schedules REST requests while the server does not answer: one probe at a time, waiting
//   0.5, 1, 2, 4, 5, 5 … s, instead of every poller retrying at its own rate.
// - STALE_MS: data older than this is marked STALE and the page offers no command but the stops.
//   250 ms: five stream periods at 50 Hz and above a human reaction time, so a display that is STALE
//   is one an operator could act on wrongly; the issue names the same bound.

export const STALE_MS = 250;

const decoder = new TextDecoder();

// Wall-clock milliseconds with sub-millisecond resolution (performance.now is monotonic; timeOrigin
// anchors it to the epoch).
export const wallNowMs = () => performance.timeOrigin + performance.now();

export class LatestByTopic {
  constructor() {
    this.slots = new Map();  // topic -> {bytes, stampMs, receivedMs, dropped, seq}
    this.received = 0;
    this.dropped = 0;        // messages replaced before the page decoded them
  }

  put(topic, bytes, stampNs) {
    const slot = this.slots.get(topic) || {seq: 0, dropped: 0, taken: 0};
    if (slot.bytes) {
      slot.dropped++;
      this.dropped++;
    }
    // The frame's bytes are copied out of the socket's buffer (small for everything but images).
    slot.bytes = bytes;
    slot.stampMs = Number(stampNs / 1000000n) + Number(stampNs % 1000000n) / 1e6;
    slot.receivedMs = wallNowMs();
    slot.seq++;
    this.received++;
    this.slots.set(topic, slot);
  }

  // The newest undecoded message of `topic` as {msg, stampMs, receivedMs}, or null when nothing new
  // arrived since the last take. A message that does not parse is dropped. `decode` turns the bytes
  // into the message: JSON by default; a binary (protobuf) topic passes its own decoder, which
  // returns null for bytes it cannot read.
  take(topic, decode = (bytes) => JSON.parse(decoder.decode(bytes))) {
    const slot = this.slots.get(topic);
    if (!slot || !slot.bytes) return null;
    const {bytes, stampMs, receivedMs} = slot;
    slot.bytes = null;
    slot.taken++;
    try {
      const msg = decode(bytes);
      return msg ? {msg, stampMs, receivedMs} : null;
    } catch {
      return null;
    }
  }

  pending(topic) { return !!this.slots.get(topic)?.bytes; }

  // Server stamp of the newest message of `topic` received (decoded or not), NaN before the first.
  stampOf(topic) { return this.slots.get(topic)?.stampMs ?? NaN; }

  clear() { this.slots.clear(); }
}

// Offset of the server's wall clock from the browser's (server - browser, ms), measured from a REST
// answer that carries the server's time: offset = stamp - (t0 + t1) / 2, error at most half the round
// trip. The best of a few samples (the shortest round trip) is kept.
export class ServerClock {
  constructor() {
    this.offsetMs = 0;
    this.errorMs = NaN;   // NaN: not compared yet (offset 0 assumed)
    this.measuredAt = 0;
  }

  get known() { return Number.isFinite(this.errorMs); }

  // fetchStamp(): resolves to the server's time in seconds (a measured_js timestamp).
  async measure(fetchStamp, samples = 3) {
    let best = null;
    for (let i = 0; i < samples; ++i) {
      const t0 = wallNowMs();
      const stampS = Number(await fetchStamp());
      const t1 = wallNowMs();
      if (!Number.isFinite(stampS)) continue;
      const rtt = t1 - t0;
      if (!best || rtt < best.rtt) best = {rtt, offset: stampS * 1000 - (t0 + t1) / 2};
    }
    if (!best) return false;
    // Within the measurement's own error the clocks agree: keep 0 rather than noise.
    this.offsetMs = Math.abs(best.offset) <= best.rtt / 2 ? 0 : best.offset;
    this.errorMs = best.rtt / 2;
    this.measuredAt = wallNowMs();
    return true;
  }

  // Age in ms of a server time stamp (ms since the epoch, server clock).
  ageMs(serverStampMs, now = wallNowMs()) {
    return Number.isFinite(serverStampMs) ? now - (serverStampMs - this.offsetMs) : Infinity;
  }
}

// "12 ms", "1.3 s", "4 min"
export function formatAge(ms) {
  if (!Number.isFinite(ms)) return '—';
  const a = Math.max(0, ms);
  if (a < 1000) return `${a.toFixed(0)} ms`;
  if (a < 60000) return `${(a / 1000).toFixed(1)} s`;
  return `${(a / 60000).toFixed(0)} min`;
}

// Exponential backoff while the server does not answer. `reachable` is what pollers look at: while
// false they do not send; `probe` (one request at a time) decides when the server is back.
export class Backoff {
  constructor({probe, firstMs = 500, capMs = 5000, onChange = () => {}}) {
    this.probe = probe;
    this.firstMs = firstMs;
    this.capMs = capMs;
    this.onChange = onChange;
    this.reachable = true;
    this.delayMs = firstMs;
    this.timer = null;
    this.failures = 0;
  }

  // A request failed at the network level (no HTTP answer): stop polling, probe with backoff.
  failed() {
    this.failures++;
    if (!this.reachable) return;
    this.reachable = false;
    this.delayMs = this.firstMs;
    this.onChange(false);
    this.schedule();
  }

  // Something answered (a REST reply or the stream): polling may resume.
  answered() {
    if (this.reachable) return;
    clearTimeout(this.timer);
    this.timer = null;
    this.reachable = true;
    this.delayMs = this.firstMs;
    this.onChange(true);
  }

  schedule() {
    clearTimeout(this.timer);
    this.timer = setTimeout(async () => {
      this.timer = null;
      if (this.reachable) return;
      let ok = false;
      try {
        ok = await this.probe();
      } catch {
        ok = false;
      }
      if (ok) this.answered();
      else {
        this.delayMs = Math.min(this.delayMs * 2, this.capMs);
        this.schedule();
      }
    }, this.delayMs);
  }
}
