// The status panels (issue 42) drawn on a 2D canvas: the headset shows the canvas as a texture beside the reduced
// camera view, the dashboard shows the same canvas in the page. One drawing for both, from the topics' messages:
// /vr_teleop/status/motors (vr_teleop_msgs/MotorsStatus), /vr_teleop/status/motivation (vr_teleop_msgs/Motivation),
// /vr_teleop/status/robot_hardware (vr_teleop_msgs/RobotHardwareStatus) with /vr_teleop/status/hardware (the
// server's own, vr_teleop_msgs/HardwareStatus); the dialog panel from the menus (/vr_teleop/menus: the speech menu's
// sentences and the emotions), whose pick runs a sentence and a face together through the menus' own items.
// Large type on a dark ground: at a Quest 3's ~25 pixels per degree a 36 px line on the 1024 px canvas is ~20 px tall.

import {COLORS, FONT, fitText, roundRect} from "./operator/panels.js";

export const PANEL_SIZE = {width: 1024, height: 1024};
export const PANELS = ["motors", "motivation", "hardware", "dialog"];
const TREND_WINDOW_MS = 5000;   // a variable's trend: its change over the last five seconds

/** How each motivation variable moved lately: rising, falling or steady (from the values the topic brought). */
export class Trends {
  constructor() { this.history = new Map(); }

  add(msg, now) {
    msg.name.forEach((name, i) => {
      const h = this.history.get(name) || [];
      h.push([now, msg.value[i]]);
      while (h.length > 2 && now - h[0][0] > TREND_WINDOW_MS) h.shift();
      this.history.set(name, h);
    });
  }

  /** +1 rising, -1 falling, 0 steady (a change under a thousandth of the range is steady). */
  trend(name, range) {
    const h = this.history.get(name);
    if (!h || h.length < 2) return 0;
    const change = h[h.length - 1][1] - h[0][1];
    return Math.abs(change) < 1e-3 * range ? 0 : Math.sign(change);
  }
}

/** What a motor's row says: clamped (the teleop mapping cut a command to the joint's limit), holding (torque on, it
 * keeps its position) or free (torque off). */
export function motorCondition(mode, clamped) {
  if (clamped) return "clamped";
  return mode === "off" ? "free" : "holding";
}

function frame(ctx, width, height, title, hint) {
  ctx.clearRect(0, 0, width, height);
  ctx.fillStyle = "rgba(10, 16, 24, 0.9)";
  roundRect(ctx, 0, 0, width, height, 36);
  ctx.fill();
  ctx.textBaseline = "middle";
  ctx.textAlign = "left";
  ctx.fillStyle = COLORS.info;
  ctx.font = `700 52px ${FONT}`;
  ctx.fillText(title, 40, 56);
  ctx.fillStyle = COLORS.muted;
  ctx.font = `500 30px ${FONT}`;
  ctx.fillText(fitText(ctx, hint, width - 80), 40, height - 36);
}

function bar(ctx, x, y, w, h, fraction, color, marks = []) {
  ctx.fillStyle = "rgba(60, 76, 96, 0.95)";
  roundRect(ctx, x, y, w, h, h / 2);
  ctx.fill();
  const f = Math.min(1, Math.max(0, fraction));
  if (f > 0) {
    ctx.fillStyle = color;
    roundRect(ctx, x, y, Math.max(h, w * f), h, h / 2);
    ctx.fill();
  }
  ctx.fillStyle = "#ffffff";
  for (const m of marks) ctx.fillRect(x + w * m - 2, y - 6, 4, h + 12);
}

/** Where motor i's bar is on a panel of `width` x `height` with n motors: each motor is two lines, its name,
 * temperature, mode and state above, its position in its range as a bar the panel's width below. */
export function motorBar(height, n, i, width = PANEL_SIZE.width) {
  const top = 150, rowH = Math.min(110, (height - top - 70) / Math.max(1, n));
  const size = Math.min(36, rowH * 0.36);
  const row = top + rowH * i + size * 0.6;
  return {x: 40, y: row + size * 0.75, w: width - 80, h: size * 0.6, size, row};
}

