// The comfort vignette and the robot's reticle (issue 36). While the operator holds control, the robot's head is
// meant to follow theirs; when it trails (velocity caps, a slow link, a joint limit, motors off) the camera panel
// drifts off to the side. The vignette darkens the view's edges as that lag grows, so the eyes get a cue instead
// of a swimming world, and a small reticle shows where the robot looks now.
//
// Lag: the angle between the operator's line of sight and the robot's (HeadYaw/HeadPitch from the joint states,
// about the engage zero). Strength 0 below LAG_START_DEG, 1 from LAG_FULL_DEG, smoothstep between, eased over
// EASE_S. Cheap by construction: the vignette is no extra layer to fill but a few instructions added once to the
// shaders of the world's materials (the camera panel, its overlay, the floor grid, the controllers; not the HUD or
// the menus), which darken a pixel by its angle off the eye's axis; a frame sets four shared uniforms, the reticle's
// place, colour and visibility, never a canvas or a texture.
//
// The option: on by default; `#vignette=off` (or `?vignette=off`) in the page's address starts it off; the flat
// page's "Comfort vignette" checkbox and the status menu's item (command set_comfort_vignette) switch it.

import * as THREE from "three";
import {COLORS} from "./panels.js";

export const LAG_START_DEG = 5;      // the robot's head within 5 degrees of the operator's: nothing shown
export const LAG_FULL_DEG = 25;      // 25 degrees behind or more: the vignette at its darkest and narrowest
export const COMMAND = "set_comfort_vignette";
const EASE_S = 0.12;                 // the strength follows the lag with this time constant: no flicker
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

/** GLSL added to a world material: the colour mixed toward the tint by the fragment's angle off the eye's axis
 * (its tangent, in view space), 0 inside comfortClear, `comfortOpacity` beyond comfortDark, smoothstep between. */
const VERTEX_DECLARE = "varying vec3 vComfortView;\n";
const VERTEX_SET = "#include <project_vertex>\n\tvComfortView = mvPosition.xyz;";
const FRAGMENT_DECLARE = "varying vec3 vComfortView;\nuniform float comfortOpacity;\nuniform float comfortClear;\n" +
  "uniform float comfortDark;\nuniform vec3 comfortTint;\n";
const FRAGMENT_MIX = "#include <opaque_fragment>\n\tgl_FragColor.rgb = mix(gl_FragColor.rgb, comfortTint," +
  " comfortOpacity * smoothstep(comfortClear, comfortDark, length(vComfortView.xy) / max(-vComfortView.z, 1e-4)));";

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
    this.scene = scene;
    this.headLocked = headLocked;
    this.uniforms = {comfortOpacity: {value: 0}, comfortTint: {value: TINT},
                     comfortClear: {value: Math.tan(THREE.MathUtils.degToRad(CLEAR_DEG))},
                     comfortDark: {value: Math.tan(THREE.MathUtils.degToRad(DARK_DEG))}};
    this.patched = new WeakSet();
    this.scale = 1;
    this.frames = 0;
    this.patch = (shader) => {  // one function for every material: one program per kind of material
      Object.assign(shader.uniforms, this.uniforms);
      shader.vertexShader = VERTEX_DECLARE + shader.vertexShader.replace("#include <project_vertex>", VERTEX_SET);
      shader.fragmentShader = FRAGMENT_DECLARE +
        shader.fragmentShader.replace("#include <opaque_fragment>", FRAGMENT_MIX);
    };
    this.reticle = new THREE.Mesh(new THREE.PlaneGeometry(RETICLE_SIZE, RETICLE_SIZE),
                                  new THREE.MeshBasicMaterial({map: reticleTexture(), transparent: true,
                                                               depthTest: false, depthWrite: false,
                                                               toneMapped: false, color: COLORS.info}));
    this.reticle.renderOrder = 6;
    this.reticle.visible = false;
    scene.add(this.reticle);
    this.darkenWorld();
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

  /** Adds the vignette to the shaders of the world's materials not yet given it (the head-locked HUD and menus,
   * and the reticle, keep theirs). Run at start and once a second, for objects added later. */
  darkenWorld() {
    const visit = (object) => {
      if (object === this.headLocked || object === this.reticle) return;
      for (const material of [object.material].flat()) {
        const kind = material && (material.isMeshBasicMaterial || material.isLineBasicMaterial);
        if (!kind || this.patched.has(material)) continue;
        material.onBeforeCompile = this.patch;
        material.needsUpdate = true;
        this.patched.add(material);
      }
      object.children.forEach(visit);
    };
    visit(this.scene);
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

    if (++this.frames % 60 === 0) this.darkenWorld();
    const shown = this.strength > 0.002;
    const u = this.uniforms;
    u.comfortOpacity.value = shown ? Math.min(1, this.strength * 1.5) : 0;
    this.scale = 1 - (1 - NARROWEST) * (shown ? this.strength : 0);  // tangents: the clear middle narrows
    u.comfortClear.value = this.scale * Math.tan(THREE.MathUtils.degToRad(CLEAR_DEG));
    u.comfortDark.value = this.scale * Math.tan(THREE.MathUtils.degToRad(DARK_DEG));
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
            strength: this.strength, vignetteVisible: this.uniforms.comfortOpacity.value > 0,
            opacity: this.uniforms.comfortOpacity.value, scale: this.scale,
            clearDeg: THREE.MathUtils.radToDeg(Math.atan(this.uniforms.comfortClear.value)),
            darkDeg: THREE.MathUtils.radToDeg(Math.atan(this.uniforms.comfortDark.value)),
            reticleVisible: this.reticle.visible, robotLook: this.robotLook,
            reticle: this.reticle.visible ? this.reticle.position.toArray() : null};
  }
}
