"""Procedural faces for the stand-in's screen, one per LuxAI emotion name, drawn with OpenCV.

LuxAI's robot plays video clips; the stand-in only needs faces a person (and a test) can tell apart, so each
emotion is a small set of drawing parameters: eye openness, pupils, brows, mouth curve and opening, extras.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType

import cv2
import numpy as np


@dataclass(frozen=True)
class FaceParams:
    """Drawing parameters; lengths are fractions of the screen height."""

    eye_open: float = 1.0  # 0 closed (a line) .. 1.3 wide
    left_eye_open: float | None = None  # overrides eye_open for the robot's left eye (viewer's right)
    pupil: float = 0.45  # pupil radius relative to the eye
    pupil_dx: float = 0.0  # gaze, -1 .. 1
    brow_tilt: float = 0.0  # degrees; positive lowers the inner ends (angry), negative raises them (sad)
    brow_raise: float = 0.0  # fraction of height; raised brows (surprise)
    mouth_curve: float = 0.3  # positive smiles, negative frowns
    mouth_open: float = 0.0  # 0 closed .. 1 wide open
    mouth_width: float = 0.35
    mouth_round: bool = False  # an "o" (kiss, surprise, scream)
    tongue: bool = False
    tears: bool = False
    blush: bool = False
    dirt: bool = False
    sweat: bool = False
    zzz: bool = False
    toothbrush: bool = False
    bg: tuple[int, int, int] = (18, 20, 28)  # RGB


FACES = MappingProxyType({
    "neutral": FaceParams(mouth_curve=0.05),
    "happy": FaceParams(eye_open=0.9, mouth_curve=0.9, mouth_open=0.35),
    "happy_blinking": FaceParams(eye_open=0.15, mouth_curve=0.9, mouth_open=0.3),
    "showing_smile": FaceParams(eye_open=0.8, mouth_curve=1.0, mouth_open=0.5, mouth_width=0.5),
    "sad": FaceParams(eye_open=0.7, pupil_dx=0.0, brow_tilt=-22, mouth_curve=-0.7),
    "cry": FaceParams(eye_open=0.5, brow_tilt=-25, mouth_curve=-0.9, mouth_open=0.3, tears=True),
    "angry": FaceParams(eye_open=0.7, pupil=0.55, brow_tilt=28, mouth_curve=-0.5, mouth_width=0.3),
    "afraid": FaceParams(eye_open=1.25, pupil=0.3, brow_tilt=-18, brow_raise=0.05, mouth_curve=-0.4,
                         mouth_open=0.35, sweat=True),
    "surprise": FaceParams(eye_open=1.3, pupil=0.3, brow_raise=0.08, mouth_open=0.7, mouth_round=True),
    "scream": FaceParams(eye_open=1.3, pupil=0.25, brow_tilt=-15, brow_raise=0.08, mouth_open=1.0,
                         mouth_round=True, mouth_width=0.3),
    "confused": FaceParams(eye_open=0.9, left_eye_open=0.6, pupil_dx=0.5, brow_tilt=12, mouth_curve=-0.2),
    "disgusted": FaceParams(eye_open=0.5, brow_tilt=20, mouth_curve=-0.6, mouth_width=0.3, tongue=True),
    "blowing_raspberry": FaceParams(eye_open=0.4, mouth_curve=0.0, mouth_open=0.2, tongue=True),
    "kiss": FaceParams(eye_open=0.1, mouth_open=0.25, mouth_round=True, mouth_width=0.12, blush=True),
    "shy": FaceParams(eye_open=0.6, pupil_dx=-0.6, mouth_curve=0.4, mouth_width=0.2, blush=True),
    "one_eye_wink": FaceParams(eye_open=1.0, left_eye_open=0.05, mouth_curve=0.8),
    "yawn": FaceParams(eye_open=0.1, brow_raise=0.03, mouth_open=0.9, mouth_round=True, zzz=True),
    "breathing_exercise": FaceParams(eye_open=0.05, mouth_open=0.2, mouth_round=True, mouth_width=0.15),
    "calming_down": FaceParams(eye_open=0.2, brow_tilt=-8, mouth_curve=0.3),
    "brushing_teeth": FaceParams(eye_open=0.8, mouth_curve=0.6, mouth_open=0.4, toothbrush=True),
    "dirty_face": FaceParams(eye_open=0.9, mouth_curve=-0.2, dirt=True),
    "with_a_cold": FaceParams(eye_open=0.5, brow_tilt=-10, mouth_curve=-0.3, blush=True, sweat=True),
    "talking": FaceParams(mouth_curve=0.2, mouth_open=0.5),
})
EMOTIONS = tuple(sorted(FACES))  # must equal robot_models' emotion list (checked in tests)


def normalise_emotion(name: str) -> str:
    """Accept "happy" or LuxAI's "QT/happy"; raise ValueError naming the valid emotions otherwise."""
    short = name[3:] if name.startswith("QT/") else name
    if short not in FACES:
        raise ValueError(f"unknown emotion {name!r}; valid emotions: {', '.join(EMOTIONS)} (optionally as QT/<name>)")
    return short


