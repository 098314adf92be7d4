"""The recorded stereo images against their calibration (``frontend.stereo_check``): a few
pairs spread over the recording, rectified with the data set's calibration, before any run."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

from svains.datasets.loader import stereo_pairs
from svains.datasets.types import Dataset
from svains.errors import DatasetError

log = logging.getLogger(__name__)

if TYPE_CHECKING:  # the front end imports OpenCV: only when a check runs (see below)
    from svains.frontend.stereo_check import StereoCheck

# Images whose brightest pixel is this dark hold next to nothing to track: 12-bit data in a
# 16-bit PNG keeps 4 bits of its high byte (0-15)
DARK_PEAK = 31
PAIRS = 5  # pairs looked at, evenly spread over the recording (about 0.1 s each at 1392x512)
UNIFORM_STD = 0.5  # grey levels: a camera's images this flat show nothing


def recorded_stereo_check(ds: Dataset, pairs: int = PAIRS) -> StereoCheck | None:
    """The check over ``pairs`` stereo pairs evenly spread over ``ds`` (None: no stereo images
    or no calibration)."""
    if ds.left is None or ds.right is None or ds.cam0 is None or ds.cam1 is None:
        return None
    # Imported here, not with the module: OpenCV starts its BLAS threads when loaded, and a
    # process that forks workers after that (a campaign, a process pool) leaves them hung.
    from svains.frontend.rectify import StereoRectifier
    from svains.frontend.stereo_check import ROW_OFFSET_WARN_PX, SWAPPED_FRACTION, check_pairs

    _, idx_l, idx_r = stereo_pairs(ds)
    if idx_l.size == 0:
        return None
    rect = StereoRectifier.from_calibration(ds.cam0, ds.cam1)
    pick = np.unique(np.linspace(0, idx_l.size - 1, min(pairs, idx_l.size)).round().astype(int))
    images = []
    raw = []
    peak = 0
    spread = [0.0, 0.0]  # the largest grey-level std of each camera's pairs looked at
    identical = 0
    for k in pick:
        try:
            left, right = ds.left.load(int(idx_l[k])), ds.right.load(int(idx_r[k]))
        except DatasetError:  # an unreadable file: the run drops that pair with a warning
            continue
        if left.shape == right.shape == (ds.cam0.resolution[1], ds.cam0.resolution[0]):
            images.append(rect.rectify_pair(left, right))
            raw.append((left, right))
            peak = max(peak, int(left.max()), int(right.max()))
            spread = [max(spread[0], float(left.std())), max(spread[1], float(right.std()))]
            identical += int(np.array_equal(left, right))
    for cam, (own, other) in enumerate((spread, spread[::-1])):
        if images and own < UNIFORM_STD and other >= UNIFORM_STD:
            # a dead, covered or capped camera: the run ends without fused vision, and only
            # "textureless" counts said why (a user's probe)
            log.warning("%s: cam%d's images are uniform (grey-level std below %g in the %d "
                        "stereo pairs looked at): a dead, covered or capped camera?", ds.root,
                        cam, UNIFORM_STD, len(images))  # fmt: skip
    if identical:
        log.warning("%s: cam0 and cam1 hold the same image in %d of %d stereo pairs looked at "
                    "(one camera written twice?): such pairs are dropped", ds.root, identical,
                    len(images))  # fmt: skip
    if images and peak <= DARK_PEAK:
        log.warning("%s: the images reach grey level %d of 255 at most (%d stereo pairs looked "
                    "at): 12-bit values in 16-bit files? svains keeps a 16-bit image's high byte; "
                    "scale them to the full 16 bits (value << 4)", ds.root, peak, len(images))
    check = check_pairs(images)
    if check.decided and not check.swapped and check.row_offset_px > ROW_OFFSET_WARN_PX:
        # rows that do not fit: the streams exchanged, each rectified with the other's
        # calibration, give exactly that where the two cameras' calibrations differ
        other = check_pairs([rect.rectify_pair(r, lft) for lft, r in raw])
        if other.decided and other.negative_fraction < 1.0 - SWAPPED_FRACTION:  # in order
            check.swapped_rows_px = other.row_offset_px
    return check


def check_stereo_images(ds: Dataset) -> StereoCheck | None:
    """Refuse a recording whose left and right images look swapped (``DatasetError`` naming
    the folders); the check (None without stereo images) for the caller to report."""
    check = recorded_stereo_check(ds)
    if check is not None and check.swapped:
        raise DatasetError(f"{ds.root}: cam0/cam1: {check.problem()}")
    return check
