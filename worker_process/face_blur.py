"""Face blurring's pixels (`serve --blur-faces`): shared by the server (JPEG frames for spectators and the recording,
vr_teleop_server/features/face_blur.py) and the video encoder process, which loads no vr_teleop_server module.

A face's box is grown by MARGIN of its size on every side (the box is the detector's, from a frame up to a hold's
age earlier: the margin covers a head that moved meanwhile), shrunk to CELLS x CELLS averages and smoothed back up:
what remains is a blob of the face's mean colours, which neither a person nor the detector reads as a face. Three
cells, because the detector still found 56 of 63 faces blurred into 6 x 6 cells and 4 into 4 x 4, none into 3 x 3
(the stand-in's pupils at 1-2.6 m, heads turned up to 20 degrees; a Gaussian blur over the box left 57). A frame
without a recent detection to trust is blurred whole (WHOLE_FRAME), in cells of WHOLE_CELL_PX.
"""

from __future__ import annotations

import math
from typing import Literal

import cv2
import numpy as np

MARGIN = 0.3  # of the box's width and height, on every side
CELLS = 3  # a blurred face keeps this many averages across
WHOLE_CELL_PX = 24  # a frame blurred whole: one average per this many pixels (a far face is a cell or two)
WHOLE_FRAME = "whole"

Box = tuple[int, int, int, int]  # x, y, width, height in the frame's pixels
Regions = tuple[Box, ...] | Literal["whole"]


def blur_regions(image: np.ndarray, regions: Regions, margin: float = MARGIN) -> np.ndarray:
    """Blurs `regions` of `image` in place (a copy's, when the pixels are shared) and returns it."""
    height, width = image.shape[:2]
    if regions == WHOLE_FRAME:
        small = cv2.resize(image, (max(1, width // WHOLE_CELL_PX), max(1, height // WHOLE_CELL_PX)),
                           interpolation=cv2.INTER_AREA)
        image[:] = cv2.resize(small, (width, height), interpolation=cv2.INTER_LINEAR)
        return image
    for x, y, w, h in regions:
        x0, y0 = max(0, math.floor(x - margin * w)), max(0, math.floor(y - margin * h))
        x1, y1 = min(width, math.ceil(x + w + margin * w)), min(height, math.ceil(y + h + margin * h))
        if x1 <= x0 or y1 <= y0:
            continue
        small = cv2.resize(image[y0:y1, x0:x1], (min(CELLS, x1 - x0), min(CELLS, y1 - y0)),
                           interpolation=cv2.INTER_AREA)
        image[y0:y1, x0:x1] = cv2.resize(small, (x1 - x0, y1 - y0), interpolation=cv2.INTER_LINEAR)
    return image
