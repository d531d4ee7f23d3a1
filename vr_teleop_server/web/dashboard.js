// The supervisor's dashboard. It speaks rosbridge v2 to the server that serves it, like any other client:
// subscriptions, service calls and publishes, with no private back door. Token: the page's #token=... fragment.

import * as names from "./names.js";
import {connect} from "./rosbridge.js";
import {CODEC_NAMES, IceErrors, RenderTimes, ServerClock, cameraMode, chooseVideoCodec, codecOption,
        createPeerConnection, fetchIceServers, hasTurn, mediaRoute, negotiate, onVideoFrames,
        webRtcMissing} from "./webrtc.js";
import {AutonomyModel, attentionInImage, attentionText, outcomeText} from "./autonomy.js";
import {language, t, translateMenus, translatePage} from "./i18n.js";
import {Trends, dialogChoices, drawDialog, drawHardware, drawMotivation, drawMotors, motivationStep}
  from "./status_panels.js";

const $ = (id) => document.getElementById(id);
const el = (tag, props = {}, ...children) => {
  const node = Object.assign(document.createElement(tag), props);
  children.forEach(c => node.append(c));
  return node;
};
const token = new URLSearchParams(location.hash.slice(1)).get("token");
const scheme = location.protocol === "https:" ? "wss" : "ws";
const ros = connect(`${scheme}://${location.host}/`, {token, idPrefix: "dashboard"});
window.dashboard = {ros, frames: 0};

function logLine(list, text, level = "info") {
  const item = el("li", {className: level, textContent: `${new Date().toLocaleTimeString()}  ${text}`});
  list.prepend(item);
  while (list.children.length > 200) list.lastChild.remove();
}

translatePage();
function setup() {
  $("role").textContent = token ? t("role.token") : t("role.open");
  $("connection").textContent = t("connection.connected");
  $("connection").className = "badge on";
}
ros.onopen = () => { setup(); startCamera(); };  // a new connection has no peer connection: negotiate again
ros.onclose = () => {
  $("connection").textContent = t("connection.disconnected");
  $("connection").className = "badge off";
};
ros.onstatus = (msg) => {
  logLine($("events"), `server: ${msg.msg}`, msg.level);
  if (/\/study\/|\/decision\/|label/.test(msg.msg)) logLine($("labels"), msg.msg, msg.level);  // where it was asked
};

// ---- camera -----------------------------------------------------------------------------------------------------
// WebRTC first (video like a call, negotiated through /vr_teleop/media/offer on this connection); the JPEG topic
// when negotiation fails or the peer connection does not come up. #camera=jpeg in the URL forces the JPEG topic.
// Frame age: JPEG frames carry their render time in the header stamp; WebRTC frames find theirs by RTP timestamp
// (requestVideoFrameCallback) in the telemetry's mapping. Signalling, the clock and the mapping: webrtc.js, shared
// with the operator page.
const camera = {path: "", pc: null, jpeg: false, ages: [], mode: cameraMode(), codec: "", codecChoice: null,
                // like for like, for bench/media.py: each frame's age when decoded (WebRTC: the last packet's
                // receipt plus the decoder's processing, from requestVideoFrameCallback; JPEG: img.decode()) and
                // when handed to the compositor (WebRTC: presentationTime; JPEG: the next animation frame)
                decodedAges: [], paintedAges: []};
