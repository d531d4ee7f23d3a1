// The operator's poses and Joy over a WebRTC data channel (issue 21): "poses", unordered, no retransmissions, on
// the camera's peer connection (created there before its offer: CameraFeed's prepare hook). Over a lossy network
// a lost pose is gone instead of holding up every pose behind it, as a lost TCP segment does to the WebSocket.
// The server takes poses on the channel only from the operator who holds control (main.js sends over rosbridge
// otherwise, and whenever the channel is not open: no WebRTC, #camera=jpeg, a failed negotiation).
//
// One binary message per XR frame (issue 30): send() collects the frame's head, controller poses and Joy, and
// flush() at the end of the frame packs them into one pose frame (client_protocol/pose_frame.py, version 1,
// little-endian: encodePoseFrame below), about 130 bytes for everything instead of five JSON frames of about 265
// each: one SCTP chunk per frame, and the congestion window counts both chunks and bytes.
//
// Never a backlog at the sender: what the channel has not taken stays pending, each topic keeping only its newest
// message, until the channel has buffered no more than about two frames (bufferedAmount at most
// bufferedAmountLowThreshold, BUFFER_BUDGET bytes); the next flush (the next frame, or the channel's
// bufferedamountlow event) sends all of it in one message. A congested channel sends fewer, fresher frames.
//
// A stalled channel is not a stalled operator: when the channel has taken no head pose for STALL_MS (its
// congestion window full, waiting out a retransmission timer of a second or more), head poses go over rosbridge
// (send() answers false) until the channel takes one again. The server merges both roads by stamp (older than
// the newest taken: dropped), so the watchdog holds only when both roads are stalled.

import * as names from "../names.js";
import {stampSeconds} from "../rosbridge.js";

export const POSES_LABEL = "poses";
const HEAD = names.HEAD_POSE_TOPIC;
export const POSE_TOPICS = [HEAD, names.CONTROLLER_POSE_TOPICS.left, names.CONTROLLER_POSE_TOPICS.right];
export const JOY_TOPICS = [names.JOY_TOPICS.left, names.JOY_TOPICS.right];
export const BUFFER_BUDGET = 260;   // bytes: about two full frames (130 bytes each)
export const STALL_MS = 100;        // no head pose taken by the channel for this long: the head goes over rosbridge

const VERSION = 1;
const HEADER_BYTES = 12;            // "VP", version, flags, float64 stamp
const POSE_BYTES = 28;              // float32 x, y, z, qx, qy, qz, qw
const JOY_BYTES = 17;               // float32 4 axes, uint8 buttons
const JOY_BUTTONS = 4;

/** One pose frame (ArrayBuffer) from {topic: message}: PoseStamped in ROS axes (flag bit 5 clear) and Joy. The
 * stamp is the head pose's, else the newest message's, in seconds since 1970. */
export function encodePoseFrame(msgs) {
  const poses = POSE_TOPICS.filter((t) => msgs.has(t));
  const joys = JOY_TOPICS.filter((t) => msgs.has(t));
  const view = new DataView(new ArrayBuffer(HEADER_BYTES + POSE_BYTES * poses.length + JOY_BYTES * joys.length));
  let flags = 0;
  POSE_TOPICS.forEach((t, i) => { if (msgs.has(t)) flags |= 1 << i; });
  JOY_TOPICS.forEach((t, i) => { if (msgs.has(t)) flags |= 1 << (3 + i); });
  const stamps = [...msgs.values()].map((m) => stampSeconds(m.header?.stamp) ?? 0);
  const stamp = msgs.has(HEAD) ? stampSeconds(msgs.get(HEAD).header?.stamp) ?? 0 : Math.max(...stamps);
  view.setUint8(0, 0x56);  // "V"
  view.setUint8(1, 0x50);  // "P"
  view.setUint8(2, VERSION);
  view.setUint8(3, flags);
  view.setFloat64(4, stamp, true);
  let offset = HEADER_BYTES;
  for (const t of poses) {
    const {position: p, orientation: q} = msgs.get(t).pose;
    for (const v of [p.x, p.y, p.z, q.x, q.y, q.z, q.w]) {
      view.setFloat32(offset, v, true);
      offset += 4;
    }
  }
  for (const t of joys) {
    const {axes, buttons} = msgs.get(t);
    for (let i = 0; i < 4; i += 1) {
      view.setFloat32(offset, axes[i] ?? 0, true);
      offset += 4;
    }
    let bits = 0;
    for (let b = 0; b < JOY_BUTTONS; b += 1) if (buttons[b]) bits |= 1 << b;
    view.setUint8(offset, bits);
    offset += 1;
  }
  return view.buffer;
}

export class PoseChannel {
  constructor({now = () => performance.now()} = {}) {
    this.now = now;
    this.channel = null;
    this.headTakenAt = null;   // when the channel last took a head pose (null: none on this channel yet)
    this.failovers = 0;        // head poses sent over rosbridge because the channel was stalled
    this.pending = new Map();  // topic -> newest message not yet taken
    this.sent = 0;             // pose frames handed to the channel
    this.replaced = 0;         // messages overtaken by a newer one of their topic before the channel took them
  }

  /** CameraFeed's prepare(pc): called on every new peer connection, before its offer. */
  attach(pc) {
    const channel = pc.createDataChannel(POSES_LABEL, {ordered: false, maxRetransmits: 0});
    channel.binaryType = "arraybuffer";
    channel.bufferedAmountLowThreshold = BUFFER_BUDGET;
    channel.addEventListener("bufferedamountlow", () => this.flush());
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

  /** Takes a publish for this frame's message (true) while the channel is open; false: send it over rosbridge
   * instead. flush() sends what was taken. */
  send(topic, msg) {
    if (!this.open) return false;
    if (topic === HEAD && this.stalled()) {  // this head pose over rosbridge, and the one waiting is dropped
      this.pending.delete(HEAD);
      this.failovers += 1;
      return false;
    }
    if (this.pending.has(topic)) this.replaced += 1;
    this.pending.set(topic, msg);
    return true;
  }

  /** The channel has taken no head pose for STALL_MS and still has more buffered than it takes. */
  stalled() {
    const now = this.now();
    this.headTakenAt ??= now;
    const channel = this.channel;
    return now - this.headTakenAt > STALL_MS && channel.bufferedAmount > channel.bufferedAmountLowThreshold;
  }

  /** At the end of each frame (and when the channel drains): what is pending, as one pose frame. */
  flush() {
    const channel = this.channel;
    if (!this.pending.size || !this.open || channel.bufferedAmount > channel.bufferedAmountLowThreshold) return;
    const frame = encodePoseFrame(this.pending);
    const head = this.pending.has(HEAD);
    this.pending.clear();
    try {
      channel.send(frame);
    } catch {
      return;  // closing: the next frames go over rosbridge
    }
    this.sent += 1;
    if (head) this.headTakenAt = this.now();
  }

  stats() {
    return {open: this.open, sent: this.sent, replaced: this.replaced, failovers: this.failovers};
  }
}