/** Where variable i's bar is on a motivation panel of `width`. */
export function motivationBar(width, i) {
  const y = 130 + 190 * i;
  return {x: 50, y: y + 84, w: width - 100, h: 44, row: y};
}

/** msg: the newest MotorsStatus (null before the first); clamped: the joints the teleop state calls clamped; hint:
 * the line at the bottom (how the panel is worked where it is shown). */
export function drawMotors(canvas, msg, clamped, t, hint) {
  const ctx = canvas.getContext("2d");
  const {width, height} = canvas;
  frame(ctx, width, height, t("panel.motors"), hint);
  if (!msg) {
    ctx.fillStyle = COLORS.muted;
    ctx.font = `500 36px ${FONT}`;
    ctx.fillText(t("panel.waiting"), 40, 160);
    return;
  }
  const n = msg.name.length;
  ctx.font = `500 28px ${FONT}`;
  ctx.fillStyle = COLORS.muted;
  ctx.fillText(fitText(ctx, t("panel.motors_legend"), width - 80), 40, 104);
  const modes = {on: t("panel.mode_on"), off: t("panel.mode_off"), brake: t("panel.mode_brake")};
  const conditions = {clamped: t("panel.clamped"), holding: t("panel.holding"), free: t("panel.free")};
  msg.name.forEach((name, i) => {
    const b = motorBar(height, n, i, width), y = b.row;
    const condition = motorCondition(msg.mode[i], clamped.has(name));
    const fault = msg.fault?.[i];
    ctx.font = `600 ${b.size}px ${FONT}`;
    ctx.textAlign = "right";  // from the right: temperature, mode, state (or the fault the motor reports)
    ctx.fillStyle = {clamped: COLORS.warning, holding: COLORS.ok, free: COLORS.muted}[condition];
    if (fault) ctx.fillStyle = COLORS.error;
    const state = fault || conditions[condition];
    ctx.fillText(state, width - 40, y);
    const right = width - 40 - ctx.measureText(state).width - 30;
    ctx.fillStyle = msg.mode[i] === "on" ? COLORS.info : COLORS.warning;
    const mode = modes[msg.mode[i]] ?? msg.mode[i];
    ctx.fillText(mode, right, y);
    const temperature = `${msg.temperature[i].toFixed(0)} °C`;
    const right2 = right - ctx.measureText(mode).width - 30;
    ctx.fillStyle = COLORS.info;
    ctx.fillText(temperature, right2, y);
    ctx.textAlign = "left";
    ctx.fillStyle = fault ? COLORS.error : COLORS.info;
    ctx.fillText(fitText(ctx, name, right2 - ctx.measureText(temperature).width - 70), 40, y);
    const color = condition === "clamped" ? COLORS.warning : fault ? COLORS.error : "#2f80ed";
    bar(ctx, b.x, b.y, b.w, b.h, msg.position_normalized[i], color);
  });
}