Object.assign(window.dashboard, {camera, videoFrames: 0});
const clock = new ServerClock(ros);
let renderTimes = null;
function keep(list, age) {
  list.push(age);
  if (list.length > 600) list.shift();
}
function showAge(age) {
  keep(camera.ages, age);
  const road = camera.path === "WebRTC" && camera.codec ? `WebRTC, ${CODEC_NAMES[camera.codec] ?? camera.codec}`
    : camera.path;
  $("camera-age").textContent = `frame age ${Math.max(0, age).toFixed(3)} s (${road})`;
}
setInterval(() => clock.sync().catch(() => {}), 30000);
function useJpeg(reason) {
  if (camera.pc) { camera.pc.close(); camera.pc = null; }
  $("camera-video").hidden = true;
  $("camera").hidden = false;
  camera.path = "JPEG";
  if (reason) logLine($("events"), `camera: WebRTC unavailable (${reason}); showing the JPEG topic`, "warning");
  if (camera.jpeg) return;
  camera.jpeg = true;
  ros.subscribe(names.CAMERA_TOPIC, "sensor_msgs/CompressedImage", (msg) => {
    if (camera.path !== "JPEG") return;
    const s = msg.header.stamp;
    const frame = {seq: msg.header.seq, src: `data:image/jpeg;base64,${msg.data}`,
                   rendered: (s.secs ?? s.sec) + (s.nsecs ?? s.nanosec) / 1e9};
    recentFrames.set(frame.seq, frame);
    camera.newest = frame.seq;
    if (recentFrames.size > RECENT_FRAMES) recentFrames.delete(recentFrames.keys().next().value);
    window.dashboard.frames += 1;
    showFrame(attendedFrame() ?? frame);
  }, {throttle_rate: 0, queue_length: 1});
}
// The attention box and the picture come from the same capture: the JPEG frames of the last few seconds are kept
// by header.seq, and while the robot attends to a face the view shows the frame its box was found in (the
// AttentionTarget's frame_seq, republished at each detection), the box over it; otherwise the newest frame.
const RECENT_FRAMES = 90;  // at 30 fps, three seconds: longer than a face search takes on a busy machine
const recentFrames = new Map();  // seq -> {seq, src, rendered}, oldest first
camera.shown = null;  // the frame the view shows (or is decoding): {seq, src, rendered}
camera.painted = null;  // the seq of the frame the view shows, once decoded
function attendedFrame() {
  const a = autonomy.attention;
  return a?.source && a.has_face && a.frame_seq ? recentFrames.get(a.frame_seq) ?? null : null;
}
function showFrame(frame) {
  if (camera.shown?.seq === frame.seq) return;
  camera.shown = frame;
  const img = $("camera");
  img.src = frame.src;
  img.decode().then(() => {
    if (camera.shown !== frame) return;  // a newer one came while this one decoded
    camera.painted = frame.seq;
    const age = clock.now() - frame.rendered;
    showAge(age);
    if (frame.seq === camera.newest) {  // the transport's figures (bench/media.py): a frame held for its box is not
      keep(camera.decodedAges, age);
      requestAnimationFrame(() => keep(camera.paintedAges, clock.now() - frame.rendered));
    }
    markAttention();  // the box for this frame, or none
  }, () => {});
}
function onVideoFrame(now, meta) {
  window.dashboard.videoFrames += 1;
  window.dashboard.frames += 1;
  if (meta.rtpTimestamp === undefined) return;
  camera.lastRtp = meta.rtpTimestamp;
  renderTimes.saw(meta.rtpTimestamp);
  // presentationTime: the frame handed to the compositor (as the JPEG path's decode, before the next vsync)
  const shown = (performance.timeOrigin + (meta.presentationTime ?? now)) / 1000 + clock.offset;
  const decoded = meta.receiveTime === undefined || meta.processingDuration === undefined ? null
    : (performance.timeOrigin + meta.receiveTime) / 1000 + meta.processingDuration + clock.offset;
  renderTimes.whenKnown(meta.rtpTimestamp, (rendered) => {
    showAge(shown - rendered);
    keep(camera.paintedAges, shown - rendered);
    if (decoded !== null) keep(camera.decodedAges, decoded - rendered);
  });
}
async function useWebRtc() {
  const ice = await fetchIceServers(ros);  // fresh TURN credentials for every peer connection
  // H.264 first where this browser decodes it in hardware, VP8 otherwise; #codec=h264|vp8 forces one (webrtc.js)
  const option = codecOption();
  if (option.problem) logLine($("events"), `camera: ${option.problem}`, "warning");
  camera.codecChoice ??= await chooseVideoCodec({option});
  const videoCodec = camera.codecChoice.codec;
  const pc = camera.pc = createPeerConnection({video: true, audio: true, iceServers: ice.iceServers,  // audio: click
                                               videoCodec});                            // the video to hear it
  const iceErrors = camera.iceErrors = new IceErrors(pc, (text) => logLine($("events"), `camera: ${text}`, "danger"),
                                                     ice.expires);
  const stream = new MediaStream();
  const video = $("camera-video");
  pc.ontrack = (event) => { stream.addTrack(event.track); video.srcObject = stream; };
  try {
    camera.codec = (await negotiate(ros, pc, {videoCodec})).videoCodec;
  } catch (err) {
    const relay = iceErrors.summary() || (hasTurn(ice.iceServers) ? "" : "no TURN relay configured on the server");
    throw new Error(relay && !err.refused ? `${err.message}; ${relay}` : err.message);
  }
  camera.route = (await mediaRoute(pc).catch(() => ({route: ""}))).route;
  if (camera.route) logLine($("events"), `camera: WebRTC, ${camera.route}`);
  if (!renderTimes) {
    renderTimes = new RenderTimes(ros);
    onVideoFrames(video, onVideoFrame);
  }
  pc.addEventListener("connectionstatechange", () => {
    if (camera.pc === pc && ["failed", "closed"].includes(pc.connectionState)) useJpeg(`peer connection ${pc.connectionState}`);
  });
  camera.path = "WebRTC";
  $("camera").hidden = true;
  video.hidden = false;
  video.onclick = () => { video.muted = !video.muted; };
  video.play().catch(() => {});
}
async function startCamera() {
  clock.sync().catch(() => {});
  if (camera.mode === "jpeg" || webRtcMissing()) return useJpeg(camera.mode === "jpeg" ? "" : webRtcMissing());
  if (camera.pc) { camera.pc.close(); camera.pc = null; }
  try { await useWebRtc(); } catch (err) { useJpeg(err.message); }
}
setInterval(() => {
  if (camera.path === "JPEG" && !camera.ages.length) $("camera-age").textContent = "JPEG, no frames yet";
}, 1000);

// ---- joints -----------------------------------------------------------------------------------------------------
const gauges = new Map();
let clamped = new Set();
function gauge(container, name, lower, upper) {
  const mark = el("div", {className: "mark"});
  const value = el("span", {className: "value", textContent: "–"});
  const row = el("div", {className: "gauge", title: `${lower} … ${upper}`},
    el("span", {className: "name", textContent: name}), el("div", {className: "bar"}, mark), value);
  row.dataset.name = name;
  container.append(row);
  return {row, mark, value, lower, upper,
    set(v) {
      this.mark.style.left = `${Math.min(100, Math.max(0, 100 * (v - lower) / (upper - lower)))}%`;
      this.value.textContent = v.toFixed(1);
    }};
}
ros.subscribe(names.DESCRIPTION_TOPIC, "std_msgs/String", (msg) => {
  const description = JSON.parse(msg.data);
  $("gauges").replaceChildren();
  gauges.clear();
  for (const j of description.joints) gauges.set(j.name, gauge($("gauges"), j.name, j.lower, j.upper));
});
ros.subscribe(names.JOINT_STATE_TOPIC, "sensor_msgs/JointState", (msg) => {
  msg.name.forEach((name, i) => gauges.get(name)?.set(msg.position[i]));
}, {throttle_rate: 100, queue_length: 1});

