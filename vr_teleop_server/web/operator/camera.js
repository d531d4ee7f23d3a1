// The robot's eyes. A camera source hands the panel a THREE.Texture and counts what it shows; the panel does not
// care where the frames come from. Two sources of one shape ({texture, aspect, frameAge(), stats(), dispose()}):
// VideoCameraSource, WebRTC video (issue 20) on a <video> element uploaded as a THREE.VideoTexture, and
// JpegCameraSource, the JPEG topic over rosbridge. CameraFeed (what main.js holds) negotiates WebRTC on every
// rosbridge connection and falls back to the JPEG topic when that is refused, impossible or fails later, saying so.
// Signalling, the clock and the RTP -> render time mapping are ../webrtc.js, shared with the dashboard.
//
// Capture poses (issue 36). Each frame comes with the robot's head pose when it was taken: on the JPEG road from
// /vr_teleop/camera/capture_pose (matched by header stamp), on WebRTC from the "capture_poses" data channel (matched
// by RTP timestamp). CameraFeed.placementPose() gives main.js the pose to hang the panel by: the shown frame's
// capture pose, so a still object in the room stays still while the robot's head catches up; without one (its
// message lost, or not come yet) the pose of the nearest frame taken within NEAREST_S of it, else the newest joint
// state (today's placement). The URL's #placement=newest (or `camera.placement = "newest"`) keeps today's
// placement throughout.

import * as names from "../names.js";
import * as THREE from "three";
import {stampSeconds} from "../rosbridge.js";
import {CODEC_NAMES, IceErrors, MediaError, RenderTimes, ServerClock, cameraMode, chooseVideoCodec, codecOption,
        createPeerConnection, fetchIceServers, hasTurn, mediaRoute, negotiate, onVideoFrames, rtpDelta,
        webRtcMissing} from "../webrtc.js";

export const CAMERA_TOPIC = names.CAMERA_TOPIC;
export const CAPTURE_POSE_TOPIC = names.CAPTURE_POSE_TOPIC;
export const CAPTURE_POSES_CHANNEL = names.CAPTURE_POSES_CHANNEL;
const AGES_KEPT = 2000;
const POSES_KEPT = 240;        // capture poses kept by frame key (8 s at 30 fps)
const NEAREST_S = 0.2;         // a frame without its pose is placed by the nearest frame's taken this close to it
const TRACE_KEPT = 20000;

/** "capture" (the default: the panel by each frame's capture pose) or "newest" (by the newest joint state): the page
 * URL's #placement=... (joined with & to the rest of the hash). */