/** msg: the newest Motivation; trends: a Trends; selected: the row the controls act on (-1: none). */
export function drawMotivation(canvas, msg, trends, selected, t, hint) {
  const ctx = canvas.getContext("2d");
  const {width, height} = canvas;
  frame(ctx, width, height, t("panel.motivation"), hint);
  if (!msg) {
    ctx.fillStyle = COLORS.muted;
    ctx.font = `500 36px ${FONT}`;
    ctx.fillText(t("panel.waiting"), 40, 160);
    return;
  }
  msg.name.forEach((name, i) => {
    const b = motivationBar(width, i), y = b.row, rowH = 190;
    const range = msg.max[i] - msg.min[i];
    const at = (v) => (v - msg.min[i]) / range;
    if (i === selected) {
      ctx.strokeStyle = "#ffffff";
      ctx.lineWidth = 5;
      roundRect(ctx, 20, y - 10, width - 40, rowH - 20, 22);
      ctx.stroke();
    }
    const level = msg.level[i];
    ctx.font = `700 44px ${FONT}`;
    ctx.fillStyle = level === "ok" ? COLORS.info : COLORS.warning;
    const words = {pain: t("motivation.pain"), frustration: t("motivation.frustration"),
                   curiosity: t("motivation.curiosity"), fatigue: t("motivation.fatigue")};
    ctx.fillText(words[name] ?? name, 50, y + 36);  // a lab's own variables by their own names
    const trend = trends.trend(name, range);
    ctx.textAlign = "right";
    ctx.fillText(`${msg.value[i].toFixed(1)} ${["▼", "▶", "▲"][trend + 1]}`, width - 50, y + 36);
    ctx.textAlign = "left";
    const marks = [msg.has_low[i] && at(msg.low[i]), msg.has_high[i] && at(msg.high[i])].filter((m) => m !== false);
    bar(ctx, b.x, b.y, b.w, b.h, at(msg.value[i]), level === "ok" ? "#2f80ed" : COLORS.warning, marks);
    ctx.font = `500 28px ${FONT}`;
    ctx.fillStyle = COLORS.muted;
    ctx.fillText(`${msg.min[i]}`, 50, y + 152);
    ctx.textAlign = "right";
    ctx.fillText(`${msg.max[i]}`, width - 50, y + 152);
    ctx.textAlign = "left";
  });
}

/** The raise/lower step of a variable: a tenth of its range. */
export function motivationStep(msg, i) {
  return (msg.max[i] - msg.min[i]) / 10;
}

/** The largest font of `weight` from `size` down to `min` px at which `text` fits `maxWidth`; set on ctx. At `min`,
 * text still too wide ends in a visible "…" (fitText), never cut without a mark. */
function fitFont(ctx, text, maxWidth, size, min, weight = 600) {
  let px = size;
  ctx.font = `${weight} ${px}px ${FONT}`;
  while (px > min && ctx.measureText(text).width > maxWidth) {
    px -= 2;
    ctx.font = `${weight} ${px}px ${FONT}`;
  }
  return fitText(ctx, text, maxWidth);
}

/** `text` broken at spaces into at most `maxLines` lines of `maxWidth` at ctx's font; a last line that still does
 * not fit ends in a visible "…". */
export function wrapText(ctx, text, maxWidth, maxLines = 2) {
  const words = text.split(/\s+/).filter(Boolean), lines = [];
  while (words.length && lines.length < maxLines) {
    let line = words.shift();
    while (words.length && ctx.measureText(`${line} ${words[0]}`).width <= maxWidth) line += ` ${words.shift()}`;
    lines.push(line);
  }
  if (words.length) lines[lines.length - 1] = fitText(ctx, `${lines[lines.length - 1]} ${words.join(" ")}`, maxWidth);
  return lines.map((line) => fitText(ctx, line, maxWidth));  // a single word wider than the panel: marked, not cut
}

// ---- hardware ------------------------------------------------------------------------------------------------------

const TEMPERATURE_SCALE_C = 100;  // a temperature's bar: 0 to 100 °C

/** The hardware panel's rows, one figure a row: a heading for the robot (its backend; measured or simulated), its
 * connection, each figure its backend gives (a bar for shares and temperatures), each it cannot give with why, then a
 * heading for this server and its CPU, load, memory and temperature. robot, server: the newest
 * RobotHardwareStatus and HardwareStatus (null before the first). A row: {kind: heading | figure | missing, label,
 * value, fraction (0..1, or null: no bar), level (info, ok, warning, error, muted)}. */
