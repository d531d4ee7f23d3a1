// Supervised autonomy in the headset (issue 34): the proposal waiting for the teacher on a card above the HUD
// (what, why, how sure, a bar running down to its time-out, and the two thumbstick flicks that decide it), the
// attention target drawn over the camera panel, and the same card in the flat view's DOM with two buttons.
// The model (subscriptions, decisions, the geometry) is ../autonomy.js, shared with the dashboard.

import {AutonomyModel, attentionInImage, attentionText} from "../autonomy.js";
import {COLORS as PANEL_COLORS, FONT, fitText as fit, roundRect} from "./panels.js";

const COLORS = {...PANEL_COLORS, text: PANEL_COLORS.info, accept: PANEL_COLORS.ok, reject: PANEL_COLORS.error,
                bar: PANEL_COLORS.warning, face: PANEL_COLORS.warning, voice: "#4ea1ff"};
const REFUSAL_KEEP_MS = 6000;
// The two inputs that decide, never those that take control (right trigger), stop the robot (both thumbsticks
// clicked) or open menus (X Y A B): the right thumbstick pushed right or left, while no menu is open.
export const DECIDE_HINT = {xr: {accept: "right stick ▶", reject: "right stick ◀"},
                            flat: {accept: "→ key", reject: "← key"}};

/** The proposal card: p from AutonomyModel.current() (or null: a cleared canvas); hints: DECIDE_HINT.xr/flat. */
export function drawProposal(canvas, p, hints, note) {
  const ctx = canvas.getContext("2d");
  const {width, height} = canvas;
  ctx.clearRect(0, 0, width, height);
  if (!p) return;
  ctx.fillStyle = "rgba(10, 16, 24, 0.9)";
  roundRect(ctx, 0, 0, width, height, 28);
  ctx.fill();
  ctx.strokeStyle = COLORS.bar;
  ctx.lineWidth = 6;
  ctx.stroke();
  ctx.textBaseline = "middle";
  ctx.fillStyle = COLORS.text;
  ctx.font = `700 54px ${FONT}`;
  const more = p.others > 0 ? `  (+${p.others} more)` : "";
  ctx.fillText(fit(ctx, `ROBOT PROPOSES: ${p.label || p.action}${more}`, width - 260), 32, 52);
  ctx.textAlign = "right";
  ctx.fillStyle = COLORS.muted;
  ctx.font = `600 40px ${FONT}`;
  ctx.fillText(`${Math.round(100 * (p.confidence || 0))}% sure`, width - 32, 52);
  ctx.textAlign = "left";
  ctx.fillStyle = COLORS.text;
  ctx.font = `500 44px ${FONT}`;
  ctx.fillText(fit(ctx, p.reason ? `because ${p.reason}` : "(no reason given)", width - 64), 32, 118);
  // the countdown: the bar shrinks to the time-out, when the server does on_timeout
  const barY = 158, barH = 30;
  ctx.fillStyle = "rgba(159, 176, 195, 0.25)";
  roundRect(ctx, 32, barY, width - 64, barH, 12);
  ctx.fill();
  ctx.fillStyle = COLORS.bar;
  const left = (width - 64) * p.fraction;
  if (left > 0) {
    roundRect(ctx, 32, barY, Math.max(24, left), barH, 12);  // never narrower than its two rounded ends
    ctx.fill();
  }
  ctx.fillStyle = COLORS.muted;
  ctx.font = `600 40px ${FONT}`;
  if (note) ctx.fillStyle = COLORS.reject;
  ctx.fillText(fit(ctx, note || AutonomyModel.countdown(p), width / 2 - 48), 32, 240);
  ctx.font = `700 44px ${FONT}`;
  ctx.textAlign = "right";
  ctx.fillStyle = COLORS.accept;
  ctx.fillText(`accept: ${hints.accept}`, width - 32, 240);
  ctx.fillStyle = COLORS.reject;
  ctx.fillText(`reject: ${hints.reject}`, width - 32, 300);
  ctx.textAlign = "left";
}

/** The attention target over the camera picture: a box round the face, or a ring where it looks, or an arrow at
 * the edge towards a target outside the picture. place: attentionInImage(...); words: who and why. */
