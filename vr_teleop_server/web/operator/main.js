// The operator's seat in a headset's browser (issue 19). It speaks rosbridge to the server that serves it, like
// the Unity client: head and controller poses and Joy once per XR frame, the engage/calibrate/e-stop services,
// the menus from /vr_teleop/menus, the robot's camera on a panel, sound both ways and a heads-up display.
// Without a headset the same page is a flat view: mouse-look drives the head, the keyboard the menus.

import * as names from "../names.js";
import * as THREE from "three";
import {Rosbridge, stampSeconds} from "../rosbridge.js";
import {poseStamped, joyFromGamepad, joyMessage, sameJoy} from "./ros_axes.js";
import {CameraFeed} from "./camera.js";
import {PoseChannel} from "./pose_channel.js";
import {MenuError, MenuNavigator, TOGGLE_COMMANDS, parseMenus} from "./menus.js";
import {drawHud, drawMenu, menuStick} from "./panels.js";
import {Audio} from "./audio.js";
import {ControllerActions} from "./controls.js";
import {HAND_MENU_ID, HandActions, handRays, inputKind, rayPointer, readHand, withHandMenu} from "./hands.js";
import {OperatorAutonomy} from "./autonomy.js";
import {Comfort, COMMAND as COMFORT_COMMAND, optionFromAddress} from "./comfort.js";
import {t, translateMenus, translatePage} from "../i18n.js";
import {PANELS, PANEL_SIZE, Trends, dialogChoices, dialogFace, dialogRow, drawDialog, drawHardware, drawMotivation,
        drawMotors, hardwareRow, hardwareRows, motivationBar, motivationStep, motorBar, moveDialog}
  from "../status_panels.js";

const TOPICS = {
  head: names.HEAD_POSE_TOPIC, left: names.CONTROLLER_POSE_TOPICS.left, right: names.CONTROLLER_POSE_TOPICS.right,
  leftJoy: names.JOY_TOPICS.left, rightJoy: names.JOY_TOPICS.right,
};
const SERVICES = {
  engage: names.ENGAGE_SERVICE, calibrate: names.CALIBRATE_SERVICE,
  recenter: names.RECENTER_SERVICE,
  estop: names.ESTOP_SERVICE, select: names.MENU_SELECT_SERVICE,
  whoami: names.WHOAMI_SERVICE,
};
const TELEMETRY_TOPIC = names.TELEMETRY_TOPIC;
const JOY_KEEPALIVE_MS = 33;   // Joy goes out on every change, and at least at 30 Hz
const HUD_PERIOD_MS = 200;     // the heads-up display is redrawn five times a second
const MESSAGE_KEEP_MS = 8000;
const PANEL_DISTANCE = 2.0;    // metres from the eyes to the camera panel
const CAMERA_HFOV_DEG = 80;    // the head camera's horizontal field of view (D435 colour, fx 376 at 640 px):
                               // the panel spans the same angle, so the view is the robot's, degree for degree
const FLAT_LOOK_DEG_PER_PX = 0.25;
const EYE_HEIGHT = 1.6;

const $ = (id) => document.getElementById(id);
translatePage();  // the page's words in the reader's language (../i18n.js)
const token = new URLSearchParams(location.hash.slice(1)).get("token");
const scheme = location.protocol === "https:" ? "wss" : "ws";
const ros = new Rosbridge(`${scheme}://${location.host}/`, {token, idPrefix: "operator"});

const state = {
  teleop: null,                        // the newest /vr_teleop/teleop_state
  me: null,                            // our session's name once we hold control (the holder field says it)
  connection: null,                    // this rosbridge connection's name (/vr_teleop/whoami), for the telemetry
  link: null,                          // our entry of the newest /vr_teleop/telemetry: the link's quality
  claimHolder: false, engaging: false, pulses: 0, disconnectReason: "",
  message: null, menusProblem: null, footer: null,
  headOn: true, armsOn: true, recording: false,  // the menu switches' states, from the events' typed details
  recordingParts: [],
  zero: {yaw: 0, pitch: 0},            // the operator's head (XR yaw, pitch) when control was taken
  robotHead: {yaw: 0, pitch: 0},       // degrees, from the joint states
  head: {position: new THREE.Vector3(0, EYE_HEIGHT, 0), quaternion: new THREE.Quaternion()},
  flat: {yaw: 0, pitch: 0, dragging: false},
  xr: null, joy: {left: null, right: null}, joySent: {left: 0, right: 0},
  input: null,                         // "controllers", "hands", "a hand and a controller" (hands.js inputKind)
  posesSent: 0, frames: 0, frameCount: 0, fps: 0, frameTimes: [], workTimes: [], lastFrameAt: null,
  lastClamped: new Set(),
  motorFaults: {},                     // motor -> what it reports wrong (a real robot's joints error stream)
  voice: null,                         // {activity, direction_deg} while the robot's microphone hears a voice
  statusPanel: null,                   // the status panel open over the reduced view: one of PANELS
  motors: null, motivation: null,      // the newest /vr_teleop/status/motors and /vr_teleop/status/motivation
  robotHardware: null, hardware: null, // the newest /vr_teleop/status/robot_hardware and /vr_teleop/status/hardware
  panelRow: 0,                         // the motivation variable the controls act on
  dialogChoices: {sentences: [], faces: []},  // what the dialog panel offers (from the menus)
  dialog: {sentence: 0, face: 0},      // the dialog panel's chosen sentence and face
  dialogResult: null,                  // what became of its last pick: {text, level}
};

// ---- the scene ----------------------------------------------------------------------------------------------------
// No multisampling: the scene is flat panels facing the eyes, whose text is sharp from texture filtering; MSAA would
// cost every frame (and a software renderer dearly).
const renderer = new THREE.WebGLRenderer({antialias: false});
renderer.setPixelRatio(Math.min(window.devicePixelRatio, 2));
renderer.setSize(window.innerWidth, window.innerHeight);
renderer.xr.enabled = true;
renderer.xr.setReferenceSpaceType("local-floor");
$("view").append(renderer.domElement);

const scene = new THREE.Scene();
scene.background = new THREE.Color(0x0d141c);
scene.add(new THREE.GridHelper(12, 24, 0x3a4a5c, 0x1f2b38));
const camera = new THREE.PerspectiveCamera(70, window.innerWidth / window.innerHeight, 0.05, 50);
camera.position.set(0, EYE_HEIGHT, 0);
scene.add(camera);

