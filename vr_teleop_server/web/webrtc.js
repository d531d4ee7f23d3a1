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

/** A peer connection that receives the camera and/or the robot's audio, not yet offered. `videoCodec` ("H264" or
 * "VP8", from chooseVideoCodec) is put first in the video section's codecs (setCodecPreferences; negotiate() does
 * the same to the offer's text where a browser lacks it): the server sends the first codec it shares. */
export function createPeerConnection({video = true, audio = true, iceServers = [], videoCodec = ""} = {}) {
  const pc = new RTCPeerConnection({iceServers});
  if (video) {
    const t = pc.addTransceiver("video", {direction: "recvonly"});
    const caps = globalThis.RTCRtpReceiver?.getCapabilities?.("video")?.codecs;
    if (videoCodec && caps && typeof t.setCodecPreferences === "function") {
      t.setCodecPreferences(codecOrder(caps, videoCodec));
    }
  }
  if (audio) pc.addTransceiver("audio", {direction: "recvonly"});
  return pc;
}

/** Offers pc (after ICE gathering: the server takes no trickled candidates), sets the server's answer and waits
 * until the connection is up. Resolves {video, audio, message}: whether the server sends each (a server without a
 * camera answers the video section inactive) and what it said (why it rejected a section it could not take, e.g.
 * video without a common codec beside a data channel: the rest of the connection is up), and videoCodec: the codec
 * the server sends the camera in ("H264", "VP8"; the first of its answer's video section, the server's rule).
 * Throws MediaError; the caller closes pc. */
