// WebXR's reference spaces (right-handed, +y up, -z forward, +x right, metres) to ROS's (REP 103: +x forward,
// +y left, +z up): x_ros = -z_xr, y_ros = -x_xr, z_ros = y_xr. The change of basis is a proper rotation
// (determinant +1), so a quaternion's vector part maps like a position and w stays.
//
// Poses go out with header.frame_id FRAME_ID ("webxr"): the server reads any frame id other than "unity_left_handed" as ROS
// axes, and a name of our own keeps the page independent of whatever the Unity convention becomes.

import {stampNow} from "../rosbridge.js";

export const FRAME_ID = "webxr";

export function rosPosition(p) {
  return {x: -p.z, y: -p.x, z: p.y};
}

export function rosOrientation(q) {
  return {x: -q.z, y: -q.x, z: q.y, w: q.w};
}

/** geometry_msgs/PoseStamped from an XR position {x,y,z} and orientation {x,y,z,w}. */
export function poseStamped(position, orientation, stamp = stampNow()) {
  return {header: {stamp, frame_id: FRAME_ID},
          pose: {position: rosPosition(position), orientation: rosOrientation(orientation)}};
}

// The server's Joy layout (README "Explicit control"):
//   axes    [thumbstick x (-1 left..1 right), thumbstick y (-1 down..1 up), index trigger 0..1, grip 0..1]
//   buttons [A or X, B or Y, thumbstick click, menu]
// from the xr-standard gamepad: buttons[0] trigger, [1] squeeze, [3] thumbstick press, [4] A/X, [5] B/Y;
// axes[2], axes[3] the thumbstick (y negative pushed forward). The Touch menu button is not given to pages.
export function joyFromGamepad(gamepad) {
  const b = gamepad?.buttons || [];
  const a = gamepad?.axes || [];
  const value = (i) => b[i] ? b[i].value : 0;
  const pressed = (i) => (b[i]?.pressed ? 1 : 0);
  const stickX = a.length >= 4 ? a[2] : (a[0] ?? 0);
  const stickY = a.length >= 4 ? a[3] : (a[1] ?? 0);
  return {
    axes: [finite(stickX), finite(-stickY), finite(value(0)), finite(value(1))],
    buttons: [pressed(4), pressed(5), pressed(3), 0],
  };
}

function finite(v) {
  return Number.isFinite(v) ? v : 0;
}

export function joyMessage(joy, stamp = stampNow()) {
  return {header: {stamp, frame_id: FRAME_ID}, axes: joy.axes, buttons: joy.buttons};
}

export function sameJoy(a, b) {
  return !!a && !!b && a.axes.every((v, i) => Math.abs(v - b.axes[i]) < 0.01) &&
    a.buttons.every((v, i) => v === b.buttons[i]);
}
