// The robot's eyes. A camera source hands the panel a THREE.Texture and counts what it shows; the panel does not
// care where the frames come from. Today the source is JPEG over rosbridge (JpegCameraSource). When WebRTC media
// exist (issue 20), a VideoCameraSource built on a <video> element and THREE.VideoTexture takes its place with the
// same shape: {texture, aspect, frameAge(), stats(), dispose()}; main.js picks the source, nothing else changes.

import * as THREE from "three";
import {stampSeconds} from "./rosbridge.js";

export const CAMERA_TOPIC = "/camera/color/image_raw/compressed";
const AGES_KEPT = 2000;

export class JpegCameraSource {
  /** Newest frame only: the server sends at most one frame at a time (queue_length 1), and while a frame is being
   * decoded (in a worker, off the main thread) newer ones replace each other: never a backlog. */
  constructor(ros, {onError = () => {}, placeholder = null} = {}) {
    this.onError = onError;
    this.texture = new THREE.Texture(placeholder ?? undefined);
    this.texture.colorSpace = THREE.SRGBColorSpace;
    this.texture.generateMipmaps = false;
    this.texture.minFilter = THREE.LinearFilter;
    if (placeholder) this.texture.needsUpdate = true;
    this.aspect = 4 / 3;
    this.received = 0;      // frames from the server
    this.replaced = 0;      // frames dropped because a newer one arrived while a decode was in flight
    this.uploaded = 0;      // frames uploaded to the GPU
    this.ages = [];         // stamp-to-upload ages in seconds (the bench reads them)
    this.shownStamp = null; // stamp of the frame on the texture
    this.busy = false;
    this.pending = null;
    this.uploading = null;
    this.lastError = "";
    this.texture.onUpdate = () => this.uploadedFrame();
    this.worker = new Worker(new URL("./camera_worker.js", import.meta.url));
    this.worker.onmessage = (event) => this.decoded(event.data);
    this.worker.onerror = (event) => this.fail(`the camera decoder failed: ${event.message}`);
    ros.subscribe(CAMERA_TOPIC, "sensor_msgs/CompressedImage", (msg) => this.frame(msg),
      {throttle_rate: 0, queue_length: 1});
  }

  frame(msg) {
    this.received += 1;
    if (msg.format && !/jpe?g/i.test(msg.format)) {
      this.fail(`camera frames in ${msg.format} cannot be shown (JPEG expected)`);
      return;
    }
    const frame = {data: msg.data, stamp: stampSeconds(msg.header?.stamp), seq: this.received};
    if (this.busy) {
      if (this.pending) this.replaced += 1;
      this.pending = frame;
      return;
    }
    this.decode(frame);
  }

  decode(frame) {
    this.busy = true;
    this.worker.postMessage(frame);
  }

  decoded({bitmap, stamp, error}) {
    this.busy = false;
    if (error) this.fail(`a camera frame could not be decoded: ${error}`);
    else {
      const old = this.texture.image;
      this.texture.image = bitmap;
      this.texture.flipY = false;  // the worker flipped it: WebGL does not flip ImageBitmaps
      this.texture.needsUpdate = true;
      this.uploading = stamp;
      this.aspect = bitmap.width / bitmap.height;
      if (old && typeof old.close === "function") old.close();  // an earlier bitmap: its pixels are on the GPU
    }
    if (this.pending) {
      const next = this.pending;
      this.pending = null;
      this.decode(next);
    }
  }

  uploadedFrame() {
    if (this.uploading === null) return;
    this.uploaded += 1;
    this.shownStamp = this.uploading;
    this.ages.push(Date.now() / 1000 - this.uploading);
    if (this.ages.length > AGES_KEPT) this.ages.splice(0, this.ages.length - AGES_KEPT);
    this.uploading = null;
  }

  fail(text) {
    this.lastError = text;
    this.onError(text);
  }

  /** Seconds between the shown frame's stamp and now (server and page share a clock on one machine; across
   * machines, the two clocks' offset adds in). */
  frameAge() {
    return this.shownStamp === null ? null : Date.now() / 1000 - this.shownStamp;
  }

  stats() {
    return {received: this.received, replaced: this.replaced, uploaded: this.uploaded};
  }

  dispose() {
    this.worker.terminate();
    this.texture.dispose();
  }
}
