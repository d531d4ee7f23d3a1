// Supervised autonomy as both pages see it (issue 34): the level, where the robot's attention is, the proposals
// waiting for the teacher's decision and how they ended. One model over rosbridge (either page's client: both
// have subscribe(topic, type, callback, options) and call(service, args)), and the geometry that puts the
// attention target on a picture of the robot's camera. No drawing here: the operator page draws on its canvases
// (operator/autonomy.js), the dashboard in its DOM.

import * as names from "./names.js";

const OUTCOMES_KEPT = 8;
const OUTCOME_WORDS = {
  accepted: "accepted", rejected: "rejected", forbidden: "forbidden here", timed_out_executed: "done after the time-out",
  superseded: "replaced by a newer proposal", dropped: "dropped", teacher_initiated: "done by the teacher",
};

/** How a proposal ended, in words: "nod: rejected by teacher-1 after 0.6 s". o.label: the proposal's label when
 * this page saw the proposal, else the action's menu id. */
export function outcomeText(o) {
  const by = o.decided_by && !["timeout", "server"].includes(o.decided_by) ? ` by ${o.decided_by}` : "";
  const after = Number.isFinite(o.seconds) && o.outcome !== "teacher_initiated" ? ` after ${o.seconds.toFixed(1)} s` : "";
  return `${o.label || o.action || o.id}: ${OUTCOME_WORDS[o.outcome] || o.outcome}${by}${after}`;
}

/** What the attention target says in words: "child_left (voice and face)". The name is the server's (`who`: the
 * track id, or the name it was given with /vr_teleop/people/rename), the one every view shows. */
export function attentionText(a) {
  if (!a || !a.source) return "nobody";
  const source = {face: "face", voice: "voice", both: "voice and face", glance: "looking around"}[a.source] || a.source;
  return a.who ? `${a.who} (${source})` : source;
}

export class AutonomyModel {
  /** onChange(): called after anything shown changed. now(): milliseconds, monotonic (the countdowns). */
  constructor(ros, {onChange = () => {}, now = () => performance.now()} = {}) {
    this.ros = ros;
    this.onChange = onChange;
    this.now = now;
    this.level = "";          // "" until the server's state arrives (an older server: no autonomy at all)
    this.attention = null;    // the newest vr_teleop_msgs/AttentionTarget, or null
    this.running = [];
    this.owners = [];
    this.pending = new Map(); // id -> {proposal, due}: due (this page's clock) from the time the server says is left
    this.outcomes = [];       // newest first
    this.refusal = null;      // {text, at}: the server's word on the last refused decision or level
    this.decided = new Map(); // id -> label: proposals this page decided, until their outcome arrives
    ros.subscribe(names.AUTONOMY_STATE_TOPIC, "vr_teleop_msgs/AutonomyState", (s) => this.onState(s));
    ros.subscribe(names.AUTONOMY_ATTENTION_TOPIC, "vr_teleop_msgs/AttentionTarget", (a) => {
      this.attention = a;
      this.onChange();
    }, {throttle_rate: 100, queue_length: 1});
    ros.subscribe(names.AUTONOMY_PROPOSALS_TOPIC, "vr_teleop_msgs/Proposal", (p) => {
      this.add(p);
      this.onChange();
    });
    ros.subscribe(names.AUTONOMY_OUTCOMES_TOPIC, "vr_teleop_msgs/ProposalOutcome", (o) => {
      const label = this.pending.get(o.id)?.proposal.label || this.decided.get(o.id) || "";
      this.pending.delete(o.id);
      this.decided.delete(o.id);
      this.outcomes.unshift({...o, label, at: this.now()});
      this.outcomes.splice(OUTCOMES_KEPT);
      this.onChange();
    });
  }

  /** A proposal from the proposals topic or the state: its time-out is due when the server says (`left`, seconds
   * left when it sent the message; an older server sends none: the whole time-out), so that a page opening onto a
   * pending proposal counts down what is really left. */
  add(proposal) {
    const left = Number.isFinite(proposal.left) ? proposal.left : (proposal.timeout || 0);
    this.pending.set(proposal.id, {proposal, due: this.now() + 1000 * Math.max(0, left)});
  }

  onState(s) {
    this.level = s.level;
    this.attention = s.attention && s.attention.source !== undefined ? s.attention : this.attention;
    this.running = s.running || [];
    this.owners = s.owners || [];
    const ids = new Set((s.pending || []).map((p) => p.id));
    for (const id of this.pending.keys()) if (!ids.has(id)) this.pending.delete(id);  // the state is the truth
    for (const p of s.pending || []) this.add(p);
    this.onChange();
  }

