// Sound both ways. The robot's speech (/vr_teleop/audio/robot, PCM chunks in the format of the latched /info
// topic) is played with WebAudio, each chunk scheduled right after the previous one (unless it comes over WebRTC:
// camera.js). The operator's microphone (getUserMedia, asked for on the first push-to-talk) goes out while
// push-to-talk is held, by one of two roads:
//  - WebRTC (issue 20): an Opus track on the camera's peer connection. The server takes one peer connection per
//    rosbridge connection, so the voice's place is made before the offer (`prepare(pc)`: the audio transceiver
//    becomes sendrecv, with no track yet) and the microphone is put on it and taken off with replaceTrack: no
//    renegotiation, nothing sent while not talking, and the permission prompt comes with the first press, not
//    with the page;
//  - rosbridge, the fallback (no peer connection, or the server does not take our audio): an AudioWorklet cuts
//    PCM S16LE chunks that go to /vr_teleop/audio/operator.
// Without a microphone (refused, none, or a page that is not a secure context) push-to-talk is off, and `status`
// says so for the HUD.

import * as names from "../names.js";
const ROBOT_TOPIC = names.ROBOT_AUDIO_TOPIC;
const OPERATOR_TOPIC = names.OPERATOR_AUDIO_TOPIC;
const CHUNK_S = 0.1;
const START_LEAD_S = 0.08;  // a first chunk starts this far ahead, so the next one is there in time

export function base64ToBytes(text) {
  if (typeof Uint8Array.fromBase64 === "function") return Uint8Array.fromBase64(text);
  const raw = atob(text);
  const bytes = new Uint8Array(raw.length);
  for (let i = 0; i < raw.length; i++) bytes[i] = raw.charCodeAt(i);
  return bytes;
}

export function bytesToBase64(bytes) {
  if (typeof bytes.toBase64 === "function") return bytes.toBase64();
  let text = "";
  for (let i = 0; i < bytes.length; i += 0x8000) text += String.fromCharCode(...bytes.subarray(i, i + 0x8000));
  return btoa(text);
}

export class Audio {
  constructor(ros, {onError = () => {}} = {}) {
    this.ros = ros;
    this.onError = onError;
    this.context = null;
    this.format = {sampleRate: 22050, channels: 1, bytes: 2};
    this.nextTime = 0;
    this.played = 0;
    this.talking = false;
    this.mic = null;          // {stream, node, track} once granted
    this.micState = "off";    // off, asking, ready, denied
    this.sentChunks = 0;      // chunks published on the topic (the rosbridge road)
    this.pc = null;           // the newest peer connection (prepare) and its audio transceiver
    this.transceiver = null;
    this.rtcError = "";
    this.topicMuted = false;  // the robot's audio comes over WebRTC (camera.js): its topic's chunks are not played
    ros.subscribe(`${ROBOT_TOPIC}/info`, "audio_common_msgs/AudioInfo", (info) => this.setFormat(info));
    ros.subscribe(ROBOT_TOPIC, "audio_common_msgs/AudioData", (msg) => this.play(msg));
    ros.advertise(OPERATOR_TOPIC, "audio_common_msgs/AudioData");
    ros.advertise(`${OPERATOR_TOPIC}/info`, "audio_common_msgs/AudioInfo");
  }

  /** WebAudio starts only after a user gesture: call from a click or key handler. */
  unlock() {
    if (!this.context) {
      try {
        this.context = new AudioContext();
      } catch (err) {
        this.onError(`sound cannot play: ${err.message}`);
        return;
      }
    }
    if (this.context.state === "suspended") this.context.resume().catch(() => {});
  }

  setFormat(info) {
    const format = String(info.sample_format || "S16LE").toUpperCase();
    if (format !== "S16LE" || !(info.channels >= 1) || !(info.sample_rate > 0)) {
      this.onError(`the robot's audio is ${format}, ${info.channels} channel(s), ${info.sample_rate} Hz: ` +
                   "only PCM S16LE can be played");
      this.format = null;
      return;
    }
    this.format = {sampleRate: info.sample_rate, channels: info.channels, bytes: 2};
  }