function canvas(width, height) {
  const c = document.createElement("canvas");
  c.width = width;
  c.height = height;
  return c;
}

function textTexture(c) {
  const t = new THREE.CanvasTexture(c);
  t.colorSpace = THREE.SRGBColorSpace;
  t.minFilter = THREE.LinearFilter;
  t.generateMipmaps = false;
  return t;
}

// The camera panel hangs in the direction the robot looks: when the robot's head lags the operator's, the panel
// lags, instead of the whole world swimming. Its anchor sits at the operator's eyes.
const placeholder = canvas(640, 480);
{
  const ctx = placeholder.getContext("2d");
  ctx.fillStyle = "#1b2633";
  ctx.fillRect(0, 0, 640, 480);
  ctx.fillStyle = "#c9d6e3";
  ctx.font = "600 34px system-ui, sans-serif";
  ctx.textAlign = "center";
  ctx.fillText("waiting for the robot's camera…", 320, 240);
}
// WebRTC video (and the robot's audio) when negotiated, else the JPEG topic: camera.js. The same peer connection
// carries the operator's voice (audio.js) and the poses data channel (pose_channel.js), both prepared before each offer.
const poseChannel = new PoseChannel();
const cameraSource = new CameraFeed(ros, {onMessage: (text, level) => say(text, level), placeholder,
                                          onAudio: (on) => { audio.topicMuted = on; },
                                          prepare: (pc) => {
                                            audio.prepare(pc);
                                            poseChannel.attach(pc);
                                          }});
const panelAnchor = new THREE.Group();
const panelWidth = 2 * PANEL_DISTANCE * Math.tan(THREE.MathUtils.degToRad(CAMERA_HFOV_DEG / 2));
const panel = new THREE.Mesh(new THREE.PlaneGeometry(panelWidth, panelWidth),
                             new THREE.MeshBasicMaterial({map: cameraSource.texture, toneMapped: false}));
panel.position.set(0, 0, -PANEL_DISTANCE);
panelAnchor.add(panel);
// The attention target over the camera picture (autonomy.js draws it): a transparent layer just in front.
const attentionCanvas = canvas(640, 480);
const attentionTexture = textTexture(attentionCanvas);
const attentionLayer = new THREE.Mesh(panel.geometry, new THREE.MeshBasicMaterial({
  map: attentionTexture, transparent: true, toneMapped: false, depthWrite: false}));
attentionLayer.position.z = 0.002;
attentionLayer.renderOrder = 1;
panel.add(attentionLayer);
scene.add(panelAnchor);

// Head-locked: the heads-up display low in the view, the menu in front when open. Placed from the head pose of
// the same frame (children of the camera would trail by a frame in XR).
const headLocked = new THREE.Group();
scene.add(headLocked);
const hudCanvas = canvas(1400, 340);
const hudTexture = textTexture(hudCanvas);
const hud = new THREE.Mesh(new THREE.PlaneGeometry(0.95, 0.95 * 340 / 1400),
                           new THREE.MeshBasicMaterial({map: hudTexture, transparent: true, toneMapped: false,
                                                        depthTest: false}));
hud.position.set(0, -0.48, -1.0);
hud.renderOrder = 10;
headLocked.add(hud);
// The robot's proposal waiting for the teacher, just above the HUD while there is one (autonomy.js).
const proposalCanvas = canvas(1400, 340);
const proposalTexture = textTexture(proposalCanvas);
const proposalMesh = new THREE.Mesh(new THREE.PlaneGeometry(0.95, 0.95 * 340 / 1400),
                                    new THREE.MeshBasicMaterial({map: proposalTexture, transparent: true,
                                                                 toneMapped: false, depthTest: false}));
proposalMesh.position.set(0, -0.245, -1.0);
proposalMesh.renderOrder = 10;
proposalMesh.visible = false;
headLocked.add(proposalMesh);
const menuCanvas = canvas(1400, 1000);
const menuTexture = textTexture(menuCanvas);
const menuMesh = new THREE.Mesh(new THREE.PlaneGeometry(0.84, 0.6),
                                new THREE.MeshBasicMaterial({map: menuTexture, transparent: true, toneMapped: false,
                                                             depthTest: false}));
menuMesh.position.set(0, 0.04, -0.85);
menuMesh.renderOrder = 11;
menuMesh.visible = false;
headLocked.add(menuMesh);
// A status panel (../status_panels.js), head-locked right of the camera view, which shrinks and moves left for it
// (the paper's layout: the view keeps running beside the panel).
const statusCanvas = canvas(PANEL_SIZE.width, PANEL_SIZE.height);
const statusTexture = textTexture(statusCanvas);
const statusMesh = new THREE.Mesh(new THREE.PlaneGeometry(0.56, 0.56),
                                  new THREE.MeshBasicMaterial({map: statusTexture, transparent: true,
                                                               toneMapped: false, depthTest: false}));
statusMesh.position.set(0.34, 0.06, -1.0);
statusMesh.renderOrder = 9;
statusMesh.visible = false;
headLocked.add(statusMesh);
const REDUCED_VIEW = {scale: 0.5, x: -0.72};  // the camera panel beside an open status panel (metres at 2 m)

// The controllers, as small blocks where the hands are.
const hands = [0, 1].map((i) => {
  const grip = renderer.xr.getControllerGrip(i);
  grip.add(new THREE.Mesh(new THREE.BoxGeometry(0.03, 0.025, 0.09), new THREE.MeshBasicMaterial({color: 0x9fb0c3})));
  scene.add(grip);
  return grip;
});

function resize() {
  if (renderer.xr.isPresenting) return;
  camera.aspect = window.innerWidth / window.innerHeight;
  camera.updateProjectionMatrix();
  renderer.setSize(window.innerWidth, window.innerHeight);
}
window.addEventListener("resize", resize);

// ---- messages on the HUD ------------------------------------------------------------------------------------------
function say(text, level = "info") {
  state.message = {text, level, at: performance.now()};
  if (level === "error") pulse();
  updateHud(true);
}