// ---- teleoperation --------------------------------------------------------------------------------------------------
ros.subscribe(names.TELEOP_STATE_TOPIC, "vr_teleop_msgs/TeleopState", (s) => {
  $("teleop-state").textContent = s.engaged ? `${s.state} (engaged)` : s.state;
  $("teleop-state").className = ["stalled", "estopped", "robot_lost", "disconnected"].includes(s.state) ? "danger" : "";
  $("teleop-holder").textContent = s.holder || "nobody";
  const parts = [s.head_following && "head", s.left_arm_following && "left arm", s.right_arm_following && "right arm"];
  $("teleop-following").textContent = parts.filter(Boolean).join(", ") || "nothing";
  $("teleop-age").textContent = s.pose_age < 0 ? "no poses" : `${(s.pose_age * 1000).toFixed(0)} ms`;
  $("teleop-robot").textContent = s.robot_connected ? "connected" : "DISCONNECTED";
  clamped = new Set(s.clamped);
  for (const [name, g] of gauges) g.row.classList.toggle("clamped", clamped.has(name));
}, {throttle_rate: 100, queue_length: 1});
// The holding operator's link: the worst of its connections' telemetry entries (only the holder's carry a watchdog
// threshold).
const QUALITY_RANK = {"": 0, good: 1, degraded: 2, poor: 3};
ros.subscribe(names.TELEMETRY_TOPIC, "vr_teleop_msgs/Telemetry", (t) => {
  const holding = (t.clients || []).filter((c) => c.watchdog_threshold >= 0);
  const worst = holding.sort((a, b) => QUALITY_RANK[b.link_quality] - QUALITY_RANK[a.link_quality])[0];
  const link = $("teleop-link");
  if (!worst) {
    link.textContent = "–";
    link.className = "";
    return;
  }
  const rtt = worst.ws_rtt >= 0 ? `, round trip ${(worst.ws_rtt * 1000).toFixed(0)} ms` : "";
  link.textContent = `${worst.link_quality || "measuring"}${worst.link_warning ? ": " + worst.link_warning : rtt}`;
  link.className = {poor: "danger", degraded: "warning"}[worst.link_quality] || "";
});
ros.subscribe(names.CLAMP_TOPIC, "vr_teleop_msgs/Clamp", (c) => {
  for (const name of c.joints) {
    const g = gauges.get(name);
    if (!g) continue;
    g.row.classList.add("clamped");
    setTimeout(() => { if (!clamped.has(name)) g.row.classList.remove("clamped"); }, 1500);
  }
});

// ---- status and motivation ------------------------------------------------------------------------------------------
ros.subscribe(names.HARDWARE_STATUS_TOPIC, "vr_teleop_msgs/HardwareStatus", (h) => {
  panels.hardware = h;
  drawHardware($("hardware-panel"), panels.robotHardware, h, t, "");
  const rows = [["CPU", `${h.cpu_percent.toFixed(0)} %`], ["memory", `${h.memory_percent.toFixed(0)} %`],
                ["load", h.load_1min.toFixed(2)]];
  if (h.has_temperature) rows.push(["temperature", `${h.temperature_c.toFixed(0)} °C`]);
  $("status").replaceChildren(...rows.flatMap(([k, v]) => [el("dt", {textContent: k}), el("dd", {textContent: v})]));
});
// The headset's status panels (status_panels.js), both shown, live at their topics' rate; the motivation
// variables raised and lowered by a tenth of their range with the buttons under the panel (a supervisor's right).
const trends = new Trends();
const panels = {motors: null, motivation: null, robotHardware: null, hardware: null,
                dialog: {choices: {sentences: [], faces: []}, choice: {sentence: 0, face: 0}, result: null}};
