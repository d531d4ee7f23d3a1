// Radial menus from /vr_teleop/menus (vr_teleop_msgs/Menus: every tree flattened, each item naming its parent).
// Pure logic, no drawing: parseMenus checks a message and builds the trees; MenuNavigator is what the thumbstick,
// the trigger and the keyboard move.
//
// A level with compass items (slot left/top/right/bottom) and at most four list items is a ring of eight sectors:
// the compass items at their places, the list items on the diagonals. A level with more list items is a list
// (thumbstick up and down, with repeat).

export class MenuError extends Error {}

const COMPASS = {right: 0, top: 90, left: 180, bottom: 270};
const DIAGONALS = [135, 45, 225, 315];  // top-left, top-right, bottom-left, bottom-right
export const TOGGLE_COMMANDS = new Set(["set_arms_control", "set_head_control", "record_toggle"]);

/** {menus: [menu], byId: Map, children: Map(parent -> [item])} or a MenuError naming what cannot be drawn. */
export function parseMenus(msg) {
  if (!msg || !Array.isArray(msg.menus) || !Array.isArray(msg.items)) {
    throw new MenuError("the menus message has no menus or items list");
  }
  const byId = new Map();
  const menus = [];
  for (const [i, m] of msg.menus.entries()) {
    if (!m || typeof m.id !== "string" || !m.id) throw new MenuError(`menu ${i} has no id`);
    if (byId.has(m.id)) throw new MenuError(`menu ${m.id} appears twice`);
    const menu = {id: m.id, label: String(m.label || m.id), controller: String(m.controller || "any"),
                  button: String(m.button || "").toUpperCase(), isMenu: true};
    byId.set(m.id, menu);
    menus.push(menu);
  }
  const children = new Map();
  for (const [i, it] of msg.items.entries()) {
    if (!it || typeof it.id !== "string" || !it.id) throw new MenuError(`item ${i} has no id`);
    if (byId.has(it.id)) throw new MenuError(`item ${it.id} appears twice`);
    const slot = String(it.slot || "");
    if (!(slot in COMPASS) && slot !== "list") {
      throw new MenuError(`item ${it.id}: slot ${JSON.stringify(slot)} is not left, top, right, bottom or list`);
    }
    const item = {id: it.id, label: String(it.label || it.id), parent: String(it.parent || ""), slot,
                  position: Number(it.position) || 0, command: String(it.command || ""),
                  args: String(it.args || ""), icon: String(it.icon || "")};
    byId.set(item.id, item);
  }
  for (const item of byId.values()) {
    if (item.isMenu) continue;
    if (!byId.has(item.parent)) {
      throw new MenuError(`item ${item.id}: its parent ${item.parent || "(none)"} is unknown`);
    }
    if (!children.has(item.parent)) children.set(item.parent, []);
    children.get(item.parent).push(item);
  }
  for (const [parent, items] of children) {
    items.sort((a, b) => a.position - b.position);
    const taken = new Set();
    for (const item of items) {
      if (item.slot === "list") continue;
      if (taken.has(item.slot)) throw new MenuError(`${parent}: two items in the ${item.slot} slot`);
      taken.add(item.slot);
    }
  }
  for (const item of byId.values()) {
    if (!item.isMenu && !item.command && !children.has(item.id)) {
      throw new MenuError(`item ${item.id} has neither a command nor items under it`);
    }
  }
  return {menus, byId, children};
}

/** How a level is drawn: {kind: "ring", entries: [{item, angle}]} or {kind: "list", entries: [{item}]}. */
export function layout(tree, parentId) {
  const items = tree.children.get(parentId) || [];
  const compass = items.filter((it) => it.slot !== "list");
  const list = items.filter((it) => it.slot === "list");
  if (list.length <= DIAGONALS.length && compass.length > 0) {
    return {kind: "ring", entries: [...compass.map((item) => ({item, angle: COMPASS[item.slot]})),
                                    ...list.map((item, i) => ({item, angle: DIAGONALS[i]}))]};
  }
  const order = ["top", "right", "bottom", "left"];
  compass.sort((a, b) => order.indexOf(a.slot) - order.indexOf(b.slot));
  return {kind: "list", entries: [...compass, ...list].map((item) => ({item}))};
}