export function hardwareRows(robot, server, t) {
  const rows = [];
  const heading = (label) => rows.push({kind: "heading", label, value: "", fraction: null, level: "info"});
  const figure = (label, value, fraction = null, level = "info") =>
    rows.push({kind: "figure", label, value, fraction, level});
  const percent = (v) => `${v.toFixed(0)} %`;
  const celsius = (v) => `${v.toFixed(0)} °C`;
  if (robot) {
    const backends = {sim: t("panel.hw_backend_sim"), ros: t("panel.hw_backend_ros"),
                      luxai: t("panel.hw_backend_luxai")};
    const backend = backends[robot.backend] ?? robot.backend;  // a lab's own backend by its own name
    heading(robot.source === "modelled" ? t("panel.hw_robot_modelled", {backend})
      : t("panel.hw_robot_measured", {backend}));
    figure(t("panel.hw_connection"), robot.connected ? t("panel.hw_connected") : t("panel.hw_disconnected"), null,
           robot.connected ? "ok" : "error");
    const labels = {motor_temperature: t("panel.hw_motor_temperature", {motor: robot.hottest_motor || "–"}),
                    motor_voltage: t("panel.hw_motor_voltage"), battery: t("panel.hw_battery"),
                    cpu: t("panel.hw_robot_cpu"), memory: t("panel.hw_robot_memory"),
                    temperature: t("panel.hw_robot_temperature")};
    const why = {interface: t("panel.hw_why_interface"), no_reading: t("panel.hw_why_no_reading"),
                 not_modelled: t("panel.hw_why_not_modelled")};
    const given = {
      motor_temperature: () => figure(labels.motor_temperature, celsius(robot.motor_temperature_c),
                                      robot.motor_temperature_c / TEMPERATURE_SCALE_C),
      motor_voltage: () => figure(labels.motor_voltage, `${robot.motor_voltage_min_v.toFixed(1)} V`),
      battery: () => figure(labels.battery, percent(robot.battery_percent), robot.battery_percent / 100,
                            robot.battery_percent < 20 ? "warning" : "info"),
      cpu: () => figure(labels.cpu, percent(robot.cpu_percent), robot.cpu_percent / 100,
                        robot.cpu_percent >= 90 ? "warning" : "info"),
      memory: () => figure(labels.memory, percent(robot.memory_percent), robot.memory_percent / 100,
                           robot.memory_percent >= 90 ? "warning" : "info"),
      temperature: () => figure(labels.temperature, celsius(robot.temperature_c),
                                robot.temperature_c / TEMPERATURE_SCALE_C),
    };
    for (const name of Object.keys(given)) {
      if (robot[`has_${name}`]) given[name]();
      else {
        const i = robot.missing.indexOf(name);
        const reason = i >= 0 ? why[robot.missing_reason[i]] ?? robot.missing_reason[i] : t("panel.hw_why_no_reading");
        rows.push({kind: "missing", label: labels[name], value: reason, fraction: null, level: "muted"});
      }
      if (name === "motor_voltage") {  // the motors' faults, beside their other figures
        figure(t("panel.hw_motor_faults"), String(robot.motor_faults), null, robot.motor_faults ? "error" : "ok");
      }
    }
  } else {
    rows.push({kind: "missing", label: t("panel.hw_robot"), value: t("panel.waiting"), fraction: null,
               level: "muted"});
  }
  heading(t("panel.hw_server"));
  if (server) {
    figure(t("panel.hw_cpu"), percent(server.cpu_percent), server.cpu_percent / 100,
           server.cpu_percent >= 90 ? "warning" : "info");
    figure(t("panel.hw_load"), server.load_1min.toFixed(2));
    figure(t("panel.hw_memory"), percent(server.memory_percent), server.memory_percent / 100,
           server.memory_percent >= 90 ? "warning" : "info");
    if (server.has_temperature) {
      figure(t("panel.hw_temperature"), celsius(server.temperature_c), server.temperature_c / TEMPERATURE_SCALE_C);
    } else {
      rows.push({kind: "missing", label: t("panel.hw_temperature"), value: t("panel.hw_why_no_sensor"),
                 fraction: null, level: "muted"});
    }
  } else {
    rows.push({kind: "missing", label: t("panel.hw_cpu"), value: t("panel.waiting"), fraction: null, level: "muted"});
  }
  return rows;
}

/** Where row i of n is on a hardware panel of `width` x `height`: its text line at `y`, its bar (for a figure
 * that has one) under it. */
export function hardwareRow(height, n, i, width = PANEL_SIZE.width) {
  const top = 112, rowH = Math.min(76, (height - top - 76) / Math.max(1, n));
  const row = top + rowH * i;
  const size = Math.min(36, rowH * 0.48);
  return {row, y: row + size * 0.62, size, bar: {x: 40, y: row + size * 1.25, w: width - 80, h: rowH * 0.24}};
}

