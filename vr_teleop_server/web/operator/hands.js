// Hands instead of controllers (issue 36). Put the Touch controllers down and the Quest reports hands: input
// sources with a `hand` (25 joint poses) and no usable gamepad. These gestures drive the same actions the
// controllers do (controls.js), and the same streams: the wrist's pose on the controller's pose topic and a Joy
// whose grip axis is the fist, so the server's dead-man rule (teleop/safety.py DeadMan) applies unchanged.
//
//   pinch (thumb tip to index tip closer than PINCH_ON_M; let go once they part past PINCH_OFF_M)
//       the trigger: in a menu it selects the lit item; with no menu open the right hand takes control (again:
//       releases it) and the left hand talks through the robot while the pinch is held
//   point at the HUD and pinch          opens the menus (a ring of the page's menus: X's left, Y's top, A's right,
//                                       B's bottom)
//   in a menu: point at an item         lights it (the hand's ray is the thumbstick); pinch selects it;
//                                       a pinch pointing off the menu goes back one level, then closes
//   fist held FIST_HOLD_MS             that arm's dead-man: the arm follows the wrist while the fist is held,
//                                       and holds the moment the hand opens (or tracking is lost)
// A fist: all four fingertips closer to the wrist than FIST_ON times the wrist-to-knuckle length (the middle
// finger's knuckle, so the test scales with the hand); it opens once any fingertip is past FIST_OFF times that.
// A pinch needs the index finger out of the fist, so closing the hand is never a pinch.

export const PINCH_ON_M = 0.02, PINCH_OFF_M = 0.04;  // thumb tip to index tip, metres
export const FIST_ON = 1.1, FIST_OFF = 1.3;          // fingertip to wrist over wrist to middle knuckle
export const FIST_HOLD_MS = 300;                     // a fist held this long is the dead-man
export const HAND_MENU_ID = "hands.menus";           // the ring of menus a pinch on the HUD opens
const FINGERS = ["index", "middle", "ring", "pinky"];
const MENU_SLOTS = ["left", "top", "right", "bottom"];
const LETTER_ORDER = "XYAB";

const distance = (a, b) => Math.hypot(a.x - b.x, a.y - b.y, a.z - b.z);

/** What one hand shows this frame, from its joint poses: {wrist, pinch (m), curl: {finger: ratio}, ray}, or null
 * while it is not tracked (a joint pose missing). */
export function readHand(frame, source, refSpace) {
  const joint = (name) => {
    const space = source.hand.get(name);
    return space ? frame.getJointPose(space, refSpace) : null;
  };
  const wrist = joint("wrist"), knuckle = joint("middle-finger-phalanx-proximal"), thumb = joint("thumb-tip");
  const tips = FINGERS.map((f) => joint(`${f}-finger-tip`));
  if (!wrist || !knuckle || !thumb || tips.some((t) => !t)) return null;
  const w = wrist.transform.position;
  const palm = distance(w, knuckle.transform.position) || 1e-6;
  const curl = {};
  FINGERS.forEach((f, i) => { curl[f] = distance(tips[i].transform.position, w) / palm; });
  const ray = source.targetRaySpace ? frame.getPose(source.targetRaySpace, refSpace) : null;
  return {wrist: wrist.transform, pinch: distance(thumb.transform.position, tips[0].transform.position), curl,
          ray: ray ? ray.transform : null};
}

/** One hand's gestures with hysteresis: feed readHand's result (or null) once per frame. */
export class HandGesture {
  constructor() {
    this.pinch = false;
    this.fist = false;
    this.fistSince = null;
    this.deadman = false;
  }

  update(reading, now) {
    if (!reading) {  // not tracked: nothing held, the arm holds
      this.pinch = this.fist = this.deadman = false;
      this.fistSince = null;
      return this;
    }
    const curls = Object.values(reading.curl);
    this.fist = this.fist ? Math.max(...curls) <= FIST_OFF : Math.max(...curls) < FIST_ON;
    if (!this.fist) this.fistSince = null;
    else if (this.fistSince === null) this.fistSince = now;
    this.deadman = this.fist && now - this.fistSince >= FIST_HOLD_MS;
    const indexOut = reading.curl.index >= FIST_ON;
    if (this.fist) this.pinch = false;
    else this.pinch = this.pinch ? reading.pinch <= PINCH_OFF_M : reading.pinch < PINCH_ON_M && indexOut;
    return this;
  }

  /** The server's Joy layout (ros_axes.js): the pinch on the trigger axis, the dead-man on the grip axis. */
  joy() {
    return {axes: [0, 0, this.pinch ? 1 : 0, this.deadman ? 1 : 0], buttons: [0, 0, 0, 0]};
  }
}

/** The menu tree with a ring of its menus added (HAND_MENU_ID): hands have no X Y A B buttons. */
export function withHandMenu(tree) {
  if (!tree.menus.length || tree.byId.has(HAND_MENU_ID)) return tree;
  const menus = tree.menus.slice().sort((a, b) => rank(a) - rank(b));
  // each menu at its letter's place (X left, Y top, A right, B bottom) when the letters allow, else a list
  const letters = menus.map(rank);
  const ring = letters.every((r) => r < MENU_SLOTS.length) && new Set(letters).size === letters.length;
  const items = menus.map((m, i) => ({id: m.id, label: m.label, parent: HAND_MENU_ID, position: i,
                                      slot: ring ? MENU_SLOTS[letters[i]] : "list", command: "", args: "", icon: ""}));
  const byId = new Map(tree.byId).set(HAND_MENU_ID, {id: HAND_MENU_ID, label: "Menus", controller: "any", button: "",
                                                     isMenu: true});
  return {...tree, byId, children: new Map(tree.children).set(HAND_MENU_ID, items)};
}