let pulsedAt = -1e9;
function pulse(intensity = 0.7, ms = 80) {
  const session = renderer.xr.getSession();
  if (!session || performance.now() - pulsedAt < 500) return;  // a short pulse, not a buzz
  pulsedAt = performance.now();
  state.pulses += 1;
  for (const source of session.inputSources) {
    const actuator = source.gamepad?.hapticActuators?.[0];
    try {
      const done = actuator?.pulse ? actuator.pulse(intensity, ms)
        : source.gamepad?.vibrationActuator?.playEffect?.("dual-rumble", {duration: ms, strongMagnitude: intensity});
      done?.catch?.(() => {});
    } catch { /* haptics are a courtesy */ }
  }
}

ros.onopen = () => {
  learnConnection();
  audio.sendInfo();
  say("connected to the server", "ok");
  cameraSource.connected();  // after: what it says about the camera stays on the HUD
};
ros.onclose = (reason) => {
  state.me = null;
  state.connection = null;
  state.link = null;
  state.disconnectReason = reason;
  updateHud(true);
};
ros.onstatus = (msg) => {
  if (msg.level !== "error" && msg.level !== "warning") return;
  const m = state.message;  // the page's own word on a refusal (just said) is clearer than the stream's echo
  if (m && m.level === "error" && performance.now() - m.at < 1500 && !m.text.startsWith("server:")) return;
  say(`server: ${msg.msg}`, msg.level);
};

// ---- the link's quality (the server's telemetry names each connection: ours is the one whoami names) ---------
async function learnConnection() {
  try {
    state.connection = (await ros.call(SERVICES.whoami, {}, 5000)).connection;
  } catch { /* an older server: no link line */ }
}

ros.subscribe(TELEMETRY_TOPIC, "vr_teleop_msgs/Telemetry", (msg) => {
  const mine = (msg.clients || []).find((c) => c.client === state.connection);
  if (!mine) return;
  if (mine.link_quality === "poor" && state.link?.link_quality !== "poor") pulse(0.8, 120);
  state.link = mine;
});  // no queue_length: the camera's RenderTimes reads every report of the same subscription

/** The link's one line: the round trip (the HUD's only one: the telemetry's, the worse of the WebSocket's and the peer
 * connection's, the figure the server judges the link by) and, once there is a link to judge (this page holds control
 * and its poses have reached the server), the server's verdict. A warning that names the round trip is not given it
 * twice; one that does not gets it first (the headset's HUD cuts a long line at its end). */
function linkLine() {
  const l = state.link;
  const rtt = l ? Math.max(l.ws_rtt, l.rtc_rtt ?? -1) : -1;
  if (rtt < 0) return {id: "link", text: "round trip: measuring", level: "muted"};
  const ms = `round trip ${(rtt * 1000).toFixed(0)} ms`;
  if (!l.link_quality) return {id: "link", text: holding() ? `${ms} · link: judged once your poses arrive` : ms,
                               level: "info"};
  if (l.link_quality === "good") return {id: "link", text: `link good · ${ms}`, level: "ok"};
  const level = l.link_quality === "poor" ? "error" : "warning";
  const why = l.link_warning.includes("round trip") ? l.link_warning : `${ms} · ${l.link_warning}`;
  return {id: "link", text: `LINK ${l.link_quality.toUpperCase()}: ${why}`, level};
}

// ---- the robot's state ----------------------------------------------------------------------------------------------
ros.subscribe(names.TELEOP_STATE_TOPIC, "vr_teleop_msgs/TeleopState", (s) => {
  if (state.claimHolder && s.engaged && s.holder) {
    state.me = s.holder;
    state.claimHolder = false;
  }
  if (state.me && s.holder !== state.me) state.me = null;
  const clamped = new Set(s.clamped || []);
  if (state.me && [...clamped].some((j) => !state.lastClamped.has(j))) pulse(0.5, 50);
  state.lastClamped = clamped;
  state.teleop = s;
  if (state.statusPanel === "motors") statusDirty = true;
}, {throttle_rate: 100, queue_length: 1});
ros.subscribe(names.JOINT_STATE_TOPIC, "sensor_msgs/JointState", (js) => {
  js.name.forEach((name, i) => {
    if (name === "HeadYaw") state.robotHead.yaw = js.position[i];
    if (name === "HeadPitch") state.robotHead.pitch = js.position[i];
  });
}, {throttle_rate: 30, queue_length: 1});
ros.subscribe(names.EVENT_TOPIC, "vr_teleop_msgs/Event", (e) => {
  // Each kind's detail has typed fields (client_protocol/events.py): states come from those, never from wording.
  let detail = {};
  try { detail = e.detail ? JSON.parse(e.detail) : {}; } catch { return; /* not one of the server's events */ }
  switch (e.kind) {
    case "motor_error": state.motorFaults[detail.motor] = (detail.faults || []).join(", "); return;
    case "motor_ok": delete state.motorFaults[detail.motor]; return;
    case "voice_activity": state.voice = detail.activity ? detail : null; return;
    case "head_on": case "head_off": case "arms_on": case "arms_off":
      state[detail.part === "head" ? "headOn" : "armsOn"] = detail.enabled === true;
      break;
    case "gesture_recording":
      state.recording = detail.recording === true;
      state.recordingParts = detail.parts || [];
      break;
    default: return;
  }
  menuDirty = true;
});

// ---- the status panels (motors, motivation), live at their topics' rate -------------------------------------------
const trends = new Trends();
let statusDirty = false;
ros.subscribe(names.MOTORS_STATUS_TOPIC, "vr_teleop_msgs/MotorsStatus", (m) => {
  state.motors = m;
  if (state.statusPanel === "motors") statusDirty = true;
});
ros.subscribe(names.MOTIVATION_STATUS_TOPIC, "vr_teleop_msgs/Motivation", (m) => {
  state.motivation = m;
  trends.add(m, performance.now());
  if (state.statusPanel === "motivation") statusDirty = true;
});
ros.subscribe(names.ROBOT_HARDWARE_STATUS_TOPIC, "vr_teleop_msgs/RobotHardwareStatus", (m) => {
  state.robotHardware = m;
  if (state.statusPanel === "hardware") statusDirty = true;
});
ros.subscribe(names.HARDWARE_STATUS_TOPIC, "vr_teleop_msgs/HardwareStatus", (m) => {
  state.hardware = m;
  if (state.statusPanel === "hardware") statusDirty = true;
});

function showPanel(which) {
  state.statusPanel = state.statusPanel === which ? null : which;  // picking the item again closes it
  if (state.statusPanel) nav.close();  // the panel in view, not the menu over it
  statusDirty = true;
  menuDirty = true;
}

