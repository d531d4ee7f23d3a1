// A small rosbridge v2 client for the operator page: reconnects by itself with backoff, re-sends its auth,
// advertisements and subscriptions on every new connection, and never queues streamed data while disconnected
// (a pose from a second ago is worth nothing; the server's watchdog holds the robot meanwhile).

const BACKOFF_FIRST_MS = 500;
const BACKOFF_MAX_MS = 8000;
const SEND_BUFFER_LIMIT = 1 << 20;  // bytes waiting in the socket: beyond this, streamed publishes are skipped

export class Rosbridge {
  /** url: ws:// or wss://; token: the access token (null when the server is open). */
  constructor(url, {token = null, idPrefix = "operator"} = {}) {
    this.url = url;
    this.token = token;
    this.idPrefix = idPrefix;
    this.handlers = new Map();        // topic -> [callback]
    this.subscriptions = new Map();   // topic -> subscribe frame
    this.advertised = new Map();      // topic -> type
    this.pending = new Map();         // call id -> {resolve, reject, timer}
    this.ids = 0;
    this.attempt = 0;
    this.connected = false;
    this.nextRetryAt = null;          // performance.now() of the next attempt while disconnected
    this.onopen = () => {};
    this.onclose = () => {};
    this.onstatus = () => {};
    this.stopped = false;
    this.connect();
  }

  connect() {
    if (this.stopped) return;
    let ws;
    try {
      ws = new WebSocket(this.url);
    } catch (err) {
      this.retry(String(err));
      return;
    }
    this.ws = ws;
    ws.onopen = () => {
      this.connected = true;
      this.attempt = 0;
      this.nextRetryAt = null;
      if (this.token) this.raw({op: "auth", mac: this.token});
      this.raw({op: "set_level", level: "warning"});  // clamps and refusals reach us as status warnings
      for (const [topic, type] of this.advertised) this.raw({op: "advertise", topic, type});
      for (const frame of this.subscriptions.values()) this.raw(frame);
      this.onopen();
    };
    ws.onclose = (event) => {
      if (this.ws !== ws) return;
      const was = this.connected;
      this.connected = false;
      for (const [id, waiter] of this.pending) {
        clearTimeout(waiter.timer);
        waiter.reject(new Error("the connection to the server dropped"));
        this.pending.delete(id);
      }
      this.retry(event.reason || (was ? "the connection dropped" : "the server cannot be reached"));
    };
    ws.onmessage = (event) => {
      let msg;
      try {
        msg = JSON.parse(event.data);
      } catch {
        return;  // not ours to crash on
      }
      this.receive(msg);
    };
  }

  retry(reason) {
    if (this.stopped) return;
    const delay = Math.min(BACKOFF_MAX_MS, BACKOFF_FIRST_MS * 2 ** this.attempt);
    this.attempt += 1;
    this.nextRetryAt = performance.now() + delay;
    this.onclose(reason, delay);
    setTimeout(() => this.connect(), delay);
  }

  close() {
    this.stopped = true;
    this.ws?.close();
  }

  raw(frame) {
    this.ws.send(JSON.stringify(frame));
  }

  receive(msg) {
    if (msg.op === "publish") {
      for (const cb of this.handlers.get(msg.topic) || []) {
        try {
          cb(msg.msg);
        } catch (err) {
          console.error(`handler of ${msg.topic} failed`, err);
        }
      }
    } else if (msg.op === "service_response") {
      const waiter = this.pending.get(msg.id);
      if (!waiter) return;
      this.pending.delete(msg.id);
      clearTimeout(waiter.timer);
      // a refusal is a successful call whose response says so (success/status false, message why)
      const refused = msg.result && msg.values && (msg.values.success === false || msg.values.status === false);
      if (refused) waiter.reject(Object.assign(new Error(String(msg.values.message || "refused")), {refused: true}));
      else if (msg.result) waiter.resolve(msg.values);
      else waiter.reject(new Error(typeof msg.values === "string" ? msg.values : JSON.stringify(msg.values)));
    } else if (msg.op === "status") {
      this.onstatus(msg);
    }
  }

  subscribe(topic, type, callback, options = {}) {
    if (!this.handlers.has(topic)) this.handlers.set(topic, []);
    this.handlers.get(topic).push(callback);
    const frame = {op: "subscribe", topic, type, ...options};
    this.subscriptions.set(topic, frame);
    if (this.connected) this.raw(frame);
  }

  advertise(topic, type) {
    if (this.advertised.get(topic) === type) return;
    this.advertised.set(topic, type);
    if (this.connected) this.raw({op: "advertise", topic, type});
  }

  /** Publishes now or never: false when disconnected or the socket is backed up. */
  publish(topic, msg) {
    if (!this.connected || this.ws.bufferedAmount > SEND_BUFFER_LIMIT) return false;
    this.raw({op: "publish", topic, msg});
    return true;
  }

  call(service, args = {}, timeoutMs = 10000) {
    if (!this.connected) return Promise.reject(new Error("not connected to the server"));
    const id = `${this.idPrefix}:${++this.ids}`;
    return new Promise((resolve, reject) => {
      const timer = setTimeout(() => {
        this.pending.delete(id);
        reject(new Error(`${service}: no answer in ${timeoutMs / 1000} s`));
      }, timeoutMs);
      this.pending.set(id, {resolve, reject, timer});
      this.raw({op: "call_service", id, service, args});
    });
  }
}

/** The server's header stamp ({secs, nsecs} or {sec, nanosec}) in seconds. */
export function stampSeconds(stamp) {
  if (!stamp) return null;
  const s = stamp.secs ?? stamp.sec;
  const ns = stamp.nsecs ?? stamp.nanosec ?? 0;
  return typeof s === "number" ? s + ns / 1e9 : null;
}

/** A header stamp for now, in the ROS 1 style the server accepts always. */
export function stampNow() {
  const ms = Date.now();
  return {secs: Math.floor(ms / 1000), nsecs: (ms % 1000) * 1e6};
}