export async function negotiate(ros, pc, {gatherMs = 2000, connectMs = 10000, videoCodec = ""} = {}) {
  await pc.setLocalDescription(await pc.createOffer());
  await new Promise((resolve) => {
    if (pc.iceGatheringState === "complete") return resolve();
    pc.addEventListener("icegatheringstatechange", () => pc.iceGatheringState === "complete" && resolve());
    setTimeout(resolve, gatherMs);  // host candidates come at once; enough by then
  });
  let answer;
  try {
    const sdp = preferVideoCodec(pc.localDescription.sdp, videoCodec);  // already so after setCodecPreferences
    answer = await ros.call(OFFER_SERVICE, {sdp, type: "offer"});
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
  const sends = {video: false, audio: false, message: answer.message || "", videoCodec: firstVideoCodec(answer.sdp)};
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

// ---- the video codec (issue 36) ------------------------------------------------------------------------------------
// The server encodes the camera once per codec (VP8 and H.264) and sends each peer the first codec of its offer's
// video section that it shares (aiortc answers in the offer's order). The page asks for H.264 first where the
// browser decodes H.264 in hardware (the Quest browser does: less heat and battery, and the decode off the CPU the
// page renders with), VP8 otherwise (a software decoder: libvpx is lighter than a software H.264 decoder, and VP8 is
// the codec every WebRTC browser has). `codec=h264` or `codec=vp8` in the page's address (#token=...&codec=h264, or
// ?codec=h264) forces one, for testing.

export const VIDEO_CODECS = {h264: "H264", vp8: "VP8"};
export const CODEC_NAMES = {H264: "H.264", VP8: "VP8"};  // for people (the HUD)

/** What the browser is asked about its H.264 decoder: the profile the server encodes (constrained baseline). */
export const H264_DECODING = {
  type: "webrtc",
  video: {contentType: "video/h264; profile-level-id=42e01f; packetization-mode=1", width: 1280, height: 720,
          bitrate: 2000000, framerate: 30},
};

/** {codec, problem}: the codec the address forces ("H264", "VP8", or "" for none) and, for a value that is neither,
 * why it is ignored. */
export function codecOption(hash = globalThis.location?.hash ?? "", search = globalThis.location?.search ?? "") {
  const value = new URLSearchParams(hash.replace(/^#/, "")).get("codec") ?? new URLSearchParams(search).get("codec");
  if (!value) return {codec: "", problem: ""};
  const codec = VIDEO_CODECS[value.toLowerCase()] ?? "";
  return {codec, problem: codec ? "" : `codec=${value} in the address is not h264 or vp8: ignored, the page chooses`};
}

/** Which codec to ask for first: {codec: "H264" | "VP8", why}. In order: the address's codec=...; VP8 when this
 * browser's WebRTC has no H.264; H.264 when navigator.mediaCapabilities.decodingInfo says its H.264 WebRTC decoder
 * is powerEfficient (hardware), else VP8; without that API (or when it refuses type "webrtc"), H.264 in the Quest
 * browser (its user agent says "OculusBrowser"), VP8 elsewhere. The defaults are the browser's own objects. */
export async function chooseVideoCodec({option = codecOption(),
                                        capabilities = globalThis.RTCRtpReceiver?.getCapabilities?.("video"),
                                        mediaCapabilities = globalThis.navigator?.mediaCapabilities,
                                        userAgent = globalThis.navigator?.userAgent ?? ""} = {}) {
  if (option.codec) return {codec: option.codec, why: `codec=${option.codec.toLowerCase()} in the address`};
  const h264 = !capabilities || capabilities.codecs.some((c) => /^video\/h264$/i.test(c.mimeType));
  if (!h264) return {codec: "VP8", why: "this browser's WebRTC has no H.264"};
  if (typeof mediaCapabilities?.decodingInfo === "function") {
    try {
      const info = await mediaCapabilities.decodingInfo(H264_DECODING);
      return info.supported && info.powerEfficient ? {codec: "H264", why: "hardware H.264 decoder"}
        : {codec: "VP8", why: "no hardware H.264 decoder"};
    } catch (err) { /* no "webrtc" queries here: the user-agent rule */ }
  }
  return /OculusBrowser/.test(userAgent) ? {codec: "H264", why: "the Quest browser (user agent)"}
    : {codec: "VP8", why: "no decoder information (not the Quest browser)"};
}

function codecName(mimeType) {
  return (mimeType.split("/")[1] ?? "").toUpperCase();
}

/** RTCRtpReceiver.getCapabilities("video").codecs with `codec`'s entries first, the rest in their order; for H.264
 * those the server can send first (packetization-mode 1, constrained baseline or baseline profile). */
export function codecOrder(codecs, codec) {
  const rank = (c) => {
    if (codecName(c.mimeType) !== codec) return 2;
    if (codec !== "H264") return 0;
    const fmtp = c.sdpFmtpLine ?? "";
    return /packetization-mode=1/.test(fmtp) && /profile-level-id=42(e0|00)/i.test(fmtp) ? 0 : 1;
  };
  return [...codecs].sort((a, b) => rank(a) - rank(b));  // stable: the rest keep their order
}

/** The offer's text with `codec`'s payload types first on its video m= line (the rest in their order); unchanged
 * when it already leads or is absent. For browsers without setCodecPreferences: the server answers in this order. */
export function preferVideoCodec(sdp, codec) {
  if (!codec) return sdp;
  const lines = sdp.split("\r\n");
  const at = lines.findIndex((l) => l.startsWith("m=video "));
  if (at < 0) return sdp;
  let end = lines.findIndex((l, i) => i > at && l.startsWith("m="));
  if (end < 0) end = lines.length;
  const names = new Map();
  for (const l of lines.slice(at, end)) {
    const m = /^a=rtpmap:(\d+) ([^/]+)\//.exec(l);
    if (m) names.set(m[1], m[2].toUpperCase());
  }
  const parts = lines[at].split(" ");
  const types = parts.slice(3);
  const ours = types.filter((t) => names.get(t) === codec);
  if (!ours.length || names.get(types[0]) === codec) return sdp;
  lines[at] = [...parts.slice(0, 3), ...ours, ...types.filter((t) => names.get(t) !== codec)].join(" ");
  return lines.join("\r\n");
}

/** The codec of the first payload type of an SDP's first video section ("H264", "VP8"), "" without one. */
export function firstVideoCodec(sdp = "") {
  const lines = sdp.split(/\r?\n/);
  const at = lines.findIndex((l) => l.startsWith("m=video "));
  if (at < 0) return "";
  const [, , , first] = lines[at].split(" ");
  if (!first || lines[at].split(" ")[1] === "0") return "";
  for (const l of lines.slice(at + 1)) {
    if (l.startsWith("m=")) break;
    const m = /^a=rtpmap:(\d+) ([^/]+)\//.exec(l);
    if (m && m[1] === first) return m[2].toUpperCase();
  }
  return "";
}