  play(msg) {
    if (this.topicMuted) return;  // heard over WebRTC instead
    if (!this.format || !this.context || this.context.state !== "running") return;  // nobody to hear it yet
    const bytes = base64ToBytes(msg.data);
    const {channels, sampleRate} = this.format;
    const frames = Math.floor(bytes.byteLength / (2 * channels));
    if (frames === 0) return;
    const samples = new Int16Array(bytes.buffer, bytes.byteOffset, frames * channels);
    const buffer = this.context.createBuffer(channels, frames, sampleRate);
    for (let c = 0; c < channels; c++) {
      const out = buffer.getChannelData(c);
      for (let i = 0; i < frames; i++) out[i] = samples[i * channels + c] / 32768;
    }
    const source = this.context.createBufferSource();
    source.buffer = buffer;
    source.connect(this.context.destination);
    const now = this.context.currentTime;
    if (this.nextTime < now) this.nextTime = now + START_LEAD_S;  // a new utterance, or we fell behind
    source.start(this.nextTime);
    this.nextTime += buffer.duration;
    this.played += 1;
  }

  /** Before each offer (CameraFeed's prepare hook): the peer connection's audio may carry our voice. */
  prepare(pc) {
    const transceiver = pc.getTransceivers().find((t) => t.receiver.track?.kind === "audio");
    if (!transceiver) return;
    transceiver.direction = "sendrecv";
    this.pc = pc;
    this.transceiver = transceiver;
    this.rtcError = "";
    pc.addEventListener("connectionstatechange", () => this.route());
  }

  /** The sender our voice goes out on, or null: the peer connection is up and the server takes our audio. */
  voiceSender() {
    const t = this.transceiver;
    if (!t || this.rtcError || this.pc.connectionState !== "connected") return null;
    return ["sendrecv", "sendonly"].includes(t.currentDirection) ? t.sender : null;
  }

  /** "WebRTC" or "rosbridge": the road the voice takes now. */
  get path() {
    return this.voiceSender() ? "WebRTC" : "rosbridge";
  }

  /** The microphone on the peer connection while talking, off it otherwise. */
  route() {
    const sender = this.voiceSender();
    const track = this.talking && this.mic ? this.mic.track : null;
    if (!sender || sender.track === track) return;
    sender.replaceTrack(track).catch((err) => {
      this.rtcError = err.message;
      this.onError(`the voice cannot go over WebRTC (${err.message}); it goes over rosbridge`);
    });
  }

  /** For the HUD: how push-to-talk stands. */
  get status() {
    if (this.micState === "denied") return "voice OFF (no microphone)";
    return this.talking ? `TALKING (${this.path})` : "";
  }

  /** Push-to-talk pressed (true) or released (false). The first press asks for the microphone. */
  async talk(on) {
    this.talking = on;
    this.route();
    if (!on || this.mic || this.micState === "asking") return;
    if (this.micState === "denied") {
      this.onError("the microphone was denied: allow it in the browser's site settings, then reload");
      return;
    }
    this.unlock();
    this.micState = "asking";
    try {
      if (!navigator.mediaDevices?.getUserMedia) throw new Error("this page is not a secure context (use https)");
      const stream = await navigator.mediaDevices.getUserMedia(
        {audio: {channelCount: 1, echoCancellation: true, noiseSuppression: true}});
      await this.context.audioWorklet.addModule(new URL("./mic_worklet.js", import.meta.url));
      const source = this.context.createMediaStreamSource(stream);
      const node = new AudioWorkletNode(this.context, "mic-chunker",
        {processorOptions: {chunkSamples: Math.round(this.context.sampleRate * CHUNK_S)}});
      node.port.onmessage = (event) => this.chunk(event.data);
      source.connect(node);
      this.mic = {stream, node, track: stream.getAudioTracks()[0]};
      this.micState = "ready";
      this.sendInfo();
      this.route();  // still held: on the peer connection from now
    } catch (err) {
      this.micState = "denied";
      this.talking = false;
      const why = err.name === "NotAllowedError" ? "refused (allow it in the site settings, then reload)"
        : err.name === "NotFoundError" ? "none found" : err.message;
      this.onError(`microphone: ${why}; push-to-talk is off`);
    }
  }

  /** The format of our chunks: sent again on every connection, before the first chunk. */
  sendInfo() {
    if (!this.mic) return;
    const rate = Math.round(this.context.sampleRate);
    this.ros.publish(`${OPERATOR_TOPIC}/info`, {channels: 1, sample_rate: rate, sample_format: "S16LE",
                                                bitrate: rate * 16, coding_format: "pcm"});
  }

  chunk(buffer) {
    if (!this.talking || this.voiceSender()) return;  // over WebRTC, not twice
    if (this.ros.publish(OPERATOR_TOPIC, {data: bytesToBase64(new Uint8Array(buffer))})) this.sentChunks += 1;
  }
}
