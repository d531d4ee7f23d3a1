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

export const POSES_LABEL = "poses";
const HEAD = "/vr/head/pose";
export const BUFFER_BUDGET = 700;   // bytes: about two poses (330 bytes each): the head and one other per event

export class PoseChannel {
  constructor() {
    this.channel = null;
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
    this.pending.clear();
  }

  get open() {
    return this.channel?.readyState === "open";
  }

  /** Takes a publish (true) while the channel is open; false: send it over rosbridge instead. */
  send(topic, msg) {
    if (!this.open) return false;
    if (this.pending.has(topic)) this.replaced += 1;
    this.pending.set(topic, JSON.stringify({op: "publish", topic, msg}));
    this.pump();
    return true;
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
    }
  }

  stats() {
    return {open: this.open, sent: this.sent, replaced: this.replaced};
  }
}