def draw_face(emotion: str, width: int, height: int, *, talking_phase: float | None = None,
              voice_level: float | None = None) -> np.ndarray:
    """An RGB uint8 image (height x width) of the face for `emotion`.

    talking_phase (seconds) animates the mouth as if speaking; None draws the emotion's still mouth.
    voice_level (0..1, the operator's voice played by the robot) opens the mouth in proportion; it wins over
    talking_phase.
    """
    p = FACES[normalise_emotion(emotion)]
    img = np.zeros((height, width, 3), np.uint8)
    img[:] = p.bg
    h = float(height)
    cx = width / 2.0
    white, black = (240, 240, 245), (10, 10, 14)
    eye_y = 0.42 * h
    eye_dx = 0.22 * width
    eye_r = 0.16 * h
    mouth_open = p.mouth_open
    if talking_phase is not None:
        # Two incommensurate frequencies look less mechanical than one sine.
        wave = math.sin(2 * math.pi * 3.1 * talking_phase) * math.cos(2 * math.pi * 1.3 * talking_phase)
        mouth_open = 0.15 + 0.55 * abs(wave)
    if voice_level is not None:
        mouth_open = 0.05 + 0.8 * min(1.0, max(0.0, voice_level))
        talking_phase = talking_phase if talking_phase is not None else 0.0  # an open mouth, not an "o"

    for side, sx in (("right", -1), ("left", 1)):  # robot's right eye is on the viewer's left
        ex = cx + sx * eye_dx
        openness = p.left_eye_open if (side == "left" and p.left_eye_open is not None) else p.eye_open
        ry = max(eye_r * min(openness, 1.3), 0.0)
        center = (int(ex), int(eye_y))
        if ry < 0.12 * eye_r:  # closed: a gentle arc
            cv2.ellipse(img, center, (int(eye_r), int(0.35 * eye_r)), 0, 200, 340, white, max(2, int(h / 40)),
                        cv2.LINE_AA)
        else:
            cv2.ellipse(img, center, (int(eye_r), int(ry)), 0, 0, 360, white, -1, cv2.LINE_AA)
            pr = int(eye_r * p.pupil)
            px = int(ex + p.pupil_dx * (eye_r - pr) * 0.8)
            cv2.circle(img, (px, int(eye_y)), min(pr, int(ry)), black, -1, cv2.LINE_AA)
            cv2.circle(img, (px + pr // 3, int(eye_y) - pr // 3), max(1, pr // 4), white, -1, cv2.LINE_AA)
        # Brow: inner end toward the centre; positive tilt lowers the inner end.
        by = eye_y - eye_r * 1.45 - p.brow_raise * h
        half = eye_r * 0.9
        tilt = math.radians(p.brow_tilt)
        inner = (ex - sx * half, by + math.sin(tilt) * half)
        outer = (ex + sx * half, by - math.sin(tilt) * half)
        cv2.line(img, (int(inner[0]), int(inner[1])), (int(outer[0]), int(outer[1])), white,
                 max(2, int(h / 30)), cv2.LINE_AA)
        if p.tears:
            ty = int(eye_y + eye_r * 1.1)
            cv2.ellipse(img, (int(ex + sx * eye_r * 0.5), ty + int(0.06 * h)), (int(0.03 * h), int(0.06 * h)), 0, 0,
                        360, (90, 160, 255), -1, cv2.LINE_AA)
        if p.blush:
            cv2.ellipse(img, (int(ex + sx * eye_r * 0.6), int(eye_y + eye_r * 1.4)), (int(0.08 * h), int(0.04 * h)),
                        0, 0, 360, (230, 110, 130), -1, cv2.LINE_AA)

    my = 0.8 * h
    mw = p.mouth_width * width / 2
    if p.mouth_round or (talking_phase is None and mouth_open > 0.6 and abs(p.mouth_curve) < 0.2):
        ry = int(0.05 * h + 0.1 * h * mouth_open)
        cv2.ellipse(img, (int(cx), int(my)), (int(max(mw, ry * 0.8)), ry), 0, 0, 360, (200, 60, 70), -1, cv2.LINE_AA)
        cv2.ellipse(img, (int(cx), int(my)), (int(max(mw, ry * 0.8)), ry), 0, 0, 360, white, 2, cv2.LINE_AA)
    else:
        # Mouth as a filled region between an upper and a lower curve. Image y grows downward, so a smile's
        # middle sits lower than its corners.
        xs = np.linspace(-1, 1, 41)
        upper = my + p.mouth_curve * 0.08 * h * (1 - xs**2)
        gap = mouth_open * 0.16 * h * (1 - xs**2)
        lower = upper + gap
        top = np.stack([cx + xs * mw, upper], axis=1)
        bottom = np.stack([cx + xs[::-1] * mw, lower[::-1]], axis=1)
        poly = np.concatenate([top, bottom]).astype(np.int32)
        if mouth_open > 0.02:
            cv2.fillPoly(img, [poly], (200, 60, 70), cv2.LINE_AA)
        cv2.polylines(img, [poly], True, white, max(2, int(h / 40)), cv2.LINE_AA)
    if p.tongue:
        cv2.ellipse(img, (int(cx + 0.1 * mw), int(my + 0.06 * h)), (int(0.07 * h), int(0.08 * h)), 0, 0, 180,
                    (240, 120, 150), -1, cv2.LINE_AA)
    if p.dirt:
        for dx, dy in ((-0.3, 0.62), (0.25, 0.68), (0.05, 0.2)):
            cv2.circle(img, (int(cx + dx * width), int(dy * h)), int(0.035 * h), (120, 85, 50), -1, cv2.LINE_AA)
    if p.sweat:
        cv2.ellipse(img, (int(cx + 0.4 * width), int(0.2 * h)), (int(0.025 * h), int(0.05 * h)), 0, 0, 360,
                    (120, 190, 255), -1, cv2.LINE_AA)
    if p.zzz:
        cv2.putText(img, "z", (int(cx + 0.36 * width), int(0.22 * h)), cv2.FONT_HERSHEY_SIMPLEX, h / 160, white, 2,
                    cv2.LINE_AA)
    if p.toothbrush:
        cv2.rectangle(img, (int(cx + mw * 0.6), int(my - 0.02 * h)), (int(cx + mw * 1.9), int(my + 0.02 * h)),
                      (80, 170, 240), -1)
    return img
