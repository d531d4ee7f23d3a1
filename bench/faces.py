"""Face detectors on the stand-in's pupils, one skin tone each: recall per pupil, false positives per frame and CPU
time per frame, for CenterFace at several input sizes and, in the same run, the Haar cascade it replaced (the
baseline). Pictures come from testbed/faces.py: each pupil over a grid of head turns, distances and places in the
frame, 640x480 JPEG as the head camera's.

Targets (issue 42): recall >= 0.95 for every pupil whose face is in view (turned at most 45 degrees) and >= 30 px
tall, no pupil more than 3 points below another, CPU per frame <= 3x the cascade's. Recall on faces turned further
(profiles) is printed beside it, not counted.

`--calibrate` measures instead the server's detector (FaceDetector as `serve` builds it) by skin tone, distance and
turn from the camera, and writes the table modelled perception reads (vr_teleop_server/features/data/
face_recall.json: recall and mean confidence per grid point, the boxes' size and place on the head, false positives,
and when and how it was measured). A face counts where its centre is in the frame, as the model sees one.

Run: MUJOCO_GL=egl .venv/bin/python bench/faces.py [--quick] [--sizes 640,480+256]
     MUJOCO_GL=egl .venv/bin/python bench/faces.py --calibrate   (several minutes; at nice 0 on a quiet machine)
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import statistics
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # testbed/ (not installed with the package)

from sim.pupils import skin_tone  # noqa: E402
from testbed.faces import IN_VIEW_DEG, MIN_FACE_PX, PupilCamera, matches  # noqa: E402
from vr_teleop_server.features.faces import CascadeDetector, Detector, FaceDetector  # noqa: E402

FULL = {"distances": (0.8, 1.2, 1.6, 2.0, 2.4, 2.8), "head_yaws": (-70, -45, -25, 0, 25, 45, 70), "pans": (-20, 0, 20)}
CALIBRATION = {"distances": (1.2, 1.6, 2.0, 2.4, 2.8), "head_yaws": (0, -30, 30, -60, 60, -90, 90, -120, 120, 180),
               "pans": (-15, 0, 15)}
TABLE = Path(__file__).resolve().parent.parent / "vr_teleop_server" / "features" / "data" / "face_recall.json"
QUICK = {"distances": (1.0, 1.8, 2.4), "head_yaws": (-45, 0, 45), "pans": (0, 20)}


class Tally:
    def __init__(self) -> None:
        self.hits: dict[str, int] = defaultdict(int)
        self.counted: dict[str, int] = defaultdict(int)
        self.turned_hits: dict[str, int] = defaultdict(int)
        self.turned: dict[str, int] = defaultdict(int)
        self.false_positives = 0
        self.frames = 0
        self.cpu_s = 0.0

    def add(self, view, faces, cpu_s: float) -> None:
        self.frames += 1
        self.cpu_s += cpu_s
        # A box on no head is a false positive; a box on a head the frame's edge cuts, or a little off its centre,
        # found a true face all the same.
        self.false_positives += sum(not any(h.holds(f.x + f.width / 2, f.y + f.height / 2, 1.5) for h in view.heads)
                                    for f in faces)
        target = view.target
        found = target is not None and any(matches(target, f) for f in faces)
        if view.counted:
            self.counted[view.pupil] += 1
            self.hits[view.pupil] += found
        elif target is not None and target.whole and target.height_px >= MIN_FACE_PX:
            self.turned[view.pupil] += 1
            self.turned_hits[view.pupil] += found

    def recall(self, pupil: str) -> float:
        return self.hits[pupil] / self.counted[pupil] if self.counted[pupil] else float("nan")


def iou(centred: tuple[float, float, float, float], box) -> float:
    """Intersection over union of a box given by its centre and size and a detector's box (x, y, width, height)."""
    cx, cy, w, h = centred
    x0, y0 = max(cx - w / 2, box.x), max(cy - h / 2, box.y)
    x1, y1 = min(cx + w / 2, box.x + box.width), min(cy + h / 2, box.y + box.height)
    inter = max(0.0, x1 - x0) * max(0.0, y1 - y0)
    return inter / (w * h + box.width * box.height - inter)


