// The comfort vignette and the robot's reticle (issue 36). While the operator holds control, the robot's head is
// meant to follow theirs; when it trails (velocity caps, a slow link, a joint limit, motors off) the camera panel
// drifts off to the side. The vignette darkens the view's edges as that lag grows, so the eyes get a cue instead
// of a swimming world, and a small reticle shows where the robot looks now.
//
// Lag: the angle between the operator's line of sight and the robot's (HeadYaw/HeadPitch from the joint states,
// about the engage zero). Strength 0 below LAG_START_DEG, 1 from LAG_FULL_DEG, smoothstep between, eased over
// EASE_S. Cheap by construction: the meshes are built once; a frame changes an opacity, a scale, a colour and a
// visibility, never a canvas or a texture. The vignette is not drawn at all while its strength is 0, and once its
// outer part is fully dark that part is drawn opaque, first, writing depth: the camera panel's pixels behind it are
// then never shaded (a software renderer shades every pixel on the CPU; a headset's GPU saves the fill too).
//
// The option: on by default; `#vignette=off` (or `?vignette=off`) in the page's address starts it off; the flat
// page's "Comfort vignette" checkbox and the status menu's item (command set_comfort_vignette) switch it.

import * as THREE from "three";
import {COLORS} from "./panels.js";

export const LAG_START_DEG = 5;      // the robot's head within 5 degrees of the operator's: nothing shown
export const LAG_FULL_DEG = 25;      // 25 degrees behind or more: the vignette at its darkest and narrowest
export const COMMAND = "set_comfort_vignette";
const EASE_S = 0.12;                 // the strength follows the lag with this time constant: no flicker
const DISTANCE = 0.2;                // metres: inside the menu (0.85) and the HUD (1.0), which are drawn over it
const CLEAR_DEG = 42;                // at the faintest, the view is clear within 42 degrees of its centre...
const DARK_DEG = 70;                 // ...and dark beyond 70; at full strength both shrink by NARROWEST
const NARROWEST = 0.45;              // (tangents scaled by 0.45: clear within 22 degrees, dark beyond 51)
const RETICLE_DISTANCE = 1.9;        // metres: just in front of the camera panel (2.0)
const RETICLE_SIZE = 0.15;           // metres at 1.9 m: four and a half degrees across
const TINT = new THREE.Color("#0a1018");  // the HUD's background, rgba(10, 16, 24) (sRGB, made linear)

/** The page's option from its address: off with vignette=off|0|false in the hash or the query. */
export function optionFromAddress(loc) {
  for (const part of [loc.hash.slice(1), loc.search.slice(1)]) {
    const value = new URLSearchParams(part).get("vignette");
    if (value !== null) return !["off", "0", "false", "no"].includes(value.toLowerCase());
  }
  return true;
}

/** Rings facing +z at z=0 through `radii` (tangent units: radius / distance) with those alphas. */
function ringGeometry(radii, alphas, segments = 64) {
  const positions = [], colors = [], index = [];
  for (let j = 0; j < radii.length; j++) {
    for (let i = 0; i < segments; i++) {
      const a = (i / segments) * 2 * Math.PI;
      positions.push(radii[j] * DISTANCE * Math.cos(a), radii[j] * DISTANCE * Math.sin(a), 0);
      colors.push(TINT.r, TINT.g, TINT.b, alphas[j]);
    }
  }
  for (let j = 0; j < radii.length - 1; j++) {
    for (let i = 0; i < segments; i++) {
      const a = j * segments + i, b = j * segments + (i + 1) % segments;
      const c = a + segments, d = b + segments;
      index.push(a, c, b, b, c, d);
    }
  }
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.Float32BufferAttribute(positions, 3));
  geometry.setAttribute("color", new THREE.Float32BufferAttribute(colors, 4));  // 4: per-vertex alpha
  geometry.setIndex(index);
  return geometry;
}

/** The gradient (transparent inside `clear`, dark at `dark`, smoothstep between) and the dark outer part (from
 * `dark` to 89 degrees: the corners of any eye's view). */
