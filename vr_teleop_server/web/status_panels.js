// The status panels (issue 42) drawn on a 2D canvas: the headset shows the canvas as a texture beside the reduced
// camera view, the dashboard shows the same canvas in the page. One drawing for both, from the topics' messages:
// /vr_teleop/status/motors (vr_teleop_msgs/MotorsStatus) and /vr_teleop/status/motivation (vr_teleop_msgs/Motivation).
// Large type on a dark ground: at a Quest 3's ~25 pixels per degree a 36 px line on the 1024 px canvas is ~20 px tall.

import {COLORS, FONT, fitText, roundRect} from "./operator/panels.js";

export const PANEL_SIZE = {width: 1024, height: 1024};
export const PANELS = ["motors", "motivation"];
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