def calibrate(out: Path) -> int:
    """The server's detector on the calibration grid: the table modelled perception reads, written to `out`."""
    started_at = datetime.datetime.now(datetime.timezone.utc)
    load_before = os.getloadavg()
    detector = FaceDetector()
    camera = PupilCamera()
    pupils = sorted(camera.figures)
    tones = {p: skin_tone(p) for p in pupils}
    distances, turns = CALIBRATION["distances"], sorted({abs(a) for a in CALIBRATION["head_yaws"]})
    hits = {t: np.zeros((len(distances), len(turns))) for t in tones.values()}
    counted = {t: np.zeros((len(distances), len(turns))) for t in tones.values()}
    confidence = {t: np.zeros((len(distances), len(turns))) for t in tones.values()}
    pairs = []  # (head, box) of every whole face found: the boxes' size and place on the head
    false_positives = frames = 0
    cpu = 0.0
    try:
        detector.detect_jpeg(camera.view(pupils[0], 1.5).jpeg)  # network set-up stays out of the figures
        for i, view in enumerate(camera.views(pupils, **CALIBRATION)):
            t = time.process_time()
            faces, _size = detector.detect_jpeg(view.jpeg)
            cpu += time.process_time() - t
            frames += 1
            false_positives += sum(not any(h.holds(f.x + f.width / 2, f.y + f.height / 2, 1.5) for h in view.heads)
                                   for f in faces)
            head = view.target
            if head is None or not (0 <= head.u <= camera.width and 0 <= head.v <= camera.height):
                continue  # the model sees no face whose centre is out of the frame
            tone = tones[view.pupil]
            d = distances.index(view.distance_m)
            a = min(range(len(turns)), key=lambda j: abs(turns[j] - abs(head.turned_deg)))
            counted[tone][d, a] += 1
            box = next((f for f in faces if matches(head, f)), None)
            if box is not None:
                hits[tone][d, a] += 1
                confidence[tone][d, a] += box.confidence
                if head.whole:
                    pairs.append((head, box))
            if i % 50 == 0:
                print(f"  {i} pictures", file=sys.stderr, flush=True)
    finally:
        camera.close()
    scale = [statistics.median(b.width / h.height_px for h, b in pairs),
             statistics.median(b.height / h.height_px for h, b in pairs)]
    shift = [statistics.median((b.x + b.width / 2 - h.u) / h.height_px for h, b in pairs),
             statistics.median((b.y + b.height / 2 - h.v) / h.height_px for h, b in pairs)]
    # how well a box placed by these medians on the true head overlaps the detector's: the bound a test can hold
    ious = sorted(iou((h.u + shift[0] * h.height_px, h.v + shift[1] * h.height_px, scale[0] * h.height_px,
                       scale[1] * h.height_px), b) for h, b in pairs)
    table = {
        "measured": {
            "date": started_at.strftime("%Y-%m-%dT%H:%M:%SZ"),
            "command": "MUJOCO_GL=egl python bench/faces.py --calibrate",
            "machine": f"{platform.machine()}, {os.cpu_count()} CPUs, {platform.python_implementation()} "
                       f"{platform.python_version()}",
            "load_before": [round(x, 2) for x in load_before],
            "load_after": [round(x, 2) for x in os.getloadavg()],
            "nice": os.nice(0),
            "frames": frames,
            "detector": detector.name, "threshold": detector.threshold,
            "pictures": "testbed/faces.py PupilCamera: 640x480 JPEG q80, the head camera's field of view and height, "
                        f"each pupil at distances {list(distances)} m, head turned {list(CALIBRATION['head_yaws'])} "
                        f"deg, camera panned {list(CALIBRATION['pans'])} deg; a face counts where its centre is in "
                        "the frame, found where a box matches it (testbed.faces.matches)",
            "cpu_ms_per_frame": round(cpu / max(frames, 1) * 1e3, 1),
            "false_positives_per_frame": round(false_positives / max(frames, 1), 4),
            "skin_tones": tones,
        },
        "distances_m": list(distances),
        "turns_deg": turns,
        "counted": {t: c.astype(int).tolist() for t, c in counted.items()},
        "recall": {t: np.round(np.divide(hits[t], counted[t], out=np.zeros_like(hits[t]), where=counted[t] > 0),
                               4).tolist() for t in hits},
        "confidence": {t: np.round(np.divide(confidence[t], hits[t], out=np.zeros_like(hits[t]),
                                             where=hits[t] > 0), 3).tolist() for t in hits},
        "box": {"scale": [round(x, 4) for x in scale], "shift": [round(x, 4) for x in shift], "boxes": len(pairs),
                "iou_with_detector": {"min": round(ious[0], 3), "p05": round(ious[len(ious) // 20], 3),
                                      "median": round(ious[len(ious) // 2], 3)}},
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(table, indent=1) + "\n")
    print(f"{frames} pictures, {cpu / max(frames, 1) * 1e3:.0f} ms CPU a frame; written {out}")
    for tone in hits:
        print(f"recall, {tone} skin (rows: distances {list(distances)} m; columns: turned {turns} deg)")
        for d, row in zip(distances, table["recall"][tone]):
            print(f"  {d:4.1f} m " + " ".join(f"{r:5.2f}" for r in row))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="a small grid (a minute or so)")
    parser.add_argument("--sizes", default="640,480,320,256,480+256,384+224,320+192",
                        help="CenterFace input widths to measure, comma-separated; a+b searches at both widths")
    parser.add_argument("--threshold", type=float, default=FaceDetector().threshold,
                        help="CenterFace's score threshold (the server's default unless given)")
    parser.add_argument("--calibrate", action="store_true",
                        help=f"measure the server's detector for modelled perception and write {TABLE.name}")
    parser.add_argument("--out", type=Path, default=TABLE, help="where --calibrate writes its table")
    args = parser.parse_args(argv)
    if args.calibrate:
        return calibrate(args.out)
    grid = QUICK if args.quick else FULL
    detectors: dict[str, Detector] = {"haar cascade (baseline)": CascadeDetector()}
    for size in args.sizes.split(","):
        detectors[f"centerface @{size}"] = FaceDetector(input_widths=tuple(int(w) for w in size.split("+")),
                                                                threshold=args.threshold)
    camera = PupilCamera()
    pupils = sorted(camera.figures)
    tallies = {name: Tally() for name in detectors}
    try:
        warm = camera.view(pupils[0], 1.5)
        for d in detectors.values():
            d.detect_jpeg(warm.jpeg)  # network set-up and first-call costs stay out of the figures
        started = time.monotonic()
        for i, view in enumerate(camera.views(pupils, **grid)):
            for name, d in detectors.items():
                t = time.process_time()
                faces, _size = d.detect_jpeg(view.jpeg)
                tallies[name].add(view, faces, time.process_time() - t)
            if i % 25 == 0:
                print(f"  {i} pictures, {time.monotonic() - started:.0f} s", file=sys.stderr)
    finally:
        camera.close()

    n = next(iter(tallies.values())).frames
    counted = next(iter(tallies.values())).counted
    print(f"{n} pictures 640x480 (JPEG q80): {', '.join(f'{p} ({skin_tone(p)} skin, {counted[p]} counted)' for p in pupils)}")
    print(f"CenterFace threshold {args.threshold}")
    print(f"grid: distances {grid['distances']} m, head turned {grid['head_yaws']} deg, camera panned {grid['pans']} deg;"
          f" counted: face turned <= {IN_VIEW_DEG:.0f} deg, whole in the frame, >= {MIN_FACE_PX:.0f} px tall")
    base_cpu = tallies["haar cascade (baseline)"].cpu_s / n
    header = (f"{'detector':<26}" + "".join(f"{p + ' recall':>22}" for p in pupils)
              + f"{'spread':>8}{'profiles':>10}{'FP/frame':>10}{'CPU ms':>8}{'x cascade':>10}  targets")
    print(header)
    for name, t in tallies.items():
        recalls = [t.recall(p) for p in pupils]
        spread = max(recalls) - min(recalls)
        turned = sum(t.turned_hits.values()) / max(1, sum(t.turned.values()))
        cpu = t.cpu_s / n
        met = min(recalls) >= 0.95 and spread <= 0.03 and cpu <= 3 * base_cpu
        print(f"{name:<26}" + "".join(f"{r:>22.3f}" for r in recalls)
              + f"{spread:>8.3f}{turned:>10.3f}{t.false_positives / n:>10.3f}{cpu * 1e3:>8.1f}{cpu / base_cpu:>10.2f}"
              + f"  {'met' if met else 'not met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
