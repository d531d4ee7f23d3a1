"""What ArUco tracking costs per head-camera frame: decode + detect + pose, against decoding the JPEG alone
(the same-process baseline). Run: MUJOCO_GL=egl .venv/bin/python bench/study_aruco.py"""

from __future__ import annotations

import time

import cv2
import numpy as np

from robot_models import load_qtrobot
from sim import StandIn
from vr_teleop_server.study.perception.aruco import camera_matrix, detect_markers

N = 200


def main() -> None:
    model = load_qtrobot()
    with StandIn(model) as standin:
        standin.set_targets({"HeadPitch": 18.0})
        time.sleep(1.5)
        rgb = standin.snapshot()
    ok, jpeg = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 80])
    assert ok
    data = np.frombuffer(jpeg.tobytes(), np.uint8)
    k = camera_matrix(model, rgb.shape[1], rgb.shape[0])
    sizes = {0: 0.05, 1: 0.07, 2: 0.08, 3: 0.10}

    t = time.perf_counter()
    for _ in range(N):
        cv2.imdecode(data, cv2.IMREAD_GRAYSCALE)
    decode = (time.perf_counter() - t) / N
    t = time.perf_counter()
    for _ in range(N):
        found = detect_markers(cv2.imdecode(data, cv2.IMREAD_GRAYSCALE), k, sizes)
    full = (time.perf_counter() - t) / N
    print(f"{rgb.shape[1]}x{rgb.shape[0]} frame, {len(found)} markers")
    print(f"decode only      {decode * 1e3:6.2f} ms")
    print(f"decode+detect+pose {full * 1e3:6.2f} ms  ({full / decode:.1f}x decoding; the tracker runs at 5 Hz)")


if __name__ == "__main__":
    main()