export function drawAttention(canvas, place, words) {
  const ctx = canvas.getContext("2d");
  const {width, height} = canvas;
  ctx.clearRect(0, 0, width, height);
  if (!place) return;
  ctx.lineWidth = 6;
  ctx.font = `700 18px ${FONT}`;
  ctx.textBaseline = "bottom";
  if (place.kind === "face") {
    const {u, v, w, h} = place.box;
    ctx.strokeStyle = COLORS.face;
    ctx.strokeRect(u * width, v * height, w * width, h * height);
    label(ctx, words, u * width, v * height - 6, COLORS.face);
    return;
  }
  const x = Math.min(width - 24, Math.max(24, place.u * width));
  const y = Math.min(height - 24, Math.max(24, place.v * height));
  ctx.strokeStyle = ctx.fillStyle = COLORS.voice;
  if (place.inside) {
    ctx.beginPath();
    ctx.arc(x, y, 26, 0, 2 * Math.PI);
    ctx.moveTo(x - 40, y);
    ctx.lineTo(x - 12, y);
    ctx.moveTo(x + 12, y);
    ctx.lineTo(x + 40, y);
    ctx.moveTo(x, y - 40);
    ctx.lineTo(x, y - 12);
    ctx.moveTo(x, y + 12);
    ctx.lineTo(x, y + 40);
    ctx.stroke();
    label(ctx, words, x - 40, y - 44, COLORS.voice);
    return;
  }
  const angle = Math.atan2(place.v - 0.5, place.u - 0.5);  // an arrow at the edge, pointing out towards it
  ctx.save();
  ctx.translate(x, y);
  ctx.rotate(angle);
  ctx.beginPath();
  ctx.moveTo(20, 0);
  ctx.lineTo(-16, -16);
  ctx.lineTo(-16, 16);
  ctx.closePath();
  ctx.fill();
  ctx.restore();
  label(ctx, words, Math.min(width - 260, Math.max(8, x - 60)), y > height / 2 ? y - 28 : y + 56, COLORS.voice);
}

function label(ctx, text, x, y, color) {
  ctx.fillStyle = "rgba(10, 16, 24, 0.75)";
  const w = ctx.measureText(text).width;
  ctx.fillRect(x - 4, y - 30, w + 8, 32);
  ctx.fillStyle = color;
  ctx.fillText(text, x, y);
}

/** The operator page's autonomy: the model, what the HUD says of it and the flat view's card. */
export class OperatorAutonomy {
  /** say(text, level): the HUD's message line; onLevel(): the level changed (the status menu shows it). */
  constructor(ros, {say, onLevel = () => {}}) {
    this.say = say;
    this.dirty = true;
    let level = "";
    this.model = new AutonomyModel(ros, {onChange: () => {
      this.dirty = true;
      if (this.model.level !== level) { level = this.model.level; onLevel(); }
    }});
    this.place = null;       // the attention target on the camera picture, as last drawn (tests read it)
    this.placed = null;      // {attention, image}: what it was drawn from
    this.overlayKey = "";
    this.busy = false;
    document.getElementById("proposal-accept")?.addEventListener("click", () => this.decide("accept"));
    document.getElementById("proposal-reject")?.addEventListener("click", () => this.decide("reject"));
  }

  get pending() {
    return this.model.pending.size > 0;
  }

  async decide(decision) {
    if (!this.pending || this.busy) return;
    this.busy = true;
    const label = this.model.current()?.label;
    try {
      await this.model.decide(decision);
      this.say(`${label}: ${decision === "accept" ? "accepted" : "rejected"}`, "ok");
    } catch (err) {
      this.say(`${decision} refused: ${err.message}`, "error");
    } finally {
      this.busy = false;
    }
  }

  /** The HUD's autonomy line, or null before the server speaks of autonomy. */
  hudLine() {
    const m = this.model;
    if (!m.level) return null;
    const looking = m.attention?.source ? ` · looking at ${attentionText(m.attention)}` : "";
    const head = m.owner("head") === "autonomy" ? " · head: autonomy" : "";
    return {id: "autonomy", text: `autonomy: ${m.level}${looking}${head}`,
            level: m.level === "teleoperated" ? "muted" : "info"};
  }

  /** Redraws the card (while a proposal waits: its countdown runs) and the attention overlay (when the target
   * moved on the picture). Returns what changed: {card, overlay, proposal}. */
  draw(cardCanvas, overlayCanvas, {xr, head, hfovDeg, image}) {
    const p = this.model.current();
    const refusal = this.model.refusal && performance.now() - this.model.refusal.at < REFUSAL_KEEP_MS
      ? this.model.refusal.text : "";
    const card = !!p || this.dirty;
    if (card) drawProposal(cardCanvas, p, xr ? DECIDE_HINT.xr : DECIDE_HINT.flat, refusal);
    const place = attentionInImage(this.model.attention, head, hfovDeg, image);
    const words = attentionText(this.model.attention);
    const key = JSON.stringify([place, words]);  // an unchanged overlay is neither redrawn nor uploaded again
    const overlay = key !== this.overlayKey;
    if (overlay) drawAttention(overlayCanvas, place, words);
    this.overlayKey = key;
    this.place = place;
    this.placed = {attention: this.model.attention, image};  // what the place was drawn from
    this.showCard(p, refusal);
    this.dirty = false;
    return {card, overlay, proposal: p};
  }

  showCard(p, refusal) {
    const card = document.getElementById("proposal");
    if (!card) return;
    card.hidden = !p;
    if (!p) return;
    document.getElementById("proposal-label").textContent = p.label || p.action;
    document.getElementById("proposal-reason").textContent = p.reason ? `because ${p.reason}` : "";
    document.getElementById("proposal-confidence").textContent = `${Math.round(100 * (p.confidence || 0))}% sure`;
    document.getElementById("proposal-left").textContent = refusal || `${p.left.toFixed(1)} s`;
    document.getElementById("proposal-bar").style.width = `${(100 * p.fraction).toFixed(1)}%`;
  }
}