function drawStatus() {
  if (state.statusPanel === "motors") {
    drawMotors(statusCanvas, state.motors, state.lastClamped, t, t("panel.close_hint"));
  } else if (state.statusPanel === "motivation") {
    drawMotivation(statusCanvas, state.motivation, trends, state.panelRow, t, t("panel.motivation_hint"));
  } else if (state.statusPanel === "hardware") {
    drawHardware(statusCanvas, state.robotHardware, state.hardware, t, t("panel.close_hint"));
  } else if (state.statusPanel === "dialog") {
    drawDialog(statusCanvas, state.dialogChoices, state.dialog, state.dialogResult, t,
               state.xr ? t("panel.dialog_hint") : t("panel.dialog_keys_hint"));
  }
  statusTexture.needsUpdate = true;
}

// The motivation panel's controls: the left stick (or the arrow keys) up and down chooses a variable, left and
// right lower and raise it by a tenth of its range through /vr_teleop/motivation/increment; once per push.
let panelStickOut = false;
function panelStick(x, y) {
  if (Math.hypot(x, y) < 0.3) { panelStickOut = false; return; }
  if (panelStickOut || Math.hypot(x, y) < 0.8) return;
  panelStickOut = true;
  if (Math.abs(y) > Math.abs(x)) panelMove(y > 0 ? -1 : 1);
  else changeMotivation(x > 0 ? 1 : -1);
}

function panelMove(delta) {
  const n = state.motivation?.name.length ?? 0;
  if (!n) return;
  state.panelRow = (state.panelRow + delta + n) % n;
  statusDirty = true;
}

async function changeMotivation(sign) {
  const m = state.motivation;
  if (!m) return;
  const i = Math.min(state.panelRow, m.name.length - 1);
  try {
    await ros.call(names.MOTIVATION_INCREMENT_SERVICE, {name: m.name[i], value: sign * motivationStep(m, i)});
  } catch (err) {
    say(`${m.name[i]}: ${err.message}`, "error");
  }
}

// The dialog panel's controls (the paper's dialog window): the left stick (or the arrow keys) up and down chooses a
// sentence, left and right a face, once per push; the right trigger, A (or Enter) has the robot say the sentence
// with that face: the speech and emotion menus' own items, both at once, through /vr_teleop/menu/select.
let dialogStickOut = false;
function dialogStick(x, y) {
  if (Math.hypot(x, y) < 0.3) { dialogStickOut = false; return; }
  if (dialogStickOut || Math.hypot(x, y) < 0.8) return;
  dialogStickOut = true;
  if (Math.abs(y) > Math.abs(x)) moveInDialog(0, y > 0 ? -1 : 1);
  else moveInDialog(x > 0 ? 1 : -1, 0);
}

function moveInDialog(dx, dy) {
  state.dialog = moveDialog(state.dialog, state.dialogChoices, dx, dy);
  statusDirty = true;
}

async function pickDialog() {
  const {sentences, faces} = state.dialogChoices;
  const sentence = sentences[state.dialog.sentence], face = faces[state.dialog.face];
  if (!sentence || !face) return;
  state.dialogResult = {text: t("panel.dialog_sent", {face: face.label}), level: "ok"};
  statusDirty = true;
  const results = await Promise.allSettled([face, sentence].map((item) =>
    ros.call(SERVICES.select, {id: item.id, args: item.args})));
  const refused = results.find((r) => r.status === "rejected");
  if (refused) {
    state.dialogResult = {text: t("panel.dialog_failed", {reason: refused.reason.message}), level: "error"};
    say(refused.reason.message, "error");
    statusDirty = true;
  }
}

/** The open panel's pick (the right trigger, A, Enter): true when a panel took it. */
function panelPick() {
  if (nav.open || state.statusPanel !== "dialog") return false;
  pickDialog();
  return true;
}

// ---- menus ----------------------------------------------------------------------------------------------------------
const nav = new MenuNavigator();
let menuDirty = true;
ros.subscribe(names.MENUS_TOPIC, "vr_teleop_msgs/Menus", (msg) => {
  try {
    const translated = translateMenus(msg);
    nav.setTree(withHandMenu(parseMenus(translated)));  // hands open the menus from a ring of them (hands.js)
    state.dialogChoices = dialogChoices(translated.items);  // the robot's language may have changed the sentences
    state.dialog = moveDialog(state.dialog, state.dialogChoices, 0, 0);
    if (state.statusPanel === "dialog") statusDirty = true;
    state.menusProblem = null;
  } catch (err) {
    if (!(err instanceof MenuError)) console.error(err);
    state.menusProblem = `menus cannot be drawn (${err.message}); the last good menus stay`;
    say(state.menusProblem, "error");
  }
  menuDirty = true;
});

const toggles = {
  get(id) {
    const item = nav.tree?.byId.get(id);
    if (item?.command === "set_autonomy" && autonomy.model.level) {  // the level in force is the one ON
      try { return JSON.parse(item.args || "{}").level === autonomy.model.level; } catch { return undefined; }
    }
    if (item?.command === COMFORT_COMMAND) return comfort.enabled;
    if (!item || !TOGGLE_COMMANDS.has(item.command)) return undefined;
    const states = {set_head_control: state.headOn, set_arms_control: state.armsOn, record_toggle: state.recording};
    return states[item.command];
  },
};

function pressMenuButton(hand, letter) {
  if (letter === "B" && state.statusPanel && !nav.open) {  // B closes an open status panel
    showPanel(state.statusPanel);
    return;
  }
  if (letter === "A" && panelPick()) return;  // A picks in the dialog panel
  const menu = nav.menuFor(hand, letter);
  if (!menu) {
    if (!nav.tree) say("the menus have not arrived from the server yet", "warning");
    return;
  }
  nav.press(menu.id);
  state.footer = null;
  menuDirty = true;
}

async function runItem(item) {
  let which = null;
  try {
    which = item.command === "show_status" ? JSON.parse(item.args || "{}").which : null;
  } catch { /* args that are not JSON: the server's reply names them */ }
  if (PANELS.includes(which)) showPanel(which);
  state.footer = {text: `${item.label}…`, level: "ok"};
  menuDirty = true;
  try {
    const reply = await ros.call(SERVICES.select, {id: item.id, args: comfort.menuItem(item) ?? ""});
    let text = reply.message || "done";
    if (item.command === "show_status") text = summariseStatus(text);
    state.footer = {text: `${item.label}: ${text}`, level: "ok"};
  } catch (err) {
    state.footer = {text: `${item.label}: ${err.message}`, level: "error"};
    say(`${item.label} refused: ${err.message}`, "error");
  }
  menuDirty = true;
}