/** robot, server: the newest RobotHardwareStatus and HardwareStatus (null before the first). */
export function drawHardware(canvas, robot, server, t, hint) {
  const ctx = canvas.getContext("2d");
  const {width, height} = canvas;
  frame(ctx, width, height, t("panel.hardware"), hint);
  const rows = hardwareRows(robot, server, t);
  rows.forEach((r, i) => {
    const place = hardwareRow(height, rows.length, i, width);
    const color = COLORS[r.level] ?? COLORS.info;
    if (r.kind === "heading") {
      ctx.fillStyle = "#6aa9ff";
      ctx.textAlign = "left";
      ctx.fillText(fitFont(ctx, r.label, width - 80, place.size, 26, 700), 40, place.y);
      ctx.fillRect(40, place.row + place.size * 1.3, width - 80, 3);
      return;
    }
    ctx.textAlign = "right";
    ctx.fillStyle = r.kind === "missing" ? COLORS.muted : color;
    const value = fitFont(ctx, r.value, (width - 80) * (r.kind === "missing" ? 0.55 : 0.4), place.size, 24,
                          r.kind === "missing" ? 500 : 700);
    ctx.fillText(value, width - 40, place.y);
    const room = width - 80 - ctx.measureText(value).width - 24;
    ctx.textAlign = "left";
    ctx.fillStyle = r.kind === "missing" ? COLORS.muted : COLORS.info;
    ctx.fillText(fitFont(ctx, r.label, room, place.size, 24, 500), 40, place.y);
    if (r.fraction !== null) {
      const b = place.bar;
      bar(ctx, b.x, b.y, b.w, b.h, r.fraction, r.level === "info" ? "#2f80ed" : color);
    }
  });
}

// ---- dialog --------------------------------------------------------------------------------------------------------

/** What the dialog panel offers, from the menus message's items (translated): the speech menu's sentences (the
 * robot's language, as the server filled them in) and each face once, the quick ones first. {sentences: [{id,
 * label}], faces: [{id, label, name}]}: the ids are the menus' own items, run through /vr_teleop/menu/select. */
export function dialogChoices(items) {
  // each choice's `args` for /vr_teleop/menu/select: the face is shown without the words its emotion says alone,
  // since the chosen sentence is what the robot says with it
  const sentences = items.filter((i) => i.parent === "speech.sentences" && i.command === "say")
    .sort((a, b) => a.position - b.position).map((i) => ({id: i.id, label: i.label, args: ""}));
  const faces = [], seen = new Set();
  for (const item of items) {
    if (item.command !== "show_emotion") continue;
    let name = "";
    try { name = String(JSON.parse(item.args || "{}").name || ""); } catch { continue; }
    if (!name || seen.has(name)) continue;
    seen.add(name);
    faces.push({id: item.id, label: item.label, name, args: JSON.stringify({say: ""})});
  }
  return {sentences, faces};
}

/** The choice moved: up and down through the sentences (dy), left and right through the faces (dx), both around. */
export function moveDialog(choice, choices, dx, dy) {
  const around = (i, d, n) => (n ? (i + d + n) % n : 0);
  return {sentence: around(choice.sentence, dy, choices.sentences.length),
          face: around(choice.face, dx, choices.faces.length)};
}

const DIALOG_ROW = 86, DIALOG_TOP = 150, DIALOG_LIST_BOTTOM = 760;

/** The first sentence shown and how many fit, so that the chosen one is in view. */
export function dialogWindow(count, chosen) {
  const fit = Math.floor((DIALOG_LIST_BOTTOM - DIALOG_TOP) / DIALOG_ROW);
  const first = Math.max(0, Math.min(chosen - Math.floor(fit / 2), count - fit));
  return {first, fit};
}

/** Where sentence i's row is (its box) on a dialog panel of `width`, with `count` sentences and `chosen` the
 * chosen one; null when it is scrolled out of view. */