function vignetteGeometries(clear, dark, stops = 10) {
  const radii = [], alphas = [];
  for (let j = 0; j <= stops; j++) {
    const t = j / stops;
    radii.push(clear + (dark - clear) * t);
    alphas.push(t * t * (3 - 2 * t));
  }
  return {gradient: ringGeometry(radii, alphas), outer: ringGeometry([dark, 60], [1, 1])};
}

/** The reticle's picture, drawn once: a ring with four ticks and a dot, white on a dark outline (tinted by the
 * material's colour). */
function reticleTexture() {
  const size = 128;
  const c = document.createElement("canvas");
  c.width = c.height = size;
  const ctx = c.getContext("2d");
  const mid = size / 2;
  const stroke = (style, width) => {
    ctx.strokeStyle = style;
    ctx.lineWidth = width;
    ctx.beginPath();
    ctx.arc(mid, mid, 34, 0, 2 * Math.PI);
    for (const [dx, dy] of [[1, 0], [-1, 0], [0, 1], [0, -1]]) {
      ctx.moveTo(mid + dx * 44, mid + dy * 44);
      ctx.lineTo(mid + dx * 60, mid + dy * 60);
    }
    ctx.stroke();
  };
  stroke("rgba(10, 16, 24, 0.85)", 14);
  stroke("#ffffff", 6);
  ctx.fillStyle = "rgba(10, 16, 24, 0.85)";
  ctx.beginPath();
  ctx.arc(mid, mid, 8, 0, 2 * Math.PI);
  ctx.fill();
  ctx.fillStyle = "#ffffff";
  ctx.beginPath();
  ctx.arc(mid, mid, 5, 0, 2 * Math.PI);
  ctx.fill();
  const texture = new THREE.CanvasTexture(c);
  texture.colorSpace = THREE.SRGBColorSpace;
  return texture;
}

export class Comfort {
  /** headLocked: the group placed at the operator's head each frame; scene: for the world-placed reticle. */
  constructor({scene, headLocked, enabled = true, checkbox = null, onChange = () => {}}) {
    this.enabled = enabled;
    this.lagDeg = 0;          // the newest lag, degrees (0 while inactive)
    this.target = 0;          // the strength the lag asks for
    this.strength = 0;        // eased, what is drawn
    this.active = false;      // we hold control and the head is switched on: the robot's head should follow
    this.robotLook = {yaw: 0, pitch: 0};  // degrees, WebXR's convention (yaw left +, pitch up +): the reticle's
    this.checkbox = checkbox;
    this.onChange = onChange;
    this.lastAt = null;
    const geometries = vignetteGeometries(Math.tan(THREE.MathUtils.degToRad(CLEAR_DEG)),
                                          Math.tan(THREE.MathUtils.degToRad(DARK_DEG)));
    const faded = () => new THREE.MeshBasicMaterial({vertexColors: true, transparent: true, opacity: 0,
                                                     depthTest: false, depthWrite: false, toneMapped: false});
    this.gradient = new THREE.Mesh(geometries.gradient, faded());
    this.outerFaded = faded();
    this.outerSolid = new THREE.MeshBasicMaterial({color: TINT, toneMapped: false});  // opaque, writes depth
    this.outer = new THREE.Mesh(geometries.outer, this.outerFaded);
    this.vignette = new THREE.Group();
    for (const mesh of [this.gradient, this.outer]) {
      mesh.renderOrder = 5;           // over the camera panel, under the HUD (10) and the menu (11)
      mesh.frustumCulled = false;
      this.vignette.add(mesh);
    }
    this.vignette.position.set(0, 0, -DISTANCE);
    this.vignette.visible = false;
    headLocked.add(this.vignette);
    this.reticle = new THREE.Mesh(new THREE.PlaneGeometry(RETICLE_SIZE, RETICLE_SIZE),
                                  new THREE.MeshBasicMaterial({map: reticleTexture(), transparent: true,
                                                               depthTest: false, depthWrite: false,
                                                               toneMapped: false, color: COLORS.info}));
    this.reticle.renderOrder = 6;
    this.reticle.visible = false;
    scene.add(this.reticle);
    this.tint = "info";
    this._euler = new THREE.Euler(0, 0, 0, "YXZ");
    this._robot = new THREE.Vector3();
    this._eyes = new THREE.Vector3();
    if (checkbox) {
      checkbox.checked = enabled;
      checkbox.addEventListener("change", () => {
        this.set(checkbox.checked);
        checkbox.blur();  // the flat view's keys (E, arrows...) ignore a focused input
      });
    }
  }