function summariseStatus(text) {
  try {
    const data = JSON.parse(text);
    return Object.entries(data).filter(([k, v]) => typeof v !== "object" && k !== "header")
      .slice(0, 4).map(([k, v]) => `${k} ${typeof v === "number" ? +v.toFixed(1) : v}`).join(", ") || text;
  } catch {
    return text;
  }
}

function selectInMenu() {
  const item = nav.select();
  menuDirty = true;
  if (item) runItem(item);
}

// ---- control: engage, release, calibrate, e-stop ---------------------------------------------------------------
function holding() {
  return !!(state.me && state.teleop?.engaged && state.teleop.holder === state.me);
}

function othersHoldBefore() {
  const s = state.teleop;
  return !!(s && s.engaged && s.holder && s.holder !== state.me);
}

async function toggleControl() {
  if (holding()) {
    try {
      const r = await ros.call(SERVICES.engage, {data: false});
      state.me = null;
      say(r.message || "released", "ok");
    } catch (err) {
      say(`release refused: ${err.message}`, "error");
    }
    return;
  }
  const zero = headAngles(state.head.quaternion);
  state.engaging = true;  // our poses flow meanwhile: the server needs a fresh one
  try {
    if (othersHoldBefore()) await new Promise((resolve) => setTimeout(resolve, 100));  // a pose first
    const r = await ros.call(SERVICES.engage, {data: true});
    state.zero = zero;
    state.claimHolder = true;
    say(r.message || "you have control", "ok");
  } catch (err) {
    say(`taking control refused: ${err.message}`, "error");
  } finally {
    state.engaging = false;
  }
}

// The calibrate gesture measures the body (T-pose) and, while we hold control, re-centres: standing square with
// the arms out, the way the operator faces becomes straight ahead for the robot's head.
async function calibrate() {
  say("calibrating: hold a T-pose…");
  const lines = [];
  let ok = true;
  try {
    const r = await ros.call(SERVICES.calibrate, {});
    lines.push(`calibrated: ${r.message}`);
  } catch (err) {
    ok = false;
    lines.push(`calibration refused: ${err.message}`);
  }
  if (holding()) {
    const zero = headAngles(state.head.quaternion);
    try {
      const r = await ros.call(SERVICES.recenter, {});
      state.zero = zero;
      lines.push("recentered: straight ahead is where you look now");
    } catch (err) {
      ok = false;
      lines.push(`recentering refused: ${err.message}`);
    }
  }
  say(lines.join("; "), ok ? "ok" : "error");
}

async function estop() {
  try {
    const r = await ros.call(SERVICES.estop, {});
    state.me = null;
    say(`EMERGENCY STOP: ${r.message}`, "error");
  } catch (err) {
    say(`emergency stop failed: ${err.message}`, "error");
  }
}

const audio = new Audio(ros, {onError: (text) => say(text, "error")});
const autonomy = new OperatorAutonomy(ros, {say, onLevel: () => { menuDirty = true; }});
const comfort = new Comfort({scene, headLocked, enabled: optionFromAddress(location), checkbox: $("vignette"),
                             onChange: () => { menuDirty = true; }});  // the vignette and the reticle
function talk(on) {
  audio.talk(on);
  $("talk").classList.toggle("on", on);
  updateHud(true);
}

function pointInMenu(x, y, now) {
  const before = nav.highlight;
  nav.stick(x, y, now);
  if (nav.highlight !== before) menuDirty = true;
}

const actions = {
  menuButton: pressMenuButton, menuOpen: () => nav.open, select: selectInMenu, panelPick, toggleControl, calibrate,
  estop,
  talk, decide: (decision) => autonomy.decide(decision), proposalPending: () => autonomy.pending,
  stick: (hand, x, y, now) => {
    const menu = nav.menu;
    if (menu && (menu.controller === hand || menu.controller === "any")) pointInMenu(x, y, now);
    else if (!nav.open && state.statusPanel === "motivation" && hand === "left") panelStick(x, y);
    else if (!nav.open && state.statusPanel === "dialog" && hand === "left") dialogStick(x, y);
  },
  // the hands' own (hands.js): the menus' ring, back one level, the ray as thumbstick, their Joy
  openMenus: () => { nav.press(HAND_MENU_ID); state.footer = null; menuDirty = true; },
  back: () => { nav.back(); menuDirty = true; },
  point: pointInMenu,
  joy: (hand, joy, now) => publishJoy(hand, joy, now),
};
const controllers = new ControllerActions(actions);
const handActions = new HandActions(actions, rayPointer(THREE, {
  menu: menuMesh, hud, menuStick: (u, v) => menuStick(menuCanvas, u, v)}), handRays(THREE, scene));

// ---- poses, once per frame ------------------------------------------------------------------------------------
function headAngles(q) {
  const e = new THREE.Euler().setFromQuaternion(q, "YXZ");
  return {yaw: e.y, pitch: e.x};
}

// While another client holds control the server refuses our streams (with an error a second): wait instead.
function othersHold() {
  const s = state.teleop;
  return !!(s && s.engaged && s.holder && s.holder !== state.me && !state.engaging);
}

// The poses data channel while we hold control (the server takes poses there from the holder only), else rosbridge;
// the channel sends what it took at the end of the frame.
function publishStream(topic, msg) {
  return (holding() && poseChannel.send(topic, msg)) || ros.publish(topic, msg);
}

function publishPose(topic, position, orientation) {
  if (othersHold()) return;
  if (publishStream(topic, poseStamped(position, orientation))) state.posesSent += 1;
}

const RELEASED_JOY = {axes: [0, 0, 0, 0], buttons: [0, 0, 0, 0]};
function publishJoy(hand, joy, now) {
  if (othersHold()) return;
  if (sameJoy(joy, state.joy[hand]) && now - state.joySent[hand] < JOY_KEEPALIVE_MS) return;
  if (publishStream(hand === "left" ? TOPICS.leftJoy : TOPICS.rightJoy, joyMessage(joy))) {
    state.joy[hand] = joy;
    state.joySent[hand] = now;
  }
}