export function placementMode(hash = globalThis.location?.hash ?? "") {
  return new URLSearchParams(hash.replace(/^#/, "")).get("placement") === "newest" ? "newest" : "capture";
}

/** Capture poses by frame key (a header stamp in seconds, or an RTP timestamp), the newest POSES_KEPT; `seconds(a,
 * b)` is how far apart two keys were taken. */
export class CapturePoses {
  constructor(seconds = (a, b) => Math.abs(a - b), keep = POSES_KEPT) {
    this.seconds = seconds;
    this.keep = keep;
    this.poses = new Map();
    this.received = 0;
  }

  /** A vr_teleop_msgs/CapturePose (or the channel's message): degrees, as the joint states have them. */
  add(key, msg) {
    if (key === null || key === undefined || !Number.isFinite(msg.head_yaw) || !Number.isFinite(msg.head_pitch)) {
      return;
    }
    this.received += 1;
    this.poses.set(key, {yaw: msg.head_yaw, pitch: msg.head_pitch, gap: msg.stamp_gap ?? 0,
                         source: msg.source ?? ""});
    while (this.poses.size > this.keep) this.poses.delete(this.poses.keys().next().value);
  }

  get(key) {
    return key === null || key === undefined ? undefined : this.poses.get(key);
  }

  /** The pose of the frame taken nearest to `key`'s, if within `within` seconds of it (else undefined). */
  nearest(key, within = NEAREST_S) {
    if (key === null || key === undefined) return undefined;
    let best, gap = within;
    for (const [k, pose] of this.poses) {
      const d = this.seconds(k, key);
      if (d <= gap) { gap = d; best = pose; }
    }
    return best;
  }
}

/** How far apart two WebRTC frames were sent, from their RTP timestamps (90 kHz, across a wrap). */
const rtpSeconds = (a, b) => Math.abs(rtpDelta(a, b)) / 90000;

export class JpegCameraSource {
  /** Newest frame only: the server sends at most one frame at a time (queue_length 1), and while a frame is being
   * decoded (in a worker, off the main thread) newer ones replace each other: never a backlog. */
  constructor(ros, {onError = () => {}, placeholder = null, clock = null} = {}) {
    this.onError = onError;
    this.now = clock ? () => clock.now() : () => Date.now() / 1000;  // the server's clock, when synchronised
    this.texture = new THREE.Texture(placeholder ?? undefined);
    this.texture.colorSpace = THREE.SRGBColorSpace;
    this.texture.generateMipmaps = false;
    this.texture.minFilter = THREE.LinearFilter;
    if (placeholder) this.texture.needsUpdate = true;
    this.aspect = 4 / 3;
    this.received = 0;      // frames from the server
    this.replaced = 0;      // frames dropped because a newer one arrived while a decode was in flight
    this.uploaded = 0;      // frames uploaded to the GPU
    this.ages = [];         // stamp-to-upload ages in seconds (the bench reads them)
    this.shownStamp = null; // stamp of the frame on the texture
    this.busy = false;
    this.pending = null;
    this.uploading = null;
    this.lastError = "";
    this.texture.onUpdate = () => this.uploadedFrame();
    this.worker = new Worker(new URL("./camera_worker.js", import.meta.url));
    this.worker.onmessage = (event) => this.decoded(event.data);
    this.worker.onerror = (event) => this.fail(`the camera decoder failed: ${event.message}`);
    this.poses = new CapturePoses();
    // Before the camera: the server publishes each frame's pose just before the frame.
    ros.subscribe(CAPTURE_POSE_TOPIC, "vr_teleop_msgs/CapturePose",
      (msg) => this.poses.add(stampSeconds(msg.header?.stamp), msg), {throttle_rate: 0, queue_length: 4});
    ros.subscribe(CAMERA_TOPIC, "sensor_msgs/CompressedImage", (msg) => this.frame(msg),
      {throttle_rate: 0, queue_length: 1});
  }

  /** The key and capture pose of the frame the next render shows (the one uploading, else the one shown). */
  shownPose() {
    const key = this.uploading ?? this.shownStamp;
    return {key, pose: this.poses.get(key)};
  }

  frame(msg) {
    this.received += 1;
    if (msg.format && !/jpe?g/i.test(msg.format)) {
      this.fail(`camera frames in ${msg.format} cannot be shown (JPEG expected)`);
      return;
    }
    const frame = {data: msg.data, stamp: stampSeconds(msg.header?.stamp), seq: this.received};
    if (this.busy) {
      if (this.pending) this.replaced += 1;
      this.pending = frame;
      return;
    }
    this.decode(frame);
  }

  decode(frame) {
    this.busy = true;
    this.worker.postMessage(frame);
  }

  decoded({bitmap, stamp, error}) {
    this.busy = false;
    if (error) this.fail(`a camera frame could not be decoded: ${error}`);
    else {
      const old = this.texture.image;
      this.texture.image = bitmap;
      this.texture.flipY = false;  // the worker flipped it: WebGL does not flip ImageBitmaps
      this.texture.needsUpdate = true;
      this.uploading = stamp;
      this.aspect = bitmap.width / bitmap.height;
      this.size = {width: bitmap.width, height: bitmap.height};
      if (old && typeof old.close === "function") old.close();  // an earlier bitmap: its pixels are on the GPU
    }
    if (this.pending) {
      const next = this.pending;
      this.pending = null;
      this.decode(next);
    }
  }

  uploadedFrame() {
    if (this.uploading === null) return;
    this.uploaded += 1;
    this.shownStamp = this.uploading;
    this.ages.push(this.now() - this.uploading);
    if (this.ages.length > AGES_KEPT) this.ages.splice(0, this.ages.length - AGES_KEPT);
    this.uploading = null;
  }

  fail(text) {
    this.lastError = text;
    this.onError(text);
  }

  /** Seconds between the shown frame's stamp and now, on the server's clock (/vr_teleop/clock). */
  frameAge() {
    return this.shownStamp === null ? null : this.now() - this.shownStamp;
  }

  stats() {
    return {received: this.received, replaced: this.replaced, uploaded: this.uploaded};
  }

  dispose() {
    this.worker.terminate();
    this.texture.dispose();
  }
}

export class VideoCameraSource {
  /** WebRTC video: the <video> element decodes (the browser's media pipeline, off the main thread) and presents
   * the newest frame; the VideoTexture uploads it when the video presents one (requestVideoFrameCallback), so a
   * late frame is never queued behind another: newest only, by nature. */
  constructor(renderTimes, clock, poses) {
    this.renderTimes = renderTimes;
    this.clock = clock;
    this.poses = poses;  // CapturePoses by RTP timestamp, from the capture-poses data channel
    const video = this.video = document.createElement("video");
    video.muted = true;  // until a user gesture (the autoplay rule): then the robot's audio plays from here
    video.playsInline = true;
    video.autoplay = true;
    // In the document, invisible: a video that is part of the page is presented (and calls back) like any other.
    Object.assign(video.style, {position: "fixed", left: "0", top: "0", width: "2px", height: "2px", opacity: "0",
                                pointerEvents: "none"});
    video.setAttribute("aria-hidden", "true");
    document.body.append(video);
    this.texture = new THREE.VideoTexture(video);
    this.texture.colorSpace = THREE.SRGBColorSpace;
    this.aspect = 4 / 3;
    this.received = 0;       // frames the video presented
    this.uploaded = 0;       // frames uploaded to the GPU
    this.ages = [];          // render-to-upload ages in seconds, on the server's clock (the bench reads them)
    this.latestRtp = null;   // RTP timestamp of the frame the video presents now
    this.shownRtp = null;    // ... of the frame on the texture
    this.texture.onUpdate = () => this.uploadedFrame();
    this.stopFrames = onVideoFrames(video, (now, meta) => this.presented(meta));
  }

  attach(stream) {
    this.video.srcObject = stream;
    this.video.play().catch(() => {});
  }

  presented(meta) {
    this.received += 1;
    if (meta.width && meta.height) {
      this.aspect = meta.width / meta.height;
      this.size = {width: meta.width, height: meta.height};
    }
    if (meta.rtpTimestamp !== undefined) {
      this.latestRtp = meta.rtpTimestamp;
      this.renderTimes.saw(meta.rtpTimestamp);
    }
  }

  uploadedFrame() {
    this.uploaded += 1;
    const rtp = this.latestRtp;
    if (rtp === null || rtp === this.shownRtp) return;
    this.shownRtp = rtp;
    const at = this.clock.now();
    this.renderTimes.whenKnown(rtp, (rendered) => {
      this.ages.push(at - rendered);
      if (this.ages.length > AGES_KEPT) this.ages.splice(0, this.ages.length - AGES_KEPT);
    });
  }

  /** The key (RTP timestamp) and capture pose of the frame the next render shows: the one the video presents
   * (the VideoTexture uploads it at that render). */
  shownPose() {
    const key = this.latestRtp ?? this.shownRtp;
    return {key, pose: this.poses.get(key)};
  }

  /** Seconds between the shown frame's render time (by its RTP timestamp, from the telemetry) and now, on the
   * server's clock; null until the telemetry has told this page about its frames. */
  frameAge() {
    if (this.shownRtp === null) return null;
    const rendered = this.renderTimes.estimate(this.shownRtp);
    return rendered === null ? null : this.clock.now() - rendered;
  }

  stats() {
    return {received: this.received, replaced: 0, uploaded: this.uploaded};
  }

  dispose() {
    this.stopFrames();
    this.video.pause();
    this.video.srcObject = null;
    this.video.remove();
    this.texture.dispose();
  }
}

export class CameraFeed {
  /** The panel's camera: WebRTC video when negotiated, else the JPEG topic. Call connected() on every (re)opened
   * rosbridge connection (the server closes a connection's peer connection with it): WebRTC is negotiated again,
   * unless the page has fallen back to JPEG (a refusal, no WebRTC, a failed connection), where it stays.
   *  - onMessage(text, level): what to say on the HUD (the fallback and its reason);
   *  - onAudio(on): the robot's audio arrives over WebRTC (on) or not: the topic's chunks must not play as well;
   *  - prepare(pc): called before each offer, to add to the same peer connection (e.g. a data channel);
   *  - mode: "webrtc" or "jpeg" (the URL's #camera=jpeg);
   *  - codec: the video codec the address forces ({codec, problem}: webrtc.js codecOption, #codec=h264|vp8); by
   *    default the page asks for H.264 first where the browser decodes it in hardware, VP8 otherwise
   *    (chooseVideoCodec, once a page). */
  constructor(ros, {onMessage = () => {}, onAudio = () => {}, prepare = null, placeholder = null,
                    mode = cameraMode(), codec = codecOption()} = {}) {
    this.ros = ros;
    this.onMessage = onMessage;
    this.onAudio = onAudio;
    this.prepare = prepare;
    this.placeholderImage = placeholder;
    this.placeholder = new THREE.Texture(placeholder ?? undefined);
    this.placeholder.colorSpace = THREE.SRGBColorSpace;
    this.placeholder.minFilter = THREE.LinearFilter;
    this.placeholder.generateMipmaps = false;
    if (placeholder) this.placeholder.needsUpdate = true;
    this.clock = new ServerClock(ros);
    this.renderTimes = null;
    this.video = null;         // VideoCameraSource while on WebRTC
    this.jpeg = null;          // JpegCameraSource once fallen back
    this.pc = null;
    this.path = "";            // "WebRTC", "JPEG", or "" while negotiating
    this.route = "";           // how the WebRTC media travel: "direct", "TURN relay (udp)"... (mediaRoute)
    this.codecOption = codec;
    this.codecChoice = null;   // {codec, why}: what the page asks for first (chooseVideoCodec)
    this.codec = "";           // what the server sends the video in: "H264", "VP8" ("" off WebRTC)
    this.iceErrors = null;     // the TURN relays' refusals on the newest peer connection (IceErrors)
    this.audioViaWebRtc = false;
    this.generation = 0;       // counts rosbridge connections: a negotiation of an older one is dropped
    this.unlocked = false;
    this.placement = placementMode();  // "capture" or "newest" (placementPose)
    this.rtpPoses = new CapturePoses(rtpSeconds);  // WebRTC frames' capture poses by RTP timestamp
    this.placed = null;        // what placementPose gave last: {key, yaw, pitch, by: "capture" | "nearest" | "newest"}
    this.trace = null;         // an array to fill with every placement (the bench sets it)
    this.forced = mode === "jpeg" ? "#camera=jpeg" : webRtcMissing();
    for (const type of ["pointerdown", "keydown"]) window.addEventListener(type, () => this.unmute(), true);
  }

  get source() {
    return this.path === "JPEG" ? this.jpeg : this.path === "WebRTC" ? this.video : null;
  }

  get texture() {
    const s = this.source;
    if (s === this.video && s && s.received === 0) return this.placeholder;  // no frame decoded yet
    return s ? s.texture : this.placeholder;
  }

  /** The road the shown frames take, for the HUD: "WebRTC, H.264", "WebRTC, VP8", "JPEG" ("" while negotiating). */
  get road() {
    return this.path === "WebRTC" && this.codec ? `WebRTC, ${CODEC_NAMES[this.codec] ?? this.codec}` : this.path;
  }

  get aspect() { return this.source?.aspect ?? 4 / 3; }
  get size() { return this.source?.size ?? null; }  // the shown frames' pixels, once one is shown
  get uploaded() { return this.source?.uploaded ?? 0; }
  get ages() { return this.source?.ages ?? []; }
  frameAge() { return this.source ? this.source.frameAge() : null; }
  stats() { return {path: this.path, ...(this.source?.stats() ?? {received: 0, replaced: 0, uploaded: 0})}; }

  connected() {
    this.generation += 1;
    this.clock.sync().catch(() => {});  // a server without the clock service: its stamps taken as ours
    if (this.path === "JPEG") return;   // the rosbridge client subscribes again by itself
    if (this.forced) {
      this.useJpeg(this.forced === "#camera=jpeg" ? "" : `camera: ${this.forced}; showing the JPEG topic`);
      return;
    }
    this.startWebRtc(this.generation);
  }

  async startWebRtc(generation) {
    this.closePeer();
    const ice = await fetchIceServers(this.ros);  // fresh TURN credentials for every peer connection
    if (!this.codecChoice) {
      this.codecChoice = await chooseVideoCodec({option: this.codecOption});
      if (this.codecOption.problem) this.onMessage(`camera: ${this.codecOption.problem}`, "warning");
    }
    if (generation !== this.generation) return;
    const videoCodec = this.codecChoice.codec;
    const pc = this.pc = createPeerConnection({video: true, audio: true, iceServers: ice.iceServers, videoCodec});
    const iceErrors = this.iceErrors = new IceErrors(pc, (text) => this.onMessage(`camera: ${text}`, "error"),
                                                   ice.expires);
    const stream = new MediaStream();
    pc.addEventListener("track", (event) => stream.addTrack(event.track));
    try {
      const posesChannel = pc.createDataChannel(CAPTURE_POSES_CHANNEL, {ordered: false, maxRetransmits: 0});
      posesChannel.onmessage = (event) => this.capturePoseMessage(event.data);
      this.prepare?.(pc);
      const sends = await negotiate(this.ros, pc, {videoCodec});
      if (this.pc !== pc || generation !== this.generation) { pc.close(); return; }  // a newer connection's turn
      if (!sends.video && sends.message) {  // the video section alone was rejected: the rest (prepare's) stays up
        this.useJpeg(`camera: WebRTC refused (${sends.message}); showing the JPEG topic`, {keepPeer: true});
        return;
      }
      if (!sends.video) throw new MediaError("the server sends no video (it has no camera)");
      if (!this.renderTimes) this.renderTimes = new RenderTimes(this.ros);
      if (!this.video) this.video = new VideoCameraSource(this.renderTimes, this.clock, this.rtpPoses);
      this.video.attach(stream);
      if (this.unlocked) this.unmute();
      this.codec = sends.videoCodec;
      this.path = "WebRTC";
      this.setAudio(sends.audio);
      pc.addEventListener("connectionstatechange", () => this.stateChanged(pc, generation));
      this.route = (await mediaRoute(pc).catch(() => ({route: ""}))).route;
      const asked = this.codec && this.codec !== videoCodec ? ` (${CODEC_NAMES[videoCodec]} asked: ` +
        `${this.codecChoice.why}; the server sends ${CODEC_NAMES[this.codec] ?? this.codec})` : "";
      this.onMessage(`camera: WebRTC video${sends.audio ? " and the robot's audio" : ""}` +
                     (this.route ? `, ${this.route}` : "") + asked, this.codec && asked ? "warning" : "ok");
    } catch (err) {
      if (this.pc === pc) this.closePeer();
      else pc.close();
      if (generation !== this.generation || !this.ros.connected) return;  // the next connection negotiates
      const why = err instanceof MediaError && err.refused ? "refused" : "failed";
      // Why a connection could not be made, when the relay says or there is none to take
      const relay = iceErrors.summary() || (hasTurn(ice.iceServers) ? "" : "no TURN relay configured on the server " +
        `(${ice.message || "direct paths only"}), which a NAT or a firewall blocking UDP needs`);
      const because = relay && (why === "failed" || iceErrors.errors.length) ? `; ${relay}` : "";
      this.useJpeg(`camera: WebRTC ${why} (${err.message}${because}); showing the JPEG topic`);
    }
  }

  capturePoseMessage(data) {
    let msg;
    try { msg = JSON.parse(data); } catch { return; }
    if (Number.isInteger(msg?.rtp_timestamp)) this.rtpPoses.add(msg.rtp_timestamp, msg);
  }

  /** The capture pose of the frame the next render shows, or null when not known. */
  capturePose() {
    return this.source?.shownPose?.().pose ?? null;
  }

  /** The head pose ({yaw, pitch}, degrees) to hang the panel by: the shown frame's capture pose, else the nearest
   * frame's (NEAREST_S), else `newest` (the newest joint state's); with placement "newest", always `newest`. */
  placementPose(newest) {
    const source = this.source;
    const {key = null, pose = null} = source?.shownPose?.() ?? {};
    let by = "newest", use = newest;
    if (this.placement === "capture") {
      const near = pose ? null : source?.poses?.nearest(key);
      if (pose) { by = "capture"; use = pose; }
      else if (near) { by = "nearest"; use = near; }
    }
    this.placed = {key, yaw: use.yaw, pitch: use.pitch, by};
    if (this.trace) {
      this.trace.push({t: performance.now(), key, yaw: use.yaw, pitch: use.pitch, by, mode: this.placement,
                       path: this.path});
      if (this.trace.length > TRACE_KEPT) this.trace.splice(0, this.trace.length - TRACE_KEPT);
    }
    return use;
  }

  stateChanged(pc, generation) {
    if (pc !== this.pc || !["failed", "closed"].includes(pc.connectionState)) return;
    if (generation !== this.generation || !this.ros.connected) {  // went with the rosbridge connection
      this.closePeer();
      return;
    }
    this.useJpeg(`camera: the WebRTC connection ${pc.connectionState}; showing the JPEG topic`);
  }

  useJpeg(reason, {keepPeer = false} = {}) {
    if (!keepPeer) this.closePeer();
    this.setAudio(false);
    this.video?.dispose();
    this.video = null;
    this.codec = "";
    this.path = "JPEG";
    if (!this.jpeg) {
      this.jpeg = new JpegCameraSource(this.ros, {onError: (text) => this.onMessage(text, "error"),
                                                  placeholder: this.placeholderImage, clock: this.clock});
    }
    if (reason) this.onMessage(reason, "warning");
  }

  closePeer() {
    const pc = this.pc;
    this.pc = null;
    pc?.close();
  }

  setAudio(on) {
    if (on === this.audioViaWebRtc) return;
    this.audioViaWebRtc = on;
    this.onAudio(on);
  }

  /** After a user gesture the video may play sound: the robot's audio, when it came over WebRTC. */
  unmute() {
    this.unlocked = true;
    if (!this.video) return;
    this.video.video.muted = false;
    this.video.video.play().catch(() => {});
  }

  /** The open peer connection (null on JPEG or while negotiating): for stats, and for what prepare() added. */
  get peerConnection() {
    return this.path === "WebRTC" ? this.pc : null;
  }
}