ros.subscribe(names.ROBOT_HARDWARE_STATUS_TOPIC, "vr_teleop_msgs/RobotHardwareStatus", (m) => {
  panels.robotHardware = m;
  drawHardware($("hardware-panel"), m, panels.hardware, t, "");
});
ros.subscribe(names.MOTORS_STATUS_TOPIC, "vr_teleop_msgs/MotorsStatus", (m) => {
  panels.motors = m;
  drawMotors($("motors-panel"), m, clamped, t, "");
});
ros.subscribe(names.MOTIVATION_STATUS_TOPIC, "vr_teleop_msgs/Motivation", (m) => {
  panels.motivation = m;
  trends.add(m, performance.now());
  drawMotivation($("motivation-panel"), m, trends, -1, t, "");
  const controls = $("motivation-controls");
  if (controls.dataset.names === m.name.join(",")) return;
  controls.dataset.names = m.name.join(",");
  controls.replaceChildren(...m.name.flatMap((name) => [
    el("span", {textContent: name}),
    ...[-1, 1].map((sign) => el("button", {
      textContent: sign < 0 ? `− ${t("panel.lower")}` : `+ ${t("panel.raise")}`,
      className: sign < 0 ? "lower" : "raise",
      onclick: () => {
        const now = panels.motivation, i = now.name.indexOf(name);
        ros.call(names.MOTIVATION_INCREMENT_SERVICE, {name, value: sign * motivationStep(now, i)})
          .catch((err) => logLine($("events"), `${name}: ${err.message}`, "error"));
      }})),
  ]));
});
// The dialog panel: a sentence and a face chosen in the two lists under it, said and shown together by the button
// (the speech and emotion menus' own items, as the headset's panel runs them).
function drawDialogPanel() {
  const d = panels.dialog;
  drawDialog($("dialog-panel"), d.choices, d.choice, d.result, t, "");
}
function fillDialogControls(choices) {
  panels.dialog.choices = choices;
  const old = panels.dialog.choice, keep = (list, i) => Math.min(i, Math.max(0, list.length - 1));
  panels.dialog.choice = {sentence: keep(choices.sentences, old.sentence), face: keep(choices.faces, old.face)};
  for (const [id, list, key] of [["dialog-sentence", choices.sentences, "sentence"],
                                 ["dialog-face", choices.faces, "face"]]) {
    $(id).replaceChildren(...list.map((c, i) => el("option", {value: String(i), textContent: c.label})));
    $(id).value = String(panels.dialog.choice[key]);
  }
  drawDialogPanel();
}
for (const [id, key] of [["dialog-sentence", "sentence"], ["dialog-face", "face"]]) {
  $(id).onchange = (event) => {
    panels.dialog.choice = {...panels.dialog.choice, [key]: Number(event.target.value)};
    drawDialogPanel();
  };
}
$("dialog-say").onclick = async () => {
  const {choices, choice} = panels.dialog;
  const sentence = choices.sentences[choice.sentence], face = choices.faces[choice.face];
  if (!sentence || !face) return;
  panels.dialog.result = {text: t("panel.dialog_sent", {face: face.label}), level: "ok"};
  drawDialogPanel();
  const results = await Promise.allSettled([face, sentence].map((item) =>
    ros.call(names.MENU_SELECT_SERVICE, {id: item.id, args: item.args})
      .then((r) => logLine($("events"), `${item.id}: ${r.message}`))));
  const refused = results.find((r) => r.status === "rejected");
  if (refused) {
    panels.dialog.result = {text: t("panel.dialog_failed", {reason: refused.reason.message}), level: "error"};
    logLine($("events"), refused.reason.message, "error");
    drawDialogPanel();
  }
};
Object.assign(window.dashboard, {panels});
ros.subscribe(names.EVENT_TOPIC, "vr_teleop_msgs/Event", (e) => {
  logLine($("events"), `${e.source}: ${e.kind}${e.detail ? " " + e.detail : ""}`, e.level);
});

// ---- Wizard-of-Oz buttons, from the same menu data as the headset's --------------------------------------------
function select(id, args = "") {
  return ros.call(names.MENU_SELECT_SERVICE, {id, args})
    .then((r) => logLine($("events"), `${id}: ${r.message}`))
    .catch((err) => logLine($("events"), `${id}: ${err.message}`, "error"));
}
function canonicalArgs(args) {
  if (!args) return "{}";
  const parsed = JSON.parse(args);
  return JSON.stringify(Object.keys(parsed).sort().map((k) => [k, parsed[k]]));
}
ros.subscribe(names.MENUS_TOPIC, "vr_teleop_msgs/Menus", (message) => {
  const m = translateMenus(message);  // the labels in the page's language (i18n.js)
  fillDialogControls(dialogChoices(m.items));
  const byParent = new Map();
  for (const item of m.items) {
    if (!byParent.has(item.parent)) byParent.set(item.parent, []);
    byParent.get(item.parent).push(item);
  }
  // The headset's menus repeat some commands (the quick emotions, then every emotion in a list): the dashboard
  // shows one button per command and arguments, the first met (so the quick ones come first).
  const shown = new Set();
  const sections = [];
  for (const menu of m.menus) {
    const buttons = el("div", {className: "buttons"});
    const walk = (parent) => (byParent.get(parent) || []).forEach((item) => {
      const key = item.command && `${item.command} ${canonicalArgs(item.args)}`;
      if (item.command && !shown.has(key)) {
        shown.add(key);
        const b = el("button", {textContent: item.label, title: item.id});
        b.dataset.item = item.id;
        b.onclick = () => select(item.id);
        buttons.append(b);
      }
      walk(item.id);
    });
    walk(menu.id);
    sections.push(el("div", {className: "menu"}, el("h3", {textContent: menu.label}), buttons));
  }
  $("menus").replaceChildren(...sections);
});
// Free text is no menu item: it goes to the speech service as it is, and the recording holds it as said text,
// never under a sentence's id the teacher did not choose.
$("say-form").onsubmit = (event) => {
  event.preventDefault();
  const text = $("say-text").value.trim();
  $("say-text").value = "";
  if (!text) return;
  const quoted = JSON.stringify(text);
  ros.call(names.SPEECH_SAY_SERVICE, {message: text})
    .then((r) => logLine($("events"), r.status ? `said ${quoted}` : `stopped while saying ${quoted}`))
    .catch((err) => logLine($("events"), `say ${quoted}: ${err.message}`, "error"));
};

