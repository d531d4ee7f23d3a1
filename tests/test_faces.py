"""The face detector finds every pupil of the stand-in, whatever its skin tone: a floor under its recall on rendered
pictures (testbed/faces.py; bench/faces.py measures the full grid and the cascade it replaced)."""

from __future__ import annotations

import pytest

from sim.pupils import SKIN_TONES, skin_tone
from testbed.faces import PupilCamera, matches
from vr_teleop_server.features.faces import FaceDetector


@pytest.fixture(scope="module")
def camera():
    cam = PupilCamera()
    yield cam
    cam.close()


def test_the_pupils_span_the_skin_tones():
    from sim.pupils import PUPILS

    tones = {skin_tone(p.name) for p in PUPILS}
    assert tones == set(SKIN_TONES) and len(tones) >= 3
    # Clearly different: each tone's luminance at least 0.2 (of 1) from the next.
    luma = sorted(0.2126 * r + 0.7152 * g + 0.0722 * b for r, g, b, _ in SKIN_TONES.values())
    assert all(b - a >= 0.2 for a, b in zip(luma, luma[1:])), luma


@pytest.mark.slow  # 24 views of the classroom drawn and searched for faces
def test_recall_on_every_skin_tone_has_a_floor(camera):
    detector = FaceDetector()
    hits: dict[str, list[bool]] = {}
    false_positives = frames = 0
    for view in camera.views(distances=(0.8, 1.0, 1.8, 2.4), head_yaws=(-30.0, 0.0, 30.0), pans=(0.0, 15.0)):
        faces, (width, height) = detector.detect_jpeg(view.jpeg)
        assert (width, height) == (camera.width, camera.height)
        frames += 1
        false_positives += sum(not any(h.holds(f.x + f.width / 2, f.y + f.height / 2, 1.5) for h in view.heads)
                               for f in faces)
        if view.counted:
            hits.setdefault(view.pupil, []).append(any(matches(view.target, f) for f in faces))
    assert set(hits) == {"child_left", "adult_centre", "child_right"}
    recall = {p: sum(h) / len(h) for p, h in hits.items()}
    assert all(len(h) >= 8 for h in hits.values()), {p: len(h) for p, h in hits.items()}
    # The grid holds the near faces (0.8 m: 80-100 px tall) a search at too few widths missed, the deep-skinned
    # child's first. The detector finds every face here (18 pictures of each child, 24 of the adult), the deep-
    # skinned child's at 0.30 and up against a 0.25 threshold; the floor allows one miss per pupil (17 of 18).
    assert min(recall.values()) >= 0.94, recall
    assert max(recall.values()) - min(recall.values()) <= 0.06, recall
    assert false_positives / frames <= 0.1, (false_positives, frames)


def test_a_face_turned_away_is_not_found(camera):
    """The floor is not met by boxes everywhere: the back of a head holds no face."""
    view = camera.view("child_right", 1.2, head_yaw_deg=180.0)
    faces, _ = FaceDetector().detect_jpeg(view.jpeg)
    assert not any(matches(view.target, f) for f in faces), faces


def test_a_frame_that_is_not_a_jpeg_is_no_frame():
    assert FaceDetector().detect_jpeg(b"not a jpeg") is None
