// WebRTC media beside the rosbridge stream (issue 20), shared by the dashboard (/dashboard.js) and the operator
// page (/operator/camera.js). Signalling rides the page's rosbridge connection: `ros` is either page's client,
// anything with call(service, args) -> Promise and subscribe(topic, type, callback, options).
//
// The boundary. The server takes ONE peer connection per rosbridge connection (a second offer is refused), so
// whoever wants more on it (a data channel for poses, issue 21) adds it between creating and negotiating:
//
//   const pc = createPeerConnection({video: true, audio: true});  // recvonly transceivers, nothing sent yet
//   pc.createDataChannel("poses", {ordered: false, maxRetransmits: 0});   // anything else: BEFORE the offer
//   const sends = await negotiate(ros, pc);  // {video, audio}: what the server sends; throws MediaError
//
// The operator page's CameraFeed (operator/camera.js) does exactly this and takes that middle step as its
// `prepare(pc)` option, called on every negotiation (each new rosbridge connection gets a new peer connection).
//
// Frame ages. A JPEG frame carries its render time in its header stamp. A WebRTC frame carries an RTP timestamp
// (the server's send time at 90 kHz, random origin per peer), which requestVideoFrameCallback reports for the
// shown frame; the telemetry (/vr_teleop/telemetry, 2 Hz) lists the recent frames' RTP timestamps with their
// render times (RenderTimes). ServerClock (/vr_teleop/clock, NTP-style) puts the server's times on this clock.

import * as names from "./names.js";
export const OFFER_SERVICE = names.MEDIA_OFFER_SERVICE;
export const CLOCK_SERVICE = names.CLOCK_SERVICE;
export const TELEMETRY_TOPIC = names.TELEMETRY_TOPIC;

/** Why there is no WebRTC: `refused` when the server said no (its message), otherwise a local or network cause. */
export class MediaError extends Error {
  constructor(message, {refused = false} = {}) {
    super(message);
    this.name = "MediaError";
    this.refused = refused;
  }
}