for (const [key, topic] of Object.entries(TOPICS)) {
  ros.advertise(topic, key.endsWith("Joy") ? "sensor_msgs/Joy" : "geometry_msgs/PoseStamped");
}

function xrFrame(frame, now) {
  const refSpace = renderer.xr.getReferenceSpace();
  const viewer = frame.getViewerPose(refSpace);
  if (viewer) {
    const {position: p, orientation: o} = viewer.transform;
    state.head.position.set(p.x, p.y, p.z);
    state.head.quaternion.set(o.x, o.y, o.z, o.w);
    publishPose(TOPICS.head, p, o);
  }
  const sources = frame.session.inputSources, handsSeen = new Set(), controllersSeen = new Set();
  for (const source of sources) {
    const hand = source.handedness;
    if (hand !== "left" && hand !== "right") continue;
    if (source.hand) {  // a tracked hand (whatever gamepad it carries): hands.js, the wrist as the arm's target
      const reading = readHand(frame, source, refSpace);
      if (reading) publishPose(TOPICS[hand], reading.wrist.position, reading.wrist.orientation);
      handActions.update(hand, reading, now);
      handsSeen.add(hand);
      continue;
    }
    if (source.gripSpace) {
      const pose = frame.getPose(source.gripSpace, refSpace);
      if (pose) publishPose(TOPICS[hand], pose.transform.position, pose.transform.orientation);
    }
    if (source.gamepad) {
      publishJoy(hand, joyFromGamepad(source.gamepad), now);
      controllers.update(hand, source.gamepad, now);
      controllersSeen.add(hand);
    }
  }
  for (const hand of ["left", "right"]) {
    if (!handsSeen.has(hand)) handActions.gone(hand, now);
    if (controllersSeen.has(hand)) continue;
    controllers.gone(hand);
    if (!handsSeen.has(hand) && state.joy[hand]?.axes[3] > 0) publishJoy(hand, RELEASED_JOY, now);  // nothing held
  }
  noteInput(inputKind(sources));
}

// Which input the headset reports (controllers or hands): on the HUD's input line; hands also get a hint of how to
// use them (the message line does not repeat the input line).
function noteInput(kind) {
  if (kind === state.input) return;
  state.input = kind;
  if (kind === "hands") say("hands: pinch to select, hold a fist to move that arm", "ok");
  menuDirty = true;
}

function flatFrame() {
  const f = state.flat;
  camera.quaternion.setFromEuler(new THREE.Euler(f.pitch, f.yaw, 0, "YXZ"));
  state.head.position.copy(camera.position);
  state.head.quaternion.copy(camera.quaternion);
  publishPose(TOPICS.head, camera.position, camera.quaternion);
}

function placePanels() {
  const {zero, robotHead, head} = state;
  const look = cameraSource.placementPose(robotHead);  // where the shown frame was taken (camera.js)
  panelAnchor.position.copy(head.position);
  panelAnchor.rotation.set(zero.pitch - THREE.MathUtils.degToRad(look.pitch),
                           zero.yaw + THREE.MathUtils.degToRad(look.yaw), 0, "YXZ");
  panel.material.map = cameraSource.texture;  // the source changes: placeholder, WebRTC video or JPEG
  const reduced = state.statusPanel ? REDUCED_VIEW : {scale: 1, x: 0};
  panel.scale.set(reduced.scale, reduced.scale / cameraSource.aspect, 1);
  panel.position.x = reduced.x;
  headLocked.position.copy(head.position);
  headLocked.quaternion.copy(head.quaternion);
  hud.visible = !!state.xr;  // the flat view has the page's own HUD
  menuMesh.position.set(0, state.xr ? 0.04 : 0.16, state.xr ? -0.85 : -1.0);  // flat: above the page's HUD
  if (menuDirty) {
    drawMenu(menuCanvas, nav, toggles, state.footer, menuHint());
    menuTexture.needsUpdate = true;
    menuMesh.visible = nav.open;
    $("menu-title").textContent = nav.open ? nav.title : "";
    menuDirty = false;
  }
  statusMesh.visible = !!state.statusPanel;
  statusMesh.position.y = state.xr ? 0.06 : 0.1;
  if (statusDirty && state.statusPanel) drawStatus();
  statusDirty = false;
}

function menuHint() {
  const button = nav.menu?.button || "";
  if (state.xr && state.input === "hands") return ["point", "pinch: select", "pinch off the menu: back"];
  return state.xr ? ["stick: point", "trigger: select", `${button}: back`]
                  : ["arrows: point", "Enter: select", `${button} or Backspace: back`];
}