// ---- languages and voices from home -----------------------------------------------------------------------------
// The robot's language (/vr_teleop/speech/set_language, the one in force on its latched topic); this page's own
// language (#lang= in the address, kept with the token); the clip library: play, stop, delete and, for a
// supervisor, add (the file's bytes in /vr_teleop/clips/add; the server decodes and checks them and says why not).
$("page-language").value = language;
$("page-language").onchange = (event) => {
  const params = new URLSearchParams(location.hash.slice(1));
  params.set("lang", event.target.value);
  location.hash = params.toString();
  location.reload();  // the catalogue is read once, when the page loads
};
function clipResult(text, level = "info") {
  $("clip-result").textContent = text;
  $("clip-result").className = level === "error" ? "error-text" : "muted";
  logLine($("events"), text, level);
}
for (const button of document.querySelectorAll("#robot-languages [data-language]")) {
  button.onclick = () => ros.call(names.SPEECH_LANGUAGE_SERVICE, {language: button.dataset.language})
    .then((r) => logLine($("events"), r.message))
    .catch((err) => clipResult(err.message, "error"));
}
ros.subscribe(names.SPEECH_LANGUAGE_TOPIC, "std_msgs/String", (msg) => {
  for (const button of document.querySelectorAll("#robot-languages [data-language]")) {
    button.setAttribute("aria-pressed", String(button.dataset.language === msg.data));
  }
});
ros.subscribe(names.CLIPS_TOPIC, "vr_teleop_msgs/Clips", (library) => {
  $("clips-none").textContent = library.enabled ? t("voices.none") : t("voices.disabled");
  $("clips-none").hidden = library.clips.length > 0;
  $("clip-form").hidden = !library.enabled;
  $("clips").replaceChildren(...library.clips.map((clip) => {
    const play = el("button", {textContent: t("voices.play"), onclick: () =>
      ros.call(names.CLIP_PLAY_SERVICE, {name: clip.name}, 120_000)
        .then((r) => logLine($("events"), r.message)).catch((err) => clipResult(err.message, "error"))});
    play.dataset.clip = clip.name;
    play.setAttribute("aria-pressed", String(clip.name === library.playing));
    const remove = el("button", {textContent: t("voices.delete"), className: "danger", onclick: () =>
      ros.call(names.CLIP_REMOVE_SERVICE, {name: clip.name})
        .then((r) => clipResult(r.message)).catch((err) => clipResult(err.message, "error"))});
    return el("li", {}, el("strong", {textContent: clip.name}), " ",
              el("span", {className: "muted", textContent: t("voices.seconds", {seconds: clip.duration.toFixed(1)})}),
              " ", play, " ", remove);
  }));
});
function base64(bytes) {
  let binary = "";
  for (let i = 0; i < bytes.length; i += 0x8000) binary += String.fromCharCode(...bytes.subarray(i, i + 0x8000));
  return btoa(binary);
}
$("clip-form").onsubmit = async (event) => {
  event.preventDefault();
  const file = $("clip-file").files[0];
  if (!file) { clipResult(t("voices.choose_file"), "error"); return; }
  const name = $("clip-name").value.trim() || file.name.replace(/\.[^.]*$/, "").replace(/[^A-Za-z0-9_-]+/g, "_");
  const data = base64(new Uint8Array(await file.arrayBuffer()));
  ros.call(names.CLIP_ADD_SERVICE, {name, data}, 60_000)
    .then((r) => {
      clipResult(t("voices.added", {name, seconds: r.duration.toFixed(1)}));
      $("clip-form").reset();
    })
    .catch((err) => clipResult(t("voices.refused", {reason: err.message}), "error"));
};
$("clip-stop").onclick = () => ros.call(names.SPEECH_STOP_SERVICE)
  .then(() => logLine($("events"), t("voices.stop"))).catch((err) => clipResult(err.message, "error"));

// ---- emergency stop and control ---------------------------------------------------------------------------------
function estop() {
  ros.call(names.ESTOP_SERVICE)
    .then((r) => logLine($("events"), `EMERGENCY STOP: ${r.message}`, "danger"))
    .catch((err) => logLine($("events"), `e-stop refused: ${err.message}`, "error"));
}
$("estop").onclick = estop;
$("release").onclick = () => ros.call(names.ENGAGE_SERVICE, {data: false})
  .then((r) => logLine($("events"), r.message)).catch((err) => logLine($("events"), err.message, "error"));

