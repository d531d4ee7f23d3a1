// The status panels (issue 42) drawn on a 2D canvas: the headset shows the canvas as a texture beside the reduced
// camera view, the dashboard shows the same canvas in the page. One drawing for both, from the topics' messages:
// /vr_teleop/status/motors (vr_teleop_msgs/MotorsStatus) and /vr_teleop/status/motivation (vr_teleop_msgs/Motivation).
// Large type on a dark ground: at a Quest 3's ~25 pixels per degree a 36 px line on the 1024 px canvas is ~20 px tall.

import {COLORS, FONT, fitText, roundRect} from "./operator/panels.js";

export const PANEL_SIZE = {width: 1024, height: 1024};
export const PANELS = ["motors", "motivation"];
const TREND_WINDOW_MS = 5000;   // a variable's trend: its change over the last five seconds
const BAR = {x: 330, w: 380};   // where the bars sit in a row

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

/** Where motor i's bar is on a panel of `height` with n motors (its row's text is centred on y + h / 2). */
export function motorBar(height, n, i) {
  const top = 110, rowH = Math.min(80, (height - top - 80) / Math.max(1, n));
  const size = Math.min(36, rowH * 0.55);
  const y = top + rowH * (i + 0.5) + 10;
  return {x: BAR.x, y: y - size * 0.35, w: BAR.w, h: size * 0.7, top, size, row: y};
}

/** Where variable i's bar is on a motivation panel of `width`. */
export function motivationBar(width, i) {
  const y = 130 + 190 * i;
  return {x: 50, y: y + 84, w: width - 100, h: 44, row: y};
}

/** msg: the newest MotorsStatus (null before the first); clamped: the joints the teleop state calls clamped. */
export function drawMotors(canvas, msg, clamped, t) {
  const ctx = canvas.getContext("2d");
  const {width, height} = canvas;
  frame(ctx, width, height, t("panel.motors"), t("panel.close_hint"));
  if (!msg) {
    ctx.fillStyle = COLORS.muted;
    ctx.font = `500 36px ${FONT}`;
    ctx.fillText(t("panel.waiting"), 40, 160);
    return;
  }
  const n = msg.name.length;
  const {top, size} = motorBar(height, n, 0);
  ctx.font = `500 ${Math.round(size * 0.8)}px ${FONT}`;
  ctx.fillStyle = COLORS.muted;
  const columns = [[t("panel.joint"), 40], [t("panel.position"), BAR.x], [t("panel.temperature"), BAR.x + BAR.w + 24],
                   [t("panel.mode"), BAR.x + BAR.w + 150], [t("panel.condition"), BAR.x + BAR.w + 270]];
  for (const [word, x] of columns) ctx.fillText(word, x, top - 10);
  msg.name.forEach((name, i) => {
    const b = motorBar(height, n, i), y = b.row;
    const condition = motorCondition(msg.mode[i], clamped.has(name));
    const fault = msg.fault?.[i];
    ctx.font = `600 ${size}px ${FONT}`;
    ctx.fillStyle = fault ? COLORS.error : COLORS.info;
    ctx.fillText(fitText(ctx, name, BAR.x - 60), 40, y);
    const color = condition === "clamped" ? COLORS.warning : fault ? COLORS.error : "#2f80ed";
    bar(ctx, b.x, b.y, b.w, b.h, msg.position_normalized[i], color);
    ctx.fillStyle = COLORS.info;
    ctx.fillText(`${msg.temperature[i].toFixed(0)} °C`, BAR.x + BAR.w + 24, y);
    ctx.fillStyle = msg.mode[i] === "on" ? COLORS.info : COLORS.warning;
    const modes = {on: t("panel.mode_on"), off: t("panel.mode_off"), brake: t("panel.mode_brake")};
    ctx.fillText(modes[msg.mode[i]] ?? msg.mode[i], BAR.x + BAR.w + 150, y);
    ctx.fillStyle = {clamped: COLORS.warning, holding: COLORS.ok, free: COLORS.muted}[condition];
    const conditions = {clamped: t("panel.clamped"), holding: t("panel.holding"), free: t("panel.free")};
    ctx.fillText(fitText(ctx, fault || conditions[condition], width - (BAR.x + BAR.w + 290)), BAR.x + BAR.w + 270, y);
  });
}

/** msg: the newest Motivation; trends: a Trends; selected: the row the controls act on (-1: none). */
export function drawMotivation(canvas, msg, trends, selected, t) {
  const ctx = canvas.getContext("2d");
  const {width, height} = canvas;
  frame(ctx, width, height, t("panel.motivation"), t("panel.motivation_hint"));
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