// ---- the heads-up display -------------------------------------------------------------------------------------
let hudText = "";
let hudAt = 0;
let hudShown = [];  // the lines drawn last: what the HUD (its canvas and its DOM copy) shows now
function hudLines() {
  const lines = [];
  const s = state.teleop;
  if (ros.connected) lines.push({id: "connection", text: `● connected to ${location.host}`, level: "ok"});
  else {
    const wait = ros.nextRetryAt ? Math.max(0, (ros.nextRetryAt - performance.now()) / 1000).toFixed(1) : "?";
    lines.push({id: "connection", text: `○ DISCONNECTED (${state.disconnectReason}): reconnecting in ${wait} s`,
                level: "error"});
  }
  const hint = state.xr ? (state.input === "hands" ? "right pinch" : "right trigger") : "E";
  if (!s) lines.push({id: "control", text: "control: waiting for the server", level: "muted"});
  else if (s.state === "estopped") {
    lines.push({id: "control", text: `E-STOPPED: the robot holds (${hint}: take control again)`, level: "error"});
  } else if (holding()) {
    const parts = [s.head_following && "head", s.left_arm_following && "left arm",
                   s.right_arm_following && "right arm"];
    const following = parts.filter(Boolean).join(", ") || "nothing";
    lines.push({id: "control", text: `YOU HAVE CONTROL · ${s.state} · following: ${following}`,
                level: s.state === "active" ? "ok" : "warning"});
  } else if (s.holder && s.engaged) {
    lines.push({id: "control", text: `control held by ${s.holder} · ${s.state} · your poses wait`, level: "warning"});
  }
  else lines.push({id: "control", text: `no one in control · ${hint} takes control`, level: "info"});
  if (s && !s.robot_connected) {
    lines.push({id: "robot", text: "the ROBOT is DISCONNECTED from the server", level: "error"});
  }
  const autonomyLine = autonomy.hudLine();
  if (autonomyLine) lines.push(autonomyLine);
  const faults = Object.entries(state.motorFaults);
  if (faults.length) {
    lines.push({id: "motors", text: `MOTOR FAULT: ${faults.map(([m, f]) => `${m} (${f})`).join(", ")}`,
                level: "error"});
  }
  if (state.recording) {
    const parts = state.recordingParts.length ? ` (${state.recordingParts.join(", ")})` : "";
    lines.push({id: "recording", text: `● RECORDING a gesture${parts}`, level: "warning"});
  }
  if (state.voice) {
    const from = Number.isFinite(state.voice.direction_deg) ? ` (from ${state.voice.direction_deg}°)` : "";
    lines.push({id: "voice", text: `someone in the room is speaking${from}`, level: "info"});
  }
  if (ros.connected) lines.push(linkLine());
  const clamped = s?.clamped?.length ? s.clamped.join(", ") : "none";
  lines.push({id: "clamped", text: `clamped joints: ${clamped}`, level: s?.clamped?.length ? "warning" : "muted"});
  // No camera figure before the first frame: the view itself says it waits for the robot's camera.
  const age = cameraSource.frameAge();
  const route = cameraSource.path === "WebRTC" && cameraSource.route ? ` via ${cameraSource.route}` : "";
  const path = cameraSource.path ? ` (${cameraSource.road})${route}` : "";
  const frame = age === null ? "" : `camera frame ${Math.max(0, age * 1000).toFixed(0)} ms old${path} · `;
  const talking = audio.status ? ` · ${audio.status}` : "";
  lines.push({id: "numbers", text: `${frame}${state.fps} fps${talking}`, level: "info"});
  if (state.xr && state.input) lines.push({id: "input", text: `input: ${state.input}`, level: "info"});
  if (!state.xr) {
    lines.push({id: "keys", level: "muted",
                text: "drag: look · E: control · X Y A B: menus · hold T: talk · → ←: accept, reject · Esc: STOP"});
  }
  const m = state.message;
  if (state.menusProblem) lines.push({id: "message", text: state.menusProblem, level: "error"});
  else if (m && performance.now() - m.at < MESSAGE_KEEP_MS) lines.push({id: "message", text: m.text, level: m.level});
  return lines;
}

function updateHud(force = false) {
  const now = performance.now();
  if (!force && now - hudAt < HUD_PERIOD_MS) return;
  hudAt = now;
  if (autonomy.dirty || autonomy.pending || autonomy.place) drawAutonomy();
  const lines = hudLines();
  const text = JSON.stringify(lines);
  if (text === hudText) return;
  hudText = text;
  hudShown = lines;
  drawHud(hudCanvas, lines);
  hudTexture.needsUpdate = true;
  $("hud").replaceChildren(...lines.map((l) => {
    const p = document.createElement("p");
    p.id = `hud-${l.id}`;
    p.className = l.level;
    p.textContent = l.text;
    return p;
  }));
}

function drawAutonomy() {
  const drawn = autonomy.draw(proposalCanvas, attentionCanvas, {
    xr: !!state.xr, head: cameraSource.capturePose() ?? state.robotHead, hfovDeg: CAMERA_HFOV_DEG,
    image: cameraSource.size});  // where the shown picture was taken
  if (drawn.card) proposalTexture.needsUpdate = true;
  if (drawn.overlay) attentionTexture.needsUpdate = true;
  proposalMesh.visible = !!drawn.proposal && !!state.xr;  // the flat view has the page's own card
}

setInterval(() => {
  state.fps = state.frames;
  state.frames = 0;
}, 1000);

// ---- the loop -------------------------------------------------------------------------------------------------
const pixelRequests = [];
renderer.setAnimationLoop((time, frame) => {
  const now = performance.now();
  if (state.lastFrameAt !== null) {
    state.frameTimes.push(now - state.lastFrameAt);
    if (state.frameTimes.length > 5000) state.frameTimes.splice(0, 1000);
  }
  state.lastFrameAt = now;
  state.frames += 1;
  state.frameCount += 1;
  if (frame) xrFrame(frame, now);
  else flatFrame();
  poseChannel.flush();  // the frame's poses and Joy taken by the channel, as one binary message
  placePanels();
  comfort.update(state, holding() && state.headOn, now);
  updateHud();
  renderer.render(scene, camera);
  if (pixelRequests.length) readPixels(pixelRequests.splice(0));
  state.workTimes.push(performance.now() - now);
  if (state.workTimes.length > 5000) state.workTimes.splice(0, 1000);
});

function readPixels(requests) {
  const gl = renderer.getContext();
  const eye = state.xr ? renderer.xr.getCamera().cameras[0]?.viewport : null;  // the left eye's, in the XR layer
  const [x0, y0, w, h] = eye ? [eye.x, eye.y, eye.z, eye.w] : [0, 0, gl.drawingBufferWidth, gl.drawingBufferHeight];
  for (const {resolve, at, size} of requests) {  // at: {u, v} in the left eye (0, 0 bottom left), else its centre
    const {u, v} = at ?? {u: 0.5, v: 0.5};
    const x = Math.floor(x0 + u * w - size / 2);
    const y = Math.floor(y0 + v * h - size / 2);
    const data = new Uint8Array(size * size * 4);
    gl.readPixels(x, y, size, size, gl.RGBA, gl.UNSIGNED_BYTE, data);
    resolve(Array.from(data));
  }
}

/** Where a point of the status panel (fx, fy from 0, 0 top left to 1, 1 of its canvas) is in the left eye's view,
 * as readPixels takes it. */
function statusPoint(fx, fy) {
  const eye = state.xr ? renderer.xr.getCamera().cameras[0] : camera;
  const p = statusMesh.localToWorld(new THREE.Vector3((fx - 0.5) * 0.56, (0.5 - fy) * 0.56, 0)).project(eye);
  return {u: (p.x + 1) / 2, v: (p.y + 1) / 2};
}