export function dialogRow(width, count, chosen, i) {
  const {first, fit} = dialogWindow(count, chosen);
  if (i < first || i >= first + fit) return null;
  return {x: 24, y: DIALOG_TOP + (i - first) * DIALOG_ROW, w: width - 48, h: DIALOG_ROW - 10};
}

/** Where the face row is on a dialog panel of `width`: the chosen face in the middle, its neighbours beside. */
export function dialogFace(width) {
  return {x: 24, y: 800, w: width - 48, h: 110};
}

/** choices: dialogChoices(); choice: {sentence, face} indices; result: {text, level} of the last pick, or null. */
export function drawDialog(canvas, choices, choice, result, t, hint) {
  const ctx = canvas.getContext("2d");
  const {width, height} = canvas;
  frame(ctx, width, height, t("panel.dialog"), hint);
  ctx.font = `500 28px ${FONT}`;
  ctx.fillStyle = COLORS.muted;
  ctx.fillText(fitText(ctx, t("panel.dialog_sentences"), width - 80), 40, 116);
  const {sentences, faces} = choices;
  if (!sentences.length) {
    ctx.font = `500 34px ${FONT}`;
    ctx.fillText(fitText(ctx, t("panel.dialog_no_sentences"), width - 80), 40, DIALOG_TOP + 40);
  }
  sentences.forEach((s, i) => {
    const box = dialogRow(width, sentences.length, choice.sentence, i);
    if (!box) return;
    const chosen = i === choice.sentence;
    if (chosen) {
      ctx.fillStyle = "rgba(47, 128, 237, 0.55)";
      roundRect(ctx, box.x, box.y, box.w, box.h, 18);
      ctx.fill();
      ctx.strokeStyle = "#ffffff";
      ctx.lineWidth = 5;
      ctx.stroke();
    }
    ctx.font = `${chosen ? 700 : 500} 34px ${FONT}`;
    ctx.fillStyle = chosen ? "#ffffff" : COLORS.info;
    const lines = wrapText(ctx, s.label, box.w - 40, 2);
    const lineH = 36, top = box.y + box.h / 2 - (lines.length - 1) * lineH / 2;
    lines.forEach((line, k) => ctx.fillText(line, box.x + 20, top + k * lineH));
  });
  const first = dialogWindow(sentences.length, choice.sentence).first;
  ctx.fillStyle = COLORS.muted;
  ctx.font = `500 28px ${FONT}`;
  if (first > 0) ctx.fillText("▲", width - 60, DIALOG_TOP - 20);
  if (first + dialogWindow(sentences.length, choice.sentence).fit < sentences.length) {
    ctx.fillText("▼", width - 60, DIALOG_LIST_BOTTOM + 6);
  }
  const f = dialogFace(width);
  ctx.fillText(fitText(ctx, t("panel.dialog_face"), width - 80), 40, f.y - 14);
  if (faces.length) {
    ctx.fillStyle = "rgba(47, 128, 237, 0.55)";
    roundRect(ctx, width / 2 - 220, f.y + 8, 440, f.h - 16, 18);
    ctx.fill();
    ctx.strokeStyle = "#ffffff";
    ctx.lineWidth = 5;
    ctx.stroke();
    const at = (d) => faces[(choice.face + d + faces.length) % faces.length].label;
    ctx.textAlign = "center";
    ctx.fillStyle = "#ffffff";
    ctx.fillText(fitFont(ctx, at(0), 400, 44, 28, 700), width / 2, f.y + f.h / 2);
    ctx.fillStyle = COLORS.muted;
    if (faces.length > 1) {
      ctx.fillText(fitFont(ctx, `◀ ${at(-1)}`, 210, 32, 24, 500), 24 + 120, f.y + f.h / 2);
      ctx.fillText(fitFont(ctx, `${at(1)} ▶`, 210, 32, 24, 500), width - 24 - 120, f.y + f.h / 2);
    }
    ctx.textAlign = "left";
  }
  if (result) {
    ctx.fillStyle = COLORS[result.level] ?? COLORS.info;
    ctx.fillText(fitFont(ctx, result.text, width - 80, 30, 22, 500), 40, f.y + f.h + 36);
  }
}