  /** The proposal to decide on now (the oldest pending) with its countdown, or null. waiting: its time-out has
   * come and the server does it once the robot's voice (face, parts) is free of someone else's sentence. */
  current() {
    const first = this.pending.values().next().value;
    if (!first) return null;
    const {proposal, due} = first;
    const timeout = Math.max(0, proposal.timeout || 0);
    const left = Math.max(0, (due - this.now()) / 1000);
    return {...proposal, left, waiting: left <= 0, fraction: timeout > 0 ? Math.min(1, left / timeout) : 0,
            others: this.pending.size - 1};
  }

  /** The countdown in words: "4.2 s, then done", or what a proposal whose time-out has come waits for. */
  static countdown(p) {
    if (p.on_timeout === "drop") return p.waiting ? "dropping" : `${p.left.toFixed(1)} s, then dropped`;
    return p.waiting ? "done once the robot is free" : `${p.left.toFixed(1)} s, then done`;
  }

  /** decision: accept, reject or forbid, on the current proposal. Resolves to the server's message; rejects with
   * its refusal (a spectator's page, a proposal already gone), which is also kept in `refusal` to show. */
  async decide(decision) {
    const p = this.current();
    if (!p) throw new Error("no proposal is waiting");
    try {
      const r = await this.ros.call(names.AUTONOMY_DECIDE_SERVICE, {id: p.id, decision});
      if (this.pending.delete(p.id)) this.decided.set(p.id, p.label);
      this.refusal = null;
      this.onChange();
      return r?.message || `${decision}ed`;
    } catch (err) {
      this.refused(`${decision} refused: ${err.message}`);
      throw err;
    }
  }

  async setLevel(level) {
    try {
      const r = await this.ros.call(names.AUTONOMY_LEVEL_SERVICE, {level});
      this.refusal = null;
      this.onChange();
      return r?.message || `autonomy: ${level}`;
    } catch (err) {
      this.refused(`level ${level} refused: ${err.message}`);
      throw err;
    }
  }

  refused(text) {
    this.refusal = {text, at: this.now()};
    this.onChange();
  }

  /** Who moves the head now, from the owners (autonomy, operator...), or "". */
  owner(part) {
    return this.owners.find((o) => o.part === part)?.owner || "";
  }
}

/** Where a direction falls in the robot's camera image, as fractions of its width and height from the top left
 * ({u, v}, possibly outside 0..1), or null when it is behind the camera. yaw, pitch: the direction in the robot's
 * base frame, degrees, as the head's joints name a direction (the autonomy feature's convention): yaw positive to
 * the left, pitch positive down. headYaw, headPitch: the head's joints now. A pinhole camera looking along the
 * head, hfovDeg wide, its image `aspect` (width / height) with square pixels; the camera's offset from the neck is
 * small against a pupil's distance and is left out. */
export function directionInImage(yaw, pitch, headYaw, headPitch, hfovDeg, aspect) {
  const r = Math.PI / 180;
  const x0 = Math.cos(pitch * r) * Math.cos(yaw * r), y0 = Math.cos(pitch * r) * Math.sin(yaw * r);
  const z0 = -Math.sin(pitch * r);
  const cy = Math.cos(headYaw * r), sy = Math.sin(headYaw * r);
  const x1 = cy * x0 + sy * y0, y1 = -sy * x0 + cy * y0;              // the head's yaw undone
  const cp = Math.cos(headPitch * r), sp = Math.sin(headPitch * r);
  const x = cp * x1 - sp * z0, z = sp * x1 + cp * z0;                  // and its pitch (down positive)
  if (x <= 1e-6) return null;
  const half = Math.tan(hfovDeg * r / 2);
  return {u: 0.5 - (y1 / x) / (2 * half), v: 0.5 - (z / x) * aspect / (2 * half)};
}

/** The attention target on a picture of the camera: {kind: "face", box: {u, v, w, h}} from the face's pixels
 * (image: {width, height} of the camera's frames), or {kind: "direction", u, v, inside} from its direction and
 * the head's joints (head: {yaw, pitch}, degrees), or null (no target, or behind the camera). */
export function attentionInImage(attention, head, hfovDeg, image) {
  if (!attention || !attention.source) return null;
  const f = attention.face;
  if (attention.has_face && f && image?.width > 0 && image?.height > 0) {
    return {kind: "face", box: {u: f.x / image.width, v: f.y / image.height, w: f.width / image.width,
                                h: f.height / image.height}};
  }
  const aspect = image?.width > 0 && image?.height > 0 ? image.width / image.height : 4 / 3;
  const at = directionInImage(attention.yaw, attention.pitch, head.yaw, head.pitch, hfovDeg, aspect);
  if (!at) return null;
  return {kind: "direction", u: at.u, v: at.v, inside: at.u >= 0 && at.u <= 1 && at.v >= 0 && at.v <= 1};
}
