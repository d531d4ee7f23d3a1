// Text panels drawn on 2D canvases, shown in the 3D view as textures: the heads-up display and the radial menu.
// Large type on dark backgrounds: a headset's pixels are big, and the camera image behind is busy.

export const COLORS = {info: "#e8eef5", ok: "#7ee2a8", warning: "#ffd166", error: "#ff6b6b", muted: "#9fb0c3"};
export const FONT = "system-ui, 'DejaVu Sans', sans-serif";

export function roundRect(ctx, x, y, w, h, r) {
  ctx.beginPath();
  ctx.moveTo(x + r, y);
  ctx.arcTo(x + w, y, x + w, y + h, r);
  ctx.arcTo(x + w, y + h, x, y + h, r);
  ctx.arcTo(x, y + h, x, y, r);
  ctx.arcTo(x, y, x + w, y, r);
  ctx.closePath();
}

export function fitText(ctx, text, maxWidth) {
  if (ctx.measureText(text).width <= maxWidth) return text;
  let t = text;
  while (t.length > 1 && ctx.measureText(t + "…").width > maxWidth) t = t.slice(0, -1);
  return t + "…";
}

/** lines: [{text, level}] (level: info, ok, warning, error, muted); the last line (the latest message) may wrap
 * onto a second line rather than lose its end. */
export function drawHud(canvas, lines) {
  const ctx = canvas.getContext("2d");
  const {width, height} = canvas;
  ctx.clearRect(0, 0, width, height);
  ctx.fillStyle = "rgba(10, 16, 24, 0.82)";
  roundRect(ctx, 0, 0, width, height, 28);
  ctx.fill();
  const maxWidth = width - 56;
  let rows = lines.map((line) => ({...line}));
  let size = Math.min(44, Math.floor(height / (rows.length + 0.8)) * 0.8);
  ctx.font = `600 ${size}px ${FONT}`;
  const last = rows[rows.length - 1];
  if (last && ctx.measureText(last.text).width > maxWidth && rows.length < 6) {
    const words = last.text.split(" ");
    let first = "";
    while (words.length && ctx.measureText(`${first} ${words[0]}`.trim()).width <= maxWidth) {
      first = `${first} ${words.shift()}`.trim();
    }
    rows = [...rows.slice(0, -1), {...last, text: first}, {...last, text: words.join(" ")}];
    size = Math.min(44, Math.floor(height / (rows.length + 0.8)) * 0.8);
    ctx.font = `600 ${size}px ${FONT}`;
  }
  const step = height / (rows.length + 0.6);
  ctx.textBaseline = "middle";
  rows.forEach((line, i) => {
    ctx.fillStyle = COLORS[line.level] || COLORS.info;
    ctx.fillText(fitText(ctx, line.text, maxWidth), 28, step * (i + 0.8));
  });
}

/** The open menu: nav (a MenuNavigator), toggles (item id -> true/false), footer (the last result). */
function ringGeometry(width, height) {
  return {cx: width / 2, cy: height / 2 + 40, rx: 0.365 * width, ry: 0.33 * height};
}

/** A point of the menu (u, v from 0, 0 bottom left to 1, 1 top right) as the thumbstick pointing there would be:
 * x right, y up, 1 on the ring of items (hands.js points at the menu with this). */
export function menuStick(canvas, u, v) {
  const {cx, cy, rx, ry} = ringGeometry(canvas.width, canvas.height);
  return {x: (u * canvas.width - cx) / rx, y: (cy - (1 - v) * canvas.height) / ry};
}