export class MenuNavigator {
  constructor() {
    this.tree = null;
    this.stack = [];       // ids: the menu, then the submenus entered
    this.highlight = -1;   // index in the current layout's entries
    this.repeatAt = 0;     // list mode: when a held stick moves the highlight again
    this.stickWasOut = false;
  }

  setTree(tree) {
    const path = this.stack.slice();
    this.tree = tree;
    // keep the operator where they were if that level still exists (the gesture list is republished on change)
    this.stack = [];
    for (const id of path) if (tree.byId.has(id)) this.stack.push(id); else break;
    this.clampHighlight();
  }

  get open() {
    return this.stack.length > 0;
  }

  get menu() {
    return this.open ? this.tree.byId.get(this.stack[0]) : null;
  }

  get level() {
    return this.open ? layout(this.tree, this.stack[this.stack.length - 1]) : null;
  }

  get title() {
    return this.stack.map((id) => this.tree.byId.get(id).label).join(" › ");
  }

  /** The menu a button opens: controller "left"/"right", button letter ("X", "A"...). */
  menuFor(controller, button) {
    if (!this.tree) return null;
    return this.tree.menus.find((m) => m.button === button && (m.controller === controller ||
                                                                m.controller === "any" || !controller)) || null;
  }

  /** The menu's button pressed: opens it, goes back one level, or closes it at the top. */
  press(menuId) {
    if (!this.open || this.stack[0] !== menuId) {
      this.stack = [menuId];
      this.highlight = -1;
    } else this.back();
  }

  back() {
    this.stack.pop();
    this.highlight = -1;
  }

  close() {
    this.stack = [];
    this.highlight = -1;
  }

  clampHighlight() {
    const n = this.level?.entries.length ?? 0;
    if (this.highlight >= n) this.highlight = n - 1;
  }

  /** The thumbstick (x right, y up, -1..1), once per frame. */
  stick(x, y, now) {
    if (!this.open) return;
    const level = this.level;
    const out = Math.hypot(x, y) > 0.6;
    if (level.kind === "ring") {
      if (!out) return;
      const angle = (Math.atan2(y, x) * 180 / Math.PI + 360) % 360;
      let best = -1, bestDistance = 361;
      level.entries.forEach((e, i) => {
        const d = Math.abs(((angle - e.angle + 540) % 360) - 180);
        if (d < bestDistance) { best = i; bestDistance = d; }
      });
      if (bestDistance <= 45) this.highlight = best;
      return;
    }
    if (!out || Math.abs(y) < Math.abs(x)) { this.stickWasOut = false; return; }
    if (this.stickWasOut && now < this.repeatAt) return;
    this.repeatAt = now + (this.stickWasOut ? 150 : 400);
    this.stickWasOut = true;
    this.step(y > 0 ? -1 : 1);
  }

  /** Moves the highlight in a list (or around a ring) by delta entries. */
  step(delta) {
    const n = this.level?.entries.length ?? 0;
    if (!n) return;
    this.highlight = this.highlight < 0 ? (delta > 0 ? 0 : n - 1) : (this.highlight + delta + n) % n;
  }

  /** The keyboard's arrows on a ring: the compass item in that direction. */
  direction(slot) {
    const level = this.level;
    if (!level) return;
    if (level.kind === "list") { this.step(slot === "top" ? -1 : slot === "bottom" ? 1 : 0); return; }
    const i = level.entries.findIndex((e) => e.angle === COMPASS[slot]);
    if (i >= 0) this.highlight = i; else this.step(slot === "left" || slot === "top" ? -1 : 1);
  }

  /** The trigger: enters a submenu (returns null) or returns the item to run. */
  select() {
    const level = this.level;
    if (!level || this.highlight < 0) return null;
    const item = level.entries[this.highlight].item;
    if (this.tree.children.has(item.id)) {
      this.stack.push(item.id);
      this.highlight = -1;
      return null;
    }
    return item;
  }
}