/** "webrtc" (the default) or "jpeg": the page URL's #camera=... (after #token=..., joined with &). */
export function cameraMode(hash = globalThis.location?.hash ?? "") {
  return new URLSearchParams(hash.replace(/^#/, "")).get("camera") === "jpeg" ? "jpeg" : "webrtc";
}

/** Why this browser cannot do WebRTC, or "" when it can. */
export function webRtcMissing() {
  return typeof globalThis.RTCPeerConnection === "function" ? "" : "this browser has no WebRTC (RTCPeerConnection)";
}

/** A peer connection that receives the camera and/or the robot's audio, not yet offered. */
export function createPeerConnection({video = true, audio = true, iceServers = []} = {}) {
  const pc = new RTCPeerConnection({iceServers});
  if (video) pc.addTransceiver("video", {direction: "recvonly"});
  if (audio) pc.addTransceiver("audio", {direction: "recvonly"});
  return pc;
}

/** Offers pc (after ICE gathering: the server takes no trickled candidates), sets the server's answer and waits
 * until the connection is up. Resolves {video, audio, message}: whether the server sends each (a server without a
 * camera answers the video section inactive) and what it said (why it rejected a section it could not take, e.g.
 * video without a common codec beside a data channel: the rest of the connection is up). Throws MediaError; the
 * caller closes pc. */
export async function negotiate(ros, pc, {gatherMs = 2000, connectMs = 10000} = {}) {
  await pc.setLocalDescription(await pc.createOffer());
  await new Promise((resolve) => {
    if (pc.iceGatheringState === "complete") return resolve();
    pc.addEventListener("icegatheringstatechange", () => pc.iceGatheringState === "complete" && resolve());
    setTimeout(resolve, gatherMs);  // host candidates come at once; enough by then
  });
  let answer;
  try {
    answer = await ros.call(OFFER_SERVICE, {sdp: pc.localDescription.sdp, type: "offer"});
  } catch (err) {  // a client that rejects refusals (success false) marks them `refused`, keeping the server's reason
    if (err.refused) throw new MediaError(err.message, {refused: true});
    throw new MediaError(`${OFFER_SERVICE} failed: ${err.message}`);
  }
  if (!answer.success) throw new MediaError(answer.message || "the server refused the offer", {refused: true});
  await pc.setRemoteDescription({sdp: answer.sdp, type: answer.type});
  // A live view, not a film: no jitter buffer beyond what decoding needs (Chromium's hints; others ignore them).
  for (const r of pc.getReceivers()) {
    r.playoutDelayHint = 0;
    r.jitterBufferTarget = 0;
  }
  await new Promise((resolve, reject) => {
    const timer = setTimeout(() => reject(new MediaError(`the peer connection did not connect within ${connectMs / 1000} s`)),
                             connectMs);
    const check = () => {
      if (pc.connectionState === "connected") { clearTimeout(timer); resolve(); }
      else if (["failed", "closed"].includes(pc.connectionState)) {
        clearTimeout(timer);
        reject(new MediaError(`the peer connection ${pc.connectionState} (ICE/DTLS)`));
      }
    };
    pc.addEventListener("connectionstatechange", check);
    check();
  });
  const sends = {video: false, audio: false, message: answer.message || ""};
  for (const t of pc.getTransceivers()) {
    const kind = t.receiver.track?.kind;
    if (kind in sends && ["recvonly", "sendrecv"].includes(t.currentDirection)) sends[kind] = true;
  }
  return sends;
}

/** Server time on this page's clock: offset = server - page, from the exchange with the shortest round trip
 * (NTP's rule: the least room for asymmetry). Until the first sync the offset is 0 (one machine, one clock). */
export class ServerClock {
  constructor(ros) {
    this.ros = ros;
    this.offset = 0;
    this.synced = false;
  }

  now() {
    return Date.now() / 1000 + this.offset;
  }

  async sync(rounds = 8) {
    let best = null;
    for (let i = 0; i < rounds; i++) {
      const sent = Date.now() / 1000;
      const r = await this.ros.call(CLOCK_SERVICE, {client_send: sent});
      const back = Date.now() / 1000;
      const trip = (back - sent) - (r.server_send - r.server_receive);
      if (!best || trip < best.trip) {
        best = {trip, offset: ((r.server_receive - sent) + (r.server_send - back)) / 2};
      }
      await new Promise((resolve) => setTimeout(resolve, 50));
    }
    this.offset = best.offset;
    this.synced = true;
    return best;
  }
}

/** a - b between two 32-bit RTP timestamps, across a wrap. */
export function rtpDelta(a, b) {
  return ((a - b + 2 ** 31) % 2 ** 32 + 2 ** 32) % 2 ** 32 - 2 ** 31;
}

/** Render times (server clock, seconds) of WebRTC frames by RTP timestamp, from the telemetry. Our entry among the
 * clients' is the peer whose RTP timestamps are near the ones we receive (`saw(rtp)`; origins are random). A shown
 * frame's age is known once its render time arrives (within 0.5 s): `whenKnown`. */
export class RenderTimes {
  constructor(ros, {keep = 600} = {}) {
    this.keep = keep;
    this.times = new Map();   // rtp -> render time
    this.newest = null;       // {rtp, time, rate}: our peer's newest frame, for estimates
    this.lastRtp = undefined; // the newest RTP timestamp this page received
    this.waiting = [];        // {rtp, callback}
    ros.subscribe(TELEMETRY_TOPIC, "vr_teleop_msgs/Telemetry", (msg) => this.telemetry(msg));
  }

  saw(rtp) {
    this.lastRtp = rtp;
  }

  telemetry(msg) {
    const rtp = this.lastRtp;
    if (rtp === undefined) return;
    for (const c of msg.clients || []) {
      if (!c.rtp_clock_rate || Math.abs(rtpDelta(rtp, c.rtp_timestamp)) > 10 * c.rtp_clock_rate) continue;
      c.frame_rtp_timestamps.forEach((r, i) => this.times.set(r, c.frame_render_times[i]));
      this.newest = {rtp: c.rtp_timestamp, time: c.rtp_render_time, rate: c.rtp_clock_rate};
      while (this.times.size > this.keep) this.times.delete(this.times.keys().next().value);
    }
    this.resolve();
  }

  /** The frame's render time, or undefined while the telemetry has not listed it. */
  lookup(rtp) {
    return this.times.get(rtp);
  }

  /** The render time if known, else extrapolated from our peer's newest listed frame along the RTP clock (which
   * runs with the server's send times: off by the variation of render-to-send delay, a few ms); null before any
   * telemetry. */
  estimate(rtp) {
    const known = this.times.get(rtp);
    if (known !== undefined) return known;
    if (!this.newest) return null;
    return this.newest.time + rtpDelta(rtp, this.newest.rtp) / this.newest.rate;
  }

  /** callback(renderTime) once the frame's render time is listed; forgotten after 240 frames (not ours, or lost). */
  whenKnown(rtp, callback) {
    this.waiting.push({rtp, callback});
    this.resolve();
  }

  resolve() {
    const still = [];
    for (const w of this.waiting) {
      const t = this.times.get(w.rtp);
      if (t !== undefined) w.callback(t);
      else still.push(w);
    }
    this.waiting = still.slice(-240);
  }
}

/** Calls callback(now, metadata) for every frame the video element presents (requestVideoFrameCallback: metadata
 * has rtpTimestamp for WebRTC frames, presentationTime...). Returns a function that stops it. */
export function onVideoFrames(video, callback) {
  let stopped = false;
  let id = 0;
  const next = (now, meta) => {
    if (stopped) return;
    try {
      callback(now, meta);
    } finally {
      id = video.requestVideoFrameCallback(next);
    }
  };
  id = video.requestVideoFrameCallback(next);
  return () => {
    stopped = true;
    video.cancelVideoFrameCallback?.(id);
  };
}

// ---- ICE servers: STUN and TURN (issue 30) ------------------------------------------------------------------------
// Behind NATs and a firewall that blocks UDP, media need a TURN relay. The server hands each peer connection its ICE
// servers with fresh time-limited TURN credentials (/vr_teleop/media/ice_servers); ask before each
// createPeerConnection. IceErrors collects the relays' refusals (wrong or expired credentials) for the page to
// show; mediaRoute says from getStats whether the media go direct or through a relay, and over what.

export const ICE_SERVERS_SERVICE = names.MEDIA_ICE_SERVERS_SERVICE;

/** {iceServers, expires, message}: the server's ICE servers for RTCPeerConnection. A server without the service or
 * that refuses it gives none (host candidates only: a LAN), with the reason in message. */
export async function fetchIceServers(ros) {
  try {
    const r = await ros.call(ICE_SERVERS_SERVICE, {});
    if (!r.success) return {iceServers: [], expires: 0, message: r.message || "the ICE servers were refused"};
    const iceServers = (r.ice_servers ?? []).map(({urls, username, credential}) =>
      (username ? {urls, username, credential} : {urls}));
    return {iceServers, expires: r.expires ?? 0, message: r.message || ""};
  } catch (err) {
    return {iceServers: [], expires: 0, message: `${ICE_SERVERS_SERVICE} failed: ${err.message}`};
  }
}

/** Whether any of the servers is a TURN relay. */
export function hasTurn(iceServers) {
  return iceServers.some((s) => [].concat(s.urls).some((u) => /^turns?:/.test(u)));
}

/** The TURN relays' answers that mean no relay: 401 (credentials wrong or expired), 403, 437/438, or unreachable
 * (701), as text, once each. `onRefusal(text)` hears the credential refusals as they come. `expires` (s since 1970,
 * from fetchIceServers; 0: unknown) tells an expired credential from a wrong one: the server's clock being behind
 * the relay's issues credentials that are dead on arrival. */
export class IceErrors {
  constructor(pc, onRefusal = () => {}, expires = 0) {
    this.errors = [];
    this.refused = false;
    pc.addEventListener("icecandidateerror", (event) => {
      if (!/^turns?:/.test(event.url ?? "")) return;
      const auth = [401, 403, 437, 438].includes(event.errorCode);
      const expired = expires > 0 && expires * 1000 <= Date.now();
      const text = !auth ? `the TURN relay ${event.url} failed (${event.errorCode} ${event.errorText})`
        : `the TURN relay ${event.url} refused the credentials (${event.errorCode} ${event.errorText}): ` + (expired
          ? `they expired at ${new Date(expires * 1000).toISOString()}, before this page used them (is the ` +
            "server's clock behind?)"
          : "wrong or expired");
      if (this.errors.includes(text)) return;
      this.errors.push(text);
      if (auth) {
        this.refused = true;
        onRefusal(text);
      }
    });
  }

  summary() {
    return this.errors.join("; ");
  }
}

/** How the media travel, from the selected candidate pair: {route: "direct" | "TURN relay (udp|tcp|tls)" |
 * "the server's TURN relay" | "", local, remote, relayProtocol} ("" while there is no pair yet). */
export async function mediaRoute(pc) {
  const stats = await pc.getStats();
  let pair = null;
  stats.forEach((s) => {
    if (s.type === "transport" && s.selectedCandidatePairId) pair = stats.get(s.selectedCandidatePairId) ?? pair;
  });
  if (!pair) stats.forEach((s) => { if (s.type === "candidate-pair" && s.nominated && s.state === "succeeded") pair = s; });
  if (!pair) return {route: "", local: "", remote: "", relayProtocol: ""};
  const local = stats.get(pair.localCandidateId) ?? {};
  const remote = stats.get(pair.remoteCandidateId) ?? {};
  const route = local.candidateType === "relay" ? `TURN relay (${local.relayProtocol ?? "?"})`
    : remote.candidateType === "relay" ? "the server's TURN relay" : "direct";
  return {route, local: local.candidateType ?? "", remote: remote.candidateType ?? "",
          relayProtocol: local.relayProtocol ?? ""};
}