function rank(menu) {
  const i = LETTER_ORDER.indexOf(menu.button);
  return i < 0 ? LETTER_ORDER.length : i;
}

/** Which input the headset reports: "controllers", "hands", "a hand and a controller" or null (none). */
export function inputKind(sources) {
  let hands = 0, controllers = 0;
  for (const s of sources) {
    if (s.handedness !== "left" && s.handedness !== "right") continue;
    if (s.hand) hands += 1;
    else if (s.gamepad) controllers += 1;
  }
  if (hands && controllers) return "a hand and a controller";
  return hands ? "hands" : controllers ? "controllers" : null;
}

/** The hands' gestures turned into the page's actions (the ones ControllerActions drives), plus
 * actions.openMenus(), actions.back(), actions.point(x, y, now) and actions.joy(hand, joy, now).
 * pointer(rayTransform) says what a hand points at: {on: "menu", x, y} (the menu's thumbstick), {on: "hud"} or null. */
export class HandActions {
  constructor(actions, pointer, draw = () => {}) {
    this.actions = actions;
    this.pointer = pointer;
    this.draw = draw;  // draw(hand, ray or null, target): the ray shown from the hand (handRays)
    this.gestures = {left: new HandGesture(), right: new HandGesture()};
    this.tracked = {left: false, right: false};
    this.talking = false;
  }

  /** Once per frame for each hand source (reading null: not tracked this frame). */
  update(hand, reading, now) {
    const g = this.gestures[hand];
    if (!g) return;
    const wasPinch = g.pinch;
    g.update(reading, now);
    this.tracked[hand] = !!reading;
    const target = reading?.ray ? this.pointer(reading.ray) : null;
    if (target?.on === "menu" && this.actions.menuOpen()) this.actions.point(target.x, target.y, now);
    this.draw(hand, reading?.ray ?? null, target);
    if (g.pinch && !wasPinch) this.pinched(hand, target);
    else if (!g.pinch && wasPinch && hand === "left" && this.talking) this.stopTalking();
    this.actions.joy(hand, g.joy(), now);
  }

  pinched(hand, target) {
    if (this.actions.menuOpen()) {
      if (target?.on === "menu") this.actions.select();
      else this.actions.back();
    } else if (target?.on === "hud") this.actions.openMenus();
    else if (hand === "right") this.actions.toggleControl();
    else { this.talking = true; this.actions.talk(true); }
  }

  /** A hand no longer reported (put away, or the controllers are back): its arm holds, its talk ends. */
  gone(hand, now) {
    const g = this.gestures[hand];
    if (!g) return;
    const was = g.deadman || g.pinch;
    g.update(null, now);
    this.tracked[hand] = false;
    this.draw(hand, null, null);
    if (hand === "left" && this.talking) this.stopTalking();
    if (was) this.actions.joy(hand, g.joy(), now);
  }

  stopTalking() {
    this.talking = false;
    this.actions.talk(false);
  }
}

/** pointer() for HandActions: the hand's ray (an XRRigidTransform; it points along its -z) against the menu's and
 * the HUD's meshes. THREE is passed in so this module also runs under Node for its tests. */
export function rayPointer(THREE, {menu, hud, menuStick}) {
  const raycaster = new THREE.Raycaster();
  const origin = new THREE.Vector3(), direction = new THREE.Vector3(), q = new THREE.Quaternion();
  return (ray) => {
    const {position: p, orientation: o} = ray;
    origin.set(p.x, p.y, p.z);
    direction.set(0, 0, -1).applyQuaternion(q.set(o.x, o.y, o.z, o.w));
    raycaster.set(origin, direction);
    if (menu.visible) {
      const hit = raycaster.intersectObject(menu, false)[0];
      return hit?.uv ? {on: "menu", distance: hit.distance, ...menuStick(hit.uv.x, hit.uv.y)} : null;
    }
    const hit = hud.visible ? raycaster.intersectObject(hud, false)[0] : null;
    return hit ? {on: "hud", distance: hit.distance} : null;
  };
}

const RAY_IDLE_M = 0.4;  // a ray pointing at nothing is drawn this long

/** draw() for HandActions: a thin line from each tracked hand along its ray, to the panel it points at (lit) or a
 * short way into nothing, so the teacher sees what a pinch would press. */
export function handRays(THREE, scene) {
  const lines = {};
  for (const hand of ["left", "right"]) {
    const geometry = new THREE.BufferGeometry().setFromPoints([new THREE.Vector3(0, 0, 0),
                                                              new THREE.Vector3(0, 0, -1)]);
    const line = new THREE.Line(geometry, new THREE.LineBasicMaterial({color: 0x9fb0c3, transparent: true,
                                                                      opacity: 0.7, depthTest: false}));
    line.renderOrder = 12;
    line.visible = false;
    scene.add(line);
    lines[hand] = line;
  }
  return (hand, ray, target) => {
    const line = lines[hand];
    line.visible = !!ray;
    if (!ray) return;
    const {position: p, orientation: o} = ray;
    line.position.set(p.x, p.y, p.z);
    line.quaternion.set(o.x, o.y, o.z, o.w);
    line.scale.set(1, 1, target?.distance ?? RAY_IDLE_M);
    line.material.color.setHex(target ? 0x2f80ed : 0x9fb0c3);
  };
}
