// What the Touch controllers' buttons do on this page (the page's help and the README list the same):
//   grip (held)                 that arm follows (the dead-man; the server reads it from the Joy stream)
//   right trigger, no menu open take control; again: release it
//   left trigger, no menu open  push-to-talk while held
//   right thumbstick click      calibrate (stand in a T-pose: arms straight out to the sides); while holding
//                               control it also re-centres (where you look becomes straight ahead)
//   both thumbsticks clicked    emergency stop
//   X / Y (left), A / B (right) open the menu bound to that button in the menu data (status, speech, commands,
//                               emotions); the same button again goes back one level, then closes
//   in a menu: thumbstick points at an item, either trigger selects it
//   right thumbstick pushed right / left, no menu open, a proposal of the robot waiting: accept / reject it
//                               (never the trigger, the thumbstick clicks or the menu buttons: those take control,
//                               stop the robot and open menus)
// Edges are detected here from the xr-standard gamepad (buttons[0] trigger, [3] thumbstick, [4] A/X, [5] B/Y).

const PRESS = 0.75, RELEASE = 0.35;  // trigger hysteresis
const FLICK = 0.8, CENTRED = 0.3;    // a thumbstick pushed sideways past FLICK decides once, until back in CENTRED
const LETTERS = {left: ["X", "Y"], right: ["A", "B"]};

export class ControllerActions {
  /** actions: {menuButton(hand, letter), menuOpen(), select(), panelPick() (true: an open panel took the right
   * trigger), toggleControl(), talk(on), calibrate(), estop(),
   * stick(x, yUp, now), decide("accept" | "reject"), proposalPending()} */
  constructor(actions) {
    this.actions = actions;
    this.prev = {left: null, right: null};
    this.trigger = {left: false, right: false};
    this.talking = false;
    this.stickDown = {left: false, right: false};
    this.rightClickSolo = false;  // the right stick went down with the left up, and the left has not joined
    this.estopLatched = false;
    this.flicked = false;         // the right thumbstick was pushed sideways and has not come back to the centre
  }

  update(hand, gamepad, now) {
    if (!gamepad || !LETTERS[hand]) return;
    const b = gamepad.buttons;
    const pressed = (i) => !!b[i]?.pressed;
    const prev = this.prev[hand] || {a: false, b: false};
    const menuA = pressed(4), menuB = pressed(5);
    if (menuA && !prev.a) this.actions.menuButton(hand, LETTERS[hand][0]);
    if (menuB && !prev.b) this.actions.menuButton(hand, LETTERS[hand][1]);
    this.prev[hand] = {a: menuA, b: menuB};

    const value = b[0]?.value ?? 0;
    const wasDown = this.trigger[hand];
    const down = wasDown ? value > RELEASE : value > PRESS;
    this.trigger[hand] = down;
    if (down && !wasDown) {
      if (this.actions.menuOpen()) this.actions.select();
      else if (hand === "right" && this.actions.panelPick?.()) { /* an open panel's pick (the dialog's) */ }
      else if (hand === "right") this.actions.toggleControl();
      else { this.talking = true; this.actions.talk(true); }
    } else if (!down && wasDown && hand === "left" && this.talking) {
      this.talking = false;
      this.actions.talk(false);
    }

    const stick = pressed(3);
    const stickWas = this.stickDown[hand];
    this.stickDown[hand] = stick;
    if (stick && !stickWas) {
      if (this.stickDown.left && this.stickDown.right) {
        this.rightClickSolo = false;
        if (!this.estopLatched) { this.estopLatched = true; this.actions.estop(); }
      } else if (hand === "right") this.rightClickSolo = true;
    }
    if (!stick && stickWas) {
      if (hand === "right" && this.rightClickSolo) this.actions.calibrate();
      if (hand === "right") this.rightClickSolo = false;
      if (!this.stickDown.left && !this.stickDown.right) this.estopLatched = false;
    }

    const axes = gamepad.axes || [];
    const x = axes.length >= 4 ? axes[2] : 0, y = axes.length >= 4 ? axes[3] : 0;
    this.actions.stick(hand, x, -y, now);
    if (hand === "right") this.flick(x, y);
  }

  /** The hand's controller no longer reported (put down for hand tracking, or lost): what it held ends. */
  gone(hand) {
    if (!LETTERS[hand] || (!this.prev[hand] && !this.trigger[hand] && !this.stickDown[hand])) return;
    if (hand === "left" && this.talking) {
      this.talking = false;
      this.actions.talk(false);
    }
    this.prev[hand] = null;
    this.trigger[hand] = false;
    this.stickDown[hand] = false;
    this.rightClickSolo = false;
    if (!this.stickDown.left && !this.stickDown.right) this.estopLatched = false;
  }

  flick(x, y) {
    if (this.flicked) {
      if (Math.hypot(x, y) < CENTRED) this.flicked = false;
      return;
    }
    if (Math.abs(x) < FLICK || Math.abs(y) > Math.abs(x)) return;
    this.flicked = true;  // a push that began before the proposal came, or in a menu, decides nothing
    if (this.stickDown.right || this.actions.menuOpen() || !this.actions.proposalPending()) return;
    this.actions.decide(x > 0 ? "accept" : "reject");
  }
}