// ---- autonomy: the level, the robot's proposal and its countdown, where it looks, how proposals ended ----------
// The model is ./autonomy.js, shared with the operator page. A spectator's decision is refused by the server: the
// refusal is shown under the card.
const CAMERA_HFOV_DEG = 80;  // the head camera's horizontal field of view, as the operator page's panel spans it
const robotHead = {yaw: 0, pitch: 0};
const autonomy = new AutonomyModel(ros, {onChange: () => showAutonomy()});
Object.assign(window.dashboard, {autonomy, robotHead});
function showAutonomy() {
  const m = autonomy;
  $("autonomy-level").textContent = m.level || "not offered by this server";
  for (const b of document.querySelectorAll("#autonomy [data-level]")) {
    b.classList.toggle("current", b.dataset.level === m.level);
    b.setAttribute("aria-checked", String(b.dataset.level === m.level));
  }
  const p = m.current();
  $("proposal-card").hidden = !p;
  $("proposal-none").hidden = !!p;
  if (p) {
    $("proposal-label").textContent = `${p.label || p.action}${p.others > 0 ? ` (+${p.others} more)` : ""}`;
    $("proposal-reason").textContent = p.reason ? `because ${p.reason}` : "(no reason given)";
    $("proposal-confidence").textContent = `${Math.round(100 * (p.confidence || 0))}% sure`;
    $("proposal-bar").style.width = `${(100 * p.fraction).toFixed(1)}%`;
    $("proposal-left").textContent = `${AutonomyModel.countdown(p)} unless rejected`;
  }
  $("autonomy-refusal").hidden = !m.refusal;
  $("autonomy-refusal").textContent = m.refusal?.text || "";
  const a = m.attention;
  $("autonomy-attention").textContent = a?.source
    ? `${attentionText(a)} · yaw ${a.yaw.toFixed(0)}°, pitch ${a.pitch.toFixed(0)}° · score ${a.score.toFixed(2)}` : "nobody";
  showRename(a);
  $("autonomy-running").textContent = m.running.length ? m.running.join(", ") : "nothing";
  $("autonomy-owners").textContent = m.owners.length ? m.owners.map((o) => `${o.part}: ${o.owner}`).join(", ") : "–";
  const fresh = m.outcomes.filter((o) => !o.logged);  // newest first: logged oldest first so the newest is on top
  for (const o of fresh.reverse()) {
    o.logged = true;
    const level = {rejected: "warning", forbidden: "warning", dropped: "warning"}[o.outcome] || "info";
    logLine($("outcomes"), outcomeText(o), level);
  }
  markAttention();
}
// The attention target over the camera picture: a box round the face, over the frame the face was found in (JPEG:
// recentFrames; WebRTC video cannot be held on a past frame, so there a face is marked by its direction, as a
// voice is), or a ring where it looks.
function markAttention() {
  const media = camera.path === "WebRTC" ? $("camera-video") : $("camera");
  const mark = $("attention-mark");
  let attention = autonomy.attention;
  if (attention?.has_face && media.tagName !== "VIDEO") {
    const frame = attendedFrame();
    if (frame && camera.painted !== frame.seq) { showFrame(frame); return; }  // marked once it is decoded
    if (!frame) attention = null;  // its frame is not here (yet, or any more): no box over another picture
  } else if (attention?.has_face) {
    attention = {...attention, has_face: false};
  }
  const image = media.tagName === "VIDEO" ? {width: media.videoWidth, height: media.videoHeight}
    : {width: media.naturalWidth, height: media.naturalHeight};
  const place = image.width ? attentionInImage(attention, robotHead, CAMERA_HFOV_DEG, image) : null;
  window.dashboard.attentionPlace = place && place.kind === "face" ? {...place, frameSeq: attention.frame_seq} : place;
  if (!place || (place.kind === "direction" && !place.inside)) { mark.hidden = true; return; }
  const box = media.getBoundingClientRect(), frame = media.parentElement.getBoundingClientRect();
  const scale = Math.min(box.width / image.width, box.height / image.height);  // object-fit: contain
  const left = box.left - frame.left + (box.width - image.width * scale) / 2;
  const top = box.top - frame.top + (box.height - image.height * scale) / 2;
  const w = image.width * scale, h = image.height * scale;
  mark.hidden = false;
  mark.className = place.kind;
  mark.firstChild.textContent = attentionText(attention);
  if (place.kind === "face") {
    Object.assign(mark.style, {left: `${left + place.box.u * w}px`, top: `${top + place.box.v * h}px`,
                               width: `${place.box.w * w}px`, height: `${place.box.h * h}px`});
  } else {
    Object.assign(mark.style, {left: `${left + place.u * w}px`, top: `${top + place.v * h}px`, width: "", height: ""});
  }
}
ros.subscribe(names.JOINT_STATE_TOPIC, "sensor_msgs/JointState", (js) => {
  js.name.forEach((name, i) => {
    if (name === "HeadYaw") robotHead.yaw = js.position[i];
    if (name === "HeadPitch") robotHead.pitch = js.position[i];
  });
}, {throttle_rate: 100, queue_length: 1});
setInterval(() => { if (autonomy.pending.size || autonomy.attention?.source) showAutonomy(); }, 200);
function decide(decision) {
  if (!autonomy.current()) return;
  const label = autonomy.current().label;
  autonomy.decide(decision)
    .then((message) => logLine($("events"), `${label}: ${message}`))
    .catch((err) => logLine($("events"), `${decision} refused: ${err.message}`, "error"));
}
// Naming the person the robot looks at (/vr_teleop/people/rename): the server's name is the one both pages show.
// The form names the person it showed when the supervisor began typing, wherever the attention has moved since.
function showRename(a) {
  const form = $("rename");
  if (form.contains(document.activeElement) && form.dataset.id) return;
  form.dataset.id = a?.id || "";
  form.hidden = !form.dataset.id;
  $("rename-id").textContent = form.dataset.id;
  if (document.activeElement !== $("rename-name")) $("rename-name").placeholder = a?.who || "";
}
$("rename").onsubmit = (event) => {
  event.preventDefault();
  const id = $("rename").dataset.id, name = $("rename-name").value;
  ros.call(names.PEOPLE_RENAME_SERVICE, {id, name})
    .then((r) => {
      logLine($("events"), r.message);
      $("rename-name").value = "";
      $("rename-name").blur();
      autonomy.refusal = null;
      showAutonomy();
    })
    .catch((err) => autonomy.refused(`rename refused: ${err.message}`));
};
$("proposal-accept").onclick = () => decide("accept");
$("proposal-reject").onclick = () => decide("reject");
$("proposal-forbid").onclick = () => decide("forbid");
for (const b of document.querySelectorAll("#autonomy [data-level]")) {
  b.onclick = () => autonomy.setLevel(b.dataset.level)
    .then((message) => logLine($("events"), message))
    .catch((err) => logLine($("events"), `autonomy level refused: ${err.message}`, "error"));
}
showAutonomy();

