// The pages' rosbridge v2 client, one for the dashboard (dashboard.js) and the operator page (operator/*.js).
//
//   import {connect} from "/rosbridge.js";                 // or "../rosbridge.js" from /operator/
//   import * as names from "/names.js";                     // every topic and service name (generated)
//   const ros = connect(`wss://${location.host}/`, {token, idPrefix: "mypage"});
//   ros.subscribe(names.TELEOP_STATE_TOPIC, "vr_teleop_msgs/TeleopState", (msg) => ..., {queue_length: 1});
//   ros.advertise(topic, "std_msgs/String");                 // once; sent again on every new connection
//   ros.publish(topic, {data: "hi"});                        // true when sent, false when dropped (see below)
//   ros.callService(names.ENGAGE_SERVICE, {data: true})     // a promise of the response's values; `call` too
//     .then((values) => ..., (err) => err.refused ? say(err.message) : ...);
//   ros.onopen / ros.onclose(reason, retryInMs) / ros.onstatus(statusMessage)  // callbacks to set
//   ros.connected, ros.nextRetryAt, ros.close()
//
// One rule for connections: it connects by itself and reconnects with backoff (0.5 s doubling to 8 s), and on
// every new connection it sends first the token (auth) and set_level warning (clamps and refusals reach the page
// as status warnings), then its advertisements and subscriptions again. Nothing waits in a queue while it is
// disconnected: a publish is dropped (publish() says false; a pose from a second ago is worth nothing, and the
// server's watchdog holds the robot meanwhile), and so is a streamed publish while the socket is backed up; a
// call is refused at once (its promise rejects), so that nothing the user asked for runs later by surprise.
// Calls pending when the connection drops reject; a call unanswered in its timeout (10 s) rejects.
//
// The refusal rule, once: a call the server ran and refused comes back as a successful response whose values say
// success: false (or LuxAI's status: false) with message why; the promise rejects with an Error whose message is
// that reason and whose `refused` is true. A call rosbridge could not run (result false) rejects with refused false.

const BACKOFF_FIRST_MS = 500;
const BACKOFF_MAX_MS = 8000;
const CALL_TIMEOUT_MS = 10000;
const SEND_BUFFER_LIMIT = 1 << 20;  // bytes waiting in the socket: beyond this, streamed publishes are skipped

export class Rosbridge {
  /** url: ws:// or wss://; token: the access token (null when the server is open); idPrefix: of call ids. */
  constructor(url, {token = null, idPrefix = "page"} = {}) {
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
    this.open();
  }

  open() {
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
      this.raw({op: "set_level", level: "warning"});
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
    setTimeout(() => this.open(), delay);
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
      try {
        waiter.resolve(outcome(msg));
      } catch (err) {
        waiter.reject(err);
      }
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

  call(service, args = {}, timeoutMs = CALL_TIMEOUT_MS) {
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

  /** call, under roslibjs's name. */
  callService(service, args = {}, timeoutMs = CALL_TIMEOUT_MS) {
    return this.call(service, args, timeoutMs);
  }
}

/** A client connecting to `url` at once (see the top of this module). */
export function connect(url, options = {}) {
  return new Rosbridge(url, options);
}

/** A service_response frame's values, or the Error saying why the call did not do what was asked (the refusal
 * rule: a successful response that says success/status false is a refusal, its message the reason). */
export function outcome(msg) {
  const values = msg.values;
  if (msg.result && values && (values.success === false || values.status === false)) {
    throw Object.assign(new Error(String(values.message || "refused")), {refused: true, values});
  }
  if (!msg.result) {
    throw Object.assign(new Error(typeof values === "string" ? values : JSON.stringify(values)),
                        {refused: false, values});
  }
  return values;
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
