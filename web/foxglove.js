// Minimal browser client of the Foxglove WebSocket protocol v1 (foxglove/ws-protocol docs/spec.md):
// serverInfo, advertise/unadvertise, subscribe, binary message data (opcode 0x01: uint32 LE
// subscription id, uint64 LE timestamp ns, payload). tendril's payloads are JSON (UTF-8). The npm
// client needs a bundler, which the console deliberately avoids, so this covers what the console uses.

export const SUBPROTOCOL = 'foxglove.websocket.v1';
const OP_MESSAGE_DATA = 0x01;

export class FoxgloveConnection {
  // topics: the topics to subscribe to as soon as the server advertises them.
  // handlers: {onOpen, onClose(reason), onServerInfo(info), onMessage(topic, json, timestampNs), onStatus(msg),
  //            onChannels(advertisedTopics: Set), onRaw(topic, bytes, timestampNs) (instead of onMessage)}
  constructor(url, topics, handlers) {
    this.url = url;
    this.wanted = new Set(topics);
    this.handlers = handlers;
    this.channelsById = new Map();
    this.subscriptionTopic = new Map();  // subscription id -> topic
    this.subscribedChannels = new Map();  // channel id -> subscription id
    this.nextSubscriptionId = 1;
    this.decoder = new TextDecoder();
    this.ws = null;
    this.closedByUser = false;
    this.retryMs = 500;
    this.retryTimer = null;
  }

  open() {
    this.closedByUser = false;
    let ws;
    try {
      ws = new WebSocket(this.url, [SUBPROTOCOL]);
    } catch (err) {
      this.scheduleReconnect(`cannot open WebSocket: ${err.message}`);
      return;
    }
    ws.binaryType = 'arraybuffer';
    this.ws = ws;
    ws.onopen = () => {
      this.retryMs = 500;
      this.handlers.onOpen?.();
    };
    ws.onmessage = (ev) => this.handleFrame(ev.data);
    ws.onclose = (ev) => {
      if (this.ws !== ws) return;  // an older socket closed after a newer one opened
      this.channelsById.clear();
      this.handlers.onChannels?.(this.advertisedTopics());
      this.subscriptionTopic.clear();
      this.subscribedChannels.clear();
      this.ws = null;
      const reason = ev.reason || (ev.code === 1000 ? 'closed' : `closed (code ${ev.code})`);
      this.handlers.onClose?.(reason);
      if (!this.closedByUser) this.scheduleReconnect(reason);
    };
    ws.onerror = () => {
      // onclose follows with the details; nothing else to do here.
    };
  }

  close() {
    this.closedByUser = true;
    clearTimeout(this.retryTimer);
    this.ws?.close(1000, 'console closed');
  }

  scheduleReconnect() {
    clearTimeout(this.retryTimer);
    this.retryTimer = setTimeout(() => this.open(), this.retryMs);
    this.retryMs = Math.min(this.retryMs * 2, 5000);
  }

  send(obj) {
    if (this.ws && this.ws.readyState === WebSocket.OPEN) this.ws.send(JSON.stringify(obj));
  }

  handleFrame(data) {
    if (typeof data === 'string') {
      let msg;
      try {
        msg = JSON.parse(data);
      } catch {
        return;
      }
      this.handleJson(msg);
      return;
    }
    const view = new DataView(data);
    if (view.byteLength < 13 || view.getUint8(0) !== OP_MESSAGE_DATA) return;
    const subscriptionId = view.getUint32(1, true);
    const timestampNs = view.getBigUint64(5, true);
    const topic = this.subscriptionTopic.get(subscriptionId);
    if (!topic) return;
    // onRaw: the payload undecoded, so that a client keeping only the newest message per topic
    // parses only what it shows (a dropped image is never decoded).
    if (this.handlers.onRaw) {
      this.handlers.onRaw(topic, new Uint8Array(data, 13), timestampNs);
      return;
    }
    let payload;
    try {
      payload = JSON.parse(this.decoder.decode(new Uint8Array(data, 13)));
    } catch {
      return;
    }
    this.handlers.onMessage?.(topic, payload, timestampNs);
  }

  handleJson(msg) {
    switch (msg.op) {
      case 'serverInfo':
        this.handlers.onServerInfo?.(msg);
        break;
      case 'advertise': {
        const subscriptions = [];
        for (const channel of msg.channels || []) {
          this.channelsById.set(channel.id, channel);
          if (this.wanted.has(channel.topic) && !this.subscribedChannels.has(channel.id)) {
            const id = this.nextSubscriptionId++;
            this.subscriptionTopic.set(id, channel.topic);
            this.subscribedChannels.set(channel.id, id);
            subscriptions.push({id, channelId: channel.id});
          }
        }
        if (subscriptions.length) this.send({op: 'subscribe', subscriptions});
        this.handlers.onChannels?.(this.advertisedTopics());
        break;
      }
      case 'unadvertise':
        for (const channelId of msg.channelIds || []) {
          const subscriptionId = this.subscribedChannels.get(channelId);
          if (subscriptionId !== undefined) this.subscriptionTopic.delete(subscriptionId);
          this.subscribedChannels.delete(channelId);
          this.channelsById.delete(channelId);
        }
        this.handlers.onChannels?.(this.advertisedTopics());
        break;
      case 'status':
        this.handlers.onStatus?.(msg);
        break;
      default:
        break;
    }
  }

  subscribedTopics() { return [...this.subscriptionTopic.values()]; }

  // Subscribes one more topic: at once when it is advertised, else when it is (and after a reconnect).
  addTopic(topic) {
    this.wanted.add(topic);
    const channel = [...this.channelsById.values()].find((c) => c.topic === topic);
    if (!channel || this.subscribedChannels.has(channel.id)) return;
    const id = this.nextSubscriptionId++;
    this.subscriptionTopic.set(id, topic);
    this.subscribedChannels.set(channel.id, id);
    this.send({op: 'subscribe', subscriptions: [{id, channelId: channel.id}]});
  }

  // Unsubscribes a topic (the server stops producing what only this client wanted, e.g. the tracking).
  removeTopic(topic) {
    this.wanted.delete(topic);
    for (const [channelId, id] of this.subscribedChannels) {
      if (this.subscriptionTopic.get(id) !== topic) continue;
      this.subscribedChannels.delete(channelId);
      this.subscriptionTopic.delete(id);
      this.send({op: 'unsubscribe', subscriptionIds: [id]});
    }
  }

  // Topics the server currently advertises (empty while disconnected).
  advertisedTopics() { return new Set([...this.channelsById.values()].map((c) => c.topic)); }

  // Drops the socket as a network failure would (no clean close handshake is awaited); the client
  // reconnects on its own. The browser tests use it to simulate a lost socket.
  drop() {
    this.ws?.close(4000, 'dropped by the console');
  }
}