// ---- entering VR ----------------------------------------------------------------------------------------------
async function enterVr() {
  audio.unlock();
  try {
    const session = await navigator.xr.requestSession("immersive-vr", {requiredFeatures: ["local-floor"],
                                                                           optionalFeatures: ["hand-tracking"]});
    session.addEventListener("end", () => {
      state.xr = null;
      $("enter-vr").textContent = t("operator.enter_vr");
      document.body.classList.remove("in-vr");
      menuDirty = true;
      resize();
    });
    await renderer.xr.setSession(session);
    state.xr = session;
    document.body.classList.add("in-vr");
    $("enter-vr").textContent = t("operator.exit_vr");
    const rates = Array.from(session.supportedFrameRates || []);
    if (rates.length && session.updateTargetFrameRate) {
      const best = Math.max(...rates);
      session.updateTargetFrameRate(best).catch((err) => say(`frame rate ${best} Hz refused: ${err.message}`,
                                                             "warning"));
    }
    menuDirty = true;
  } catch (err) {
    say(`VR could not start: ${err.message}`, "error");
  }
}

$("enter-vr").addEventListener("click", () => {
  if (state.xr) state.xr.end();
  else enterVr();
});

async function checkVr() {
  const button = $("enter-vr");
  let ok = false;
  try {
    ok = !!navigator.xr && await navigator.xr.isSessionSupported("immersive-vr");
  } catch { /* no WebXR */ }
  button.disabled = !ok;
  $("vr-note").textContent = ok ? "" : window.isSecureContext ? t("operator.no_headset") : t("operator.needs_https");
}
checkVr();

// ---- the flat view: mouse-look and keys -------------------------------------------------------------------------
const view = renderer.domElement;
view.addEventListener("pointerdown", (e) => {
  state.flat.dragging = {x: e.clientX, y: e.clientY};
  view.setPointerCapture(e.pointerId);
  audio.unlock();
});
view.addEventListener("pointerup", (e) => {
  state.flat.dragging = false;
  view.releasePointerCapture(e.pointerId);
});
view.addEventListener("pointermove", (e) => {
  const f = state.flat, from = f.dragging;
  if (!from || state.xr) return;
  f.dragging = {x: e.clientX, y: e.clientY};
  f.yaw -= THREE.MathUtils.degToRad((e.clientX - from.x) * FLAT_LOOK_DEG_PER_PX);
  f.pitch = THREE.MathUtils.clamp(f.pitch - THREE.MathUtils.degToRad((e.clientY - from.y) * FLAT_LOOK_DEG_PER_PX),
                                  -Math.PI * 0.45, Math.PI * 0.45);
});

const ARROWS = {ArrowLeft: "left", ArrowRight: "right", ArrowUp: "top", ArrowDown: "bottom"};
window.addEventListener("keydown", (e) => {
  if (e.target instanceof HTMLInputElement || e.metaKey || e.ctrlKey || e.altKey) return;
  audio.unlock();
  const key = e.key.length === 1 ? e.key.toUpperCase() : e.key;
  if (e.key === "Escape") estop();
  else if (["X", "Y", "A", "B"].includes(key)) pressMenuButton(null, key);
  else if (ARROWS[e.key] && nav.open) { arrows(e.key, true); menuDirty = true; }
  else if (ARROWS[e.key] && state.statusPanel === "motivation") {
    if (e.key === "ArrowUp" || e.key === "ArrowDown") panelMove(e.key === "ArrowUp" ? -1 : 1);
    else changeMotivation(e.key === "ArrowRight" ? 1 : -1);
  }
  else if (ARROWS[e.key] && state.statusPanel === "dialog") {
    if (e.key === "ArrowUp" || e.key === "ArrowDown") moveInDialog(0, e.key === "ArrowUp" ? -1 : 1);
    else moveInDialog(e.key === "ArrowRight" ? 1 : -1, 0);
  }
  else if (e.key === "Enter" && !e.repeat && panelPick()) { /* the dialog panel's pick */ }
  else if (e.key === "Tab" && nav.open) { nav.step(e.shiftKey ? -1 : 1); menuDirty = true; }
  else if (e.key === "Enter" && nav.open) selectInMenu();
  else if (e.key === "Backspace" && nav.open) { nav.back(); menuDirty = true; }
  else if ((e.key === "ArrowRight" || e.key === "ArrowLeft") && !e.repeat && autonomy.pending) {
    autonomy.decide(e.key === "ArrowRight" ? "accept" : "reject");
  }
  else if (key === "E" && !e.repeat) toggleControl();
  else if (key === "C" && !e.repeat) calibrate();
  else if (key === "T" && !e.repeat) talk(true);
  else return;
  e.preventDefault();
});
window.addEventListener("keyup", (e) => {
  if (e.key.toUpperCase() === "T") talk(false);
  if (ARROWS[e.key]) arrows(e.key, false);
});

// On a ring the arrow keys are a digital thumbstick: two held together point at a diagonal item. In a list,
// up and down step.
const heldArrows = new Set();
function arrows(key, down) {
  if (!down) { heldArrows.delete(key); return; }
  heldArrows.add(key);
  if (nav.level?.kind !== "ring") { nav.direction(ARROWS[key]); return; }
  let x = 0, y = 0;
  for (const k of heldArrows) {
    x += {ArrowLeft: -1, ArrowRight: 1}[k] || 0;
    y += {ArrowDown: -1, ArrowUp: 1}[k] || 0;
  }
  if (x || y) nav.stick(x / Math.hypot(x, y), y / Math.hypot(x, y), performance.now());
}
$("talk").addEventListener("pointerdown", () => talk(true));
for (const type of ["pointerup", "pointerleave", "pointercancel"]) {
  $("talk").addEventListener(type, () => { if (audio.talking) talk(false); });
}
$("estop").addEventListener("click", estop);

// What tests and the bench read (no control goes through here).
window.operator = {
  ros, state, nav, camera: cameraSource, audio, poses: poseChannel, autonomy, proposalMesh, attentionCanvas,
  hands: handActions, comfort,
  hud: () => hudShown.map((l) => ({...l})),  // [{id, text, level}]: what the HUD shows (scripts/screenshots.py)
  readPixels: (at = null, size = 64) => new Promise((resolve) => pixelRequests.push({resolve, at, size})),
  statusCanvas, statusPoint, statusPanels: {motorBar, motivationBar, hardwareRow, dialogRow, dialogFace,
                                            hardwareRows: () => hardwareRows(state.robotHardware, state.hardware, t)},
};
window.operator.panel = panelAnchor;  // the camera panel's anchor: its rotation is where the panel hangs
