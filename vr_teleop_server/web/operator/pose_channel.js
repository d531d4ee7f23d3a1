// The operator's poses and Joy over a WebRTC data channel (issue 21): "poses", unordered, no retransmissions, on
// the camera's peer connection (created there before its offer: CameraFeed's prepare hook). Over a lossy network
// a lost pose is gone instead of holding up every pose behind it, as a lost TCP segment does to the WebSocket.
// The frames are the rosbridge publish frames the page would send over the WebSocket. The server takes them on
// the channel only from the operator who holds control (main.js sends over rosbridge otherwise, and whenever the
// channel is not open: no WebRTC, #camera=jpeg, a failed negotiation).
//
// Never a backlog at the sender: each topic keeps only its newest frame until the channel has buffered no more
// than about two poses (bufferedAmount at most bufferedAmountLowThreshold, BUFFER_BUDGET bytes), so a congested
// channel sends fewer, fresher poses. Not 0 as the tests' aiortc sender: the browser's SCTP takes messages on its
// network thread and says so in bufferedamountlow events a task later each, and with 0 the page sent about one
// pose per event on loopback; more than two poses per event would let the head, one pose per frame, take a
// smaller share when the channel is congested. The head pose (what the server's watchdog times and the camera
// follows) may take every other send; the other topics share the rest, the one waiting longest first.
//
// A stalled channel is not a stalled operator: when the channel has taken no head pose for STALL_MS (its
// congestion window full, waiting out a retransmission timer of a second or more), head poses go over rosbridge
// (send() answers false) until the channel takes one again. The server merges both roads by stamp (older than
// the newest taken: dropped), so the watchdog holds only when both roads are stalled.

export const POSES_LABEL = "poses";
const HEAD = "/vr/head/pose";
export const BUFFER_BUDGET = 700;   // bytes: about two poses (265 bytes each rounded, 313 not)
export const STALL_MS = 100;        // no head pose taken by the channel for this long: the head goes over rosbridge
const SCALE = 1e5;                  // floats to 5 places (10 micrometres; a thousandth of a degree in a quaternion)

// JSON.stringify's replacer: a pose in about 85% of the bytes of full doubles; the congestion window counts bytes.
function rounded(_key, value) {
  return typeof value === "number" && !Number.isInteger(value) ? Math.round(value * SCALE) / SCALE : value;
}

export class PoseChannel {
  constructor({now = () => performance.now()} = {}) {
    this.now = now;
    this.channel = null;
    this.headTakenAt = null;   // when the channel last took a head pose (null: none on this channel yet)
    this.failovers = 0;        // head poses sent over rosbridge because the channel was stalled
    this.pending = new Map();  // topic -> frame (text); a Map keeps a key's place when its value is replaced
    this.headLast = false;
    this.sent = 0;             // frames handed to the channel
    this.replaced = 0;         // frames overtaken by a newer one of their topic before the channel took them
  }

  /** CameraFeed's prepare(pc): called on every new peer connection, before its offer. */
  attach(pc) {
    const channel = pc.createDataChannel(POSES_LABEL, {ordered: false, maxRetransmits: 0});
    channel.bufferedAmountLowThreshold = BUFFER_BUDGET;
    channel.addEventListener("bufferedamountlow", () => this.pump());
    channel.addEventListener("close", () => {
      if (this.channel !== channel) return;
      this.channel = null;
      this.pending.clear();
    });
    this.channel = channel;
    this.headTakenAt = null;
    this.pending.clear();
  }

  get open() {
    return this.channel?.readyState === "open";
  }

  /** Takes a publish (true) while the channel is open; false: send it over rosbridge instead. */
  send(topic, msg) {
    if (!this.open) return false;
    if (topic === HEAD && this.stalled()) {  // this head pose over rosbridge, and the one waiting is dropped
      this.pending.delete(HEAD);
      this.failovers += 1;
      return false;
    }
    if (this.pending.has(topic)) this.replaced += 1;
    this.pending.set(topic, JSON.stringify({op: "publish", topic, msg}, rounded));
    this.pump();
    return true;
  }

  /** The channel has taken no head pose for STALL_MS and still has more buffered than it takes. */
  stalled() {
    const now = this.now();
    this.headTakenAt ??= now;
    const channel = this.channel;
    return now - this.headTakenAt > STALL_MS && channel.bufferedAmount > channel.bufferedAmountLowThreshold;
  }

  pump() {
    const channel = this.channel;
    while (this.pending.size && this.open && channel.bufferedAmount <= channel.bufferedAmountLowThreshold) {
      let topic = this.pending.has(HEAD) && !this.headLast ? HEAD : null;
      if (topic === null) {
        for (const t of this.pending.keys()) {
          if (t !== HEAD) { topic = t; break; }
        }
        topic ??= HEAD;
      }
      this.headLast = topic === HEAD;
      const frame = this.pending.get(topic);
      this.pending.delete(topic);
      try {
        channel.send(frame);
      } catch {
        return;  // closing: the next frames go over rosbridge
      }
      this.sent += 1;
      if (topic === HEAD) this.headTakenAt = this.now();
    }
  }

  stats() {
    return {open: this.open, sent: this.sent, replaced: this.replaced, failovers: this.failovers};
  }
}