export function drawMenu(canvas, nav, toggles, footer, hint) {
  const ctx = canvas.getContext("2d");
  const {width, height} = canvas;
  ctx.clearRect(0, 0, width, height);
  if (!nav.open) return;
  ctx.fillStyle = "rgba(10, 16, 24, 0.93)";
  roundRect(ctx, 0, 0, width, height, 40);
  ctx.fill();
  ctx.textAlign = "center";
  ctx.textBaseline = "middle";
  ctx.fillStyle = COLORS.info;
  ctx.font = `700 54px ${FONT}`;
  ctx.fillText(fitText(ctx, nav.title, width - 80), width / 2, 64);
  const level = nav.level;
  const label = (item) => {
    const on = toggles.get(item.id);
    const more = nav.tree.children.has(item.id) ? " ›" : "";
    return on === undefined ? item.label + more : `${item.label}: ${on ? "ON" : "off"}`;
  };
  if (level.kind === "ring") {
    // Eight places on an ellipse, wide enough that a diagonal box never overlaps its compass neighbours.
    const {cx, cy, rx, ry} = ringGeometry(width, height);
    const w = 0.24 * width, h = 116;
    ctx.strokeStyle = "rgba(159, 176, 195, 0.35)";
    ctx.lineWidth = 6;
    ctx.beginPath();
    ctx.ellipse(cx, cy, rx, ry, 0, 0, 2 * Math.PI);
    ctx.stroke();
    ctx.fillStyle = COLORS.muted;
    ctx.font = `500 36px ${FONT}`;
    hint.forEach((line, i) => ctx.fillText(line, cx, cy - 44 + 44 * i));
    level.entries.forEach((e, i) => {
      const a = e.angle * Math.PI / 180;
      const x = cx + rx * Math.cos(a), y = cy - ry * Math.sin(a);
      const lit = i === nav.highlight;
      ctx.fillStyle = lit ? "#2f80ed" : "rgba(40, 52, 68, 0.97)";
      roundRect(ctx, x - w / 2, y - h / 2, w, h, 22);
      ctx.fill();
      if (lit) {
        ctx.strokeStyle = "#ffffff";
        ctx.lineWidth = 5;
        ctx.stroke();
      }
      const on = toggles.get(e.item.id);
      ctx.fillStyle = "#ffffff";
      ctx.font = `${lit ? 700 : 600} 37px ${FONT}`;
      if (on === undefined) {
        ctx.fillText(fitText(ctx, label(e.item), w - 28), x, y);
        return;
      }
      ctx.fillText(fitText(ctx, e.item.label, w - 28), x, y - 20);
      ctx.fillStyle = on ? COLORS.ok : "#c3ccd6";
      ctx.font = `700 32px ${FONT}`;
      ctx.fillText(on ? "● ON" : "○ off", x, y + 28);
    });
  } else {
    const rows = 8, rowH = 92, top = 120;
    const first = Math.max(0, Math.min(nav.highlight - 3, level.entries.length - rows));
    ctx.textAlign = "left";
    level.entries.slice(first, first + rows).forEach((e, k) => {
      const i = first + k, y = top + k * rowH;
      const lit = i === nav.highlight;
      ctx.fillStyle = lit ? "#2f80ed" : "rgba(40, 52, 68, 0.95)";
      roundRect(ctx, 60, y, width - 120, rowH - 14, 18);
      ctx.fill();
      ctx.fillStyle = "#ffffff";
      ctx.font = `${lit ? 700 : 600} 40px ${FONT}`;
      ctx.fillText(fitText(ctx, label(e.item), width - 180), 90, y + (rowH - 14) / 2);
    });
    ctx.textAlign = "center";
    ctx.fillStyle = COLORS.muted;
    ctx.font = `500 30px ${FONT}`;
    const shown = nav.highlight < 0 ? "–" : nav.highlight + 1;
    const where = `${shown} / ${level.entries.length}`;
    ctx.fillText(`${where}   ·   ${hint.join("   ·   ")}`, width / 2, top + rows * rowH + 20);
  }
  if (footer) {
    ctx.fillStyle = footer.level === "error" ? COLORS.error : COLORS.ok;
    ctx.font = `600 34px ${FONT}`;
    ctx.textAlign = "center";
    ctx.fillText(fitText(ctx, footer.text, width - 80), width / 2, height - 44);
  }
}