// ---- study: the trial, its live metrics, the experimenter's labels, overrides and preempt -------------------------
// Labels are published as events on /study/labels, trial or not, so that the session recording holds them; a running
// trial takes them as the start and stop of human actions and answers with a state update (or a warning).
const studyLog = (text, level) => logLine($("labels"), text, level);
const fixed = (x) => (x === null || x === undefined) ? "–" : x.toFixed(2);
let awaitedHuman = "";
let trialName = null;
let interventions = 0;
ros.subscribe(names.STUDY_TRIAL_TOPIC, "vr_teleop_msgs/TrialState", (t) => {
  if (t.trial !== trialName) {  // a new trial: its own counts
    trialName = t.trial;
    interventions = 0;
    $("m-interventions").textContent = "0";
  }
  const ended = {completed: "ended", preempted: "stopped", failed: "stopped"}[t.state];
  $("trial-badge").textContent = `${t.trial}: ${t.state}`;
  $("trial-badge").className = `badge ${ended || (t.state === "running" ? "running" : "")}`;
  $("trial-name").textContent = `${t.study} / ${t.trial}`;
  $("trial-modules").textContent = `${t.perception} / ${t.decision} / ${t.action}`;
  $("trial-current").textContent = t.current || "–";
  $("trial-elapsed").textContent = `${t.elapsed.toFixed(1)} s`;
  const human = t.awaiting_human || "";  // a typed field: the words in `current` are for people
  if (human && human !== awaitedHuman && document.activeElement !== $("label-action")) $("label-action").value = human;
  awaitedHuman = human;
});
ros.subscribe(names.STUDY_METRICS_TOPIC, "vr_teleop_msgs/FluencyMetrics", (m) => {
  for (const key of ["h_idle", "r_idle", "c_act", "f_del"]) $(`m-${key}`).textContent = m.defined ? fixed(m[key]) : "–";
  $("m-effectiveness").textContent = m.effectiveness < 0 ? "–" : fixed(m.effectiveness);
  $("m-efficiency").textContent = m.final ? `${m.elapsed.toFixed(1)} s` : `(${m.elapsed.toFixed(0)} s)`;
  $("m-actions").textContent = `${m.human_actions} / ${m.robot_actions}`;
  $("trial-elapsed").textContent = `${m.elapsed.toFixed(1)} s`;
});
ros.subscribe(names.STUDY_STATE_UPDATES_TOPIC, "vr_teleop_msgs/StateUpdate", (u) => {
  const what = u.finished ? `stopped at ${u.stop.toFixed(2)} s${u.succeeded ? "" : " (failed)"}` : `started at ${u.start.toFixed(2)} s`;
  logLine($("updates"), `${u.agent} ${u.action} ${what} [${u.source}]`, u.finished && !u.succeeded ? "warning" : "info");
});
ros.subscribe(names.STUDY_INTERVENTIONS_TOPIC, "vr_teleop_msgs/Intervention", (i) => {
  $("m-interventions").textContent = String(++interventions);
  logLine($("updates"), `intervention (${i.kind}) ${i.subtask || ""} at ${i.stop.toFixed(2)} s ${i.note}`, "warning");
});
function label(kind) {
  const action = $("label-action").value.trim() || "human_action";
  const detail = JSON.stringify({action, wall_time: Date.now() / 1000});
  ros.advertise(names.STUDY_LABELS_TOPIC, "vr_teleop_msgs/Event");
  const sent = ros.publish(names.STUDY_LABELS_TOPIC, {header: {}, source: "experimenter", kind, level: "info", detail});
  studyLog(`${kind.replaceAll("_", " ")}: ${action}${sent ? "" : " NOT SENT (disconnected)"}`, sent ? "info" : "error");
}
function override(succeeded) {
  ros.call(names.DECISION_OVERRIDE_SERVICE, {succeeded, note: "marked on the dashboard"})
    .then((r) => studyLog(`override: ${r.message}`, r.success ? "info" : "error"))
    .catch((err) => studyLog(`override refused: ${err.message}`, "error"));
}
function preempt() {
  if (!confirm("Preempt the trial? The participant stops the study and the robot holds.")) return;
  ros.call(names.DECISION_PREEMPT_SERVICE)
    .then((r) => studyLog(`preempt: ${r.message}`, r.success ? "warning" : "error"))
    .catch((err) => studyLog(`preempt refused: ${err.message}`, "error"));
}
// ---- the live study (serve --study): the experimenter's console over /study/session and the /study/* services ----
let session = null;
let enrolled = null;  // the participant just enrolled: selected once the session lists them
function studyCall(service, args, what) {
  return ros.callService(service, args)
    .then((r) => { studyLog(`${what}: ${r.message}`); return r; })
    .catch((err) => { studyLog(`${what} refused: ${err.message}`, "error"); return null; });
}
function options(select, values, first = null) {
  const keep = select.value;
  select.replaceChildren(...(first ? [new Option(first, "")] : []), ...values.map((v) => new Option(v, v)));
  if ([...select.options].some((o) => o.value === keep)) select.value = keep;
}
ros.subscribe(names.STUDY_SESSION_TOPIC, "vr_teleop_msgs/StudySession", (s) => {
  session = s;
  $("live-study").hidden = false;
  $("study-name").textContent = `${s.study} (${s.kind}, ${s.design}, ${s.order})${s.balance ? " · " + s.balance : ""}`;
  $("participants").tBodies[0].replaceChildren(...s.participants.map((p) => {
    const row = document.createElement("tr");
    const running = s.running_participant === p.id ? ` (running: ${s.running_condition})` : "";
    for (const text of [p.id + (p.consented ? "" : " (no consent)"), p.order.join(", "), p.done.join(", ") || "–",
                        (p.next || "all done") + running, p.due.join(", ") || "–"]) {
      row.append(Object.assign(document.createElement("td"), {textContent: text}));
    }
    return row;
  }));
  options($("trial-participant"), s.participants.map((p) => p.id));
  if (enrolled && s.participants.some((p) => p.id === enrolled)) { $("trial-participant").value = enrolled; enrolled = null; }
  const next = s.participants.find((p) => p.id === $("trial-participant").value && p.next && !s.running_trial);
  if (!$("trial-participant").value && s.participants.length) $("trial-participant").value = s.participants.at(-1).id;
  options($("trial-condition"), s.conditions, "next in their order");
  const due = s.participants.filter((p) => p.due.length);
  $("study-due").textContent = s.running_trial
    ? `running: ${s.running_participant}, ${s.running_condition} (trial ${s.running_trial})`
    : due.length ? due.map((p) => `hand the tablet to ${p.id}: ${p.due.join(", ")}`).join(" · ")
      : (next ? `next: ${next.id}, ${next.next}` : "nothing due");
  $("woz").hidden = !s.actions.length;
  options($("woz-object"), s.objects);
  if ($("woz-actions").childElementCount !== s.actions.length) {
    $("woz-actions").replaceChildren(...s.actions.map((action) => {
      const b = Object.assign(document.createElement("button"), {textContent: action, type: "button"});
      b.onclick = () => studyCall(names.DECISION_TELEOP_SERVICE, {object: $("woz-object").value, action}, `wizard ${action}`);
      return b;
    }));
  }
});
$("enrol").onclick = () => studyCall(names.STUDY_PARTICIPANT_ADD_SERVICE, {
  consent: $("enrol-consent").checked, consent_form: $("enrol-form").value.trim(), group: $("enrol-group").value.trim(),
}, "enrol").then((r) => {
  if (!r) return;
  enrolled = r.participant;
  if ([...$("trial-participant").options].some((o) => o.value === enrolled)) $("trial-participant").value = enrolled;
  const link = `${location.origin}/participant#token=${r.token}`;
  $("enrol-link").textContent = `${r.participant}'s questionnaire page (open it on the tablet): ${link}`;
  $("enrol-consent").checked = false;
});
function startTrial() {
  studyCall(names.STUDY_TRIAL_START_SERVICE, {participant: $("trial-participant").value,
    condition: $("trial-condition").value, reason: $("trial-reason").value.trim()}, "start")
    .then((r) => { if (r) $("trial-reason").value = ""; });
}
function endTrial(outcome) {
  studyCall(names.STUDY_TRIAL_END_SERVICE, {outcome, note: $("trial-end-note").value.trim()}, `end (${outcome})`)
    .then((r) => { if (r) $("trial-end-note").value = ""; });
}
function sendNote() {
  studyCall(names.STUDY_NOTE_SERVICE, {text: $("study-note").value}, "note").then((r) => { if (r) $("study-note").value = ""; });
}
$("trial-start").onclick = startTrial;
$("trial-end-completed").onclick = () => endTrial("completed");
$("trial-end-aborted").onclick = () => endTrial("aborted");
$("study-note-send").onclick = sendNote;
$("study-note").addEventListener("keydown", (event) => { if (event.key === "Enter") { event.preventDefault(); sendNote(); } });
$("label-start").onclick = () => label("human_action_start");
$("label-stop").onclick = () => label("human_action_stop");
$("label-intervention").onclick = () => label("intervention");
$("override-ok").onclick = () => override(true);
$("override-failed").onclick = () => override(false);
$("preempt").onclick = preempt;
const KEYS = {h: () => label("human_action_start"), j: () => label("human_action_stop"), i: () => label("intervention"),
              o: () => override(true), f: () => override(false),
              a: () => decide("accept"), r: () => decide("reject"), n: () => decide("forbid"),
              s: () => { if (session) startTrial(); }, t: () => { if (session) $("study-note").focus(); }};
document.addEventListener("keydown", (event) => {
  if (event.key === "Escape") { estop(); return; }
  if (["INPUT", "SELECT", "TEXTAREA"].includes(event.target.tagName) || event.ctrlKey || event.metaKey || event.altKey) return;
  const key = event.key.toLowerCase();
  if (KEYS[key]) { event.preventDefault(); KEYS[key](); }
});