  /** Switches the vignette and the reticle on or off (the checkbox and the menu's state follow). */
  set(on) {
    this.enabled = !!on;
    if (this.checkbox) this.checkbox.checked = this.enabled;
    this.onChange(this.enabled);
  }

  /** A status menu item with our command: switched here, at once (it is the page's own display); returns the
   * args the server's select records ({"enable": ...}), or null for any other item. */
  menuItem(item) {
    if (item.command !== COMMAND) return null;
    let enable = !this.enabled;
    try {
      const given = JSON.parse(item.args || "{}").enable;
      if (typeof given === "boolean") enable = given;
    } catch { /* the server checked the args when it loaded the menu */ }
    this.set(enable);
    return JSON.stringify({enable});
  }

  /** Once per frame, after the head pose: zero and robotHead as main.js keeps them (radians; degrees). */
  update({head, zero, robotHead}, active, now) {
    const dt = this.lastAt === null ? 0 : Math.min(0.25, (now - this.lastAt) / 1000);
    this.lastAt = now;
    this.active = active;
    this._euler.set(zero.pitch - THREE.MathUtils.degToRad(robotHead.pitch),
                    zero.yaw + THREE.MathUtils.degToRad(robotHead.yaw), 0);
    this._robot.set(0, 0, -1).applyEuler(this._euler);
    this._eyes.set(0, 0, -1).applyQuaternion(head.quaternion);
    this.robotLook = {yaw: THREE.MathUtils.radToDeg(this._euler.y), pitch: THREE.MathUtils.radToDeg(this._euler.x)};
    this.lagDeg = active ? THREE.MathUtils.radToDeg(this._robot.angleTo(this._eyes)) : 0;
    const t = THREE.MathUtils.clamp((this.lagDeg - LAG_START_DEG) / (LAG_FULL_DEG - LAG_START_DEG), 0, 1);
    this.target = this.enabled ? t * t * (3 - 2 * t) : 0;
    const k = dt > 0 ? 1 - Math.exp(-dt / EASE_S) : 1;
    this.strength += (this.target - this.strength) * k;
    if (Math.abs(this.strength - this.target) < 0.002) this.strength = this.target;

    const shown = this.strength > 0.002;
    this.vignette.visible = shown;
    if (shown) {
      const opacity = Math.min(1, this.strength * 1.5);
      this.gradient.material.opacity = this.outerFaded.opacity = opacity;
      const solid = opacity >= 0.999;
      this.outer.material = solid ? this.outerSolid : this.outerFaded;
      this.outer.renderOrder = solid ? -1 : 5;  // opaque: drawn before the panel, which it hides
      this.vignette.scale.setScalar(1 - (1 - NARROWEST) * this.strength);
    }
    this.reticle.visible = this.enabled && active;
    if (this.reticle.visible) {
      this.reticle.position.copy(head.position).addScaledVector(this._robot, RETICLE_DISTANCE);
      this.reticle.quaternion.setFromEuler(this._euler);
      const tint = this.strength > 0.5 ? "warning" : "info";
      if (tint !== this.tint) {
        this.tint = tint;
        this.reticle.material.color.set(COLORS[tint]);
      }
      this.reticle.material.opacity = 0.55 + 0.45 * this.strength;
    }
  }

  /** What tests and the bench read. */
  snapshot() {
    return {enabled: this.enabled, active: this.active, lagDeg: this.lagDeg, target: this.target,
            strength: this.strength, vignetteVisible: this.vignette.visible,
            opacity: this.vignette.visible ? this.gradient.material.opacity : 0, scale: this.vignette.scale.x,
            solid: this.vignette.visible && this.outer.material === this.outerSolid,
            reticleVisible: this.reticle.visible, robotLook: this.robotLook,
            reticle: this.reticle.visible ? this.reticle.position.toArray() : null};
  }
}
