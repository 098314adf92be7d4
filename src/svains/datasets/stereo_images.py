"""The recorded stereo images against their calibration (``frontend.stereo_check``): a few
pairs spread over the recording, rectified with the data set's calibration, before any run."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from svains.datasets.loader import stereo_pairs
from svains.datasets.types import Dataset
from svains.errors import DatasetError

if TYPE_CHECKING:  # the front end imports OpenCV: only when a check runs (see below)
    from svains.frontend.stereo_check import StereoCheck

PAIRS = 5  # pairs looked at, evenly spread over the recording (about 0.1 s each at 1392x512)


def recorded_stereo_check(ds: Dataset, pairs: int = PAIRS) -> StereoCheck | None:
    """The check over ``pairs`` stereo pairs evenly spread over ``ds`` (None: no stereo images
    or no calibration)."""
    if ds.left is None or ds.right is None or ds.cam0 is None or ds.cam1 is None:
        return None
    # Imported here, not with the module: OpenCV starts its BLAS threads when loaded, and a
    # process that forks workers after that (a campaign, a process pool) leaves them hung.
    from svains.frontend.rectify import StereoRectifier
    from svains.frontend.stereo_check import check_pairs

    _, idx_l, idx_r = stereo_pairs(ds)
    if idx_l.size == 0:
        return None
    rect = StereoRectifier.from_calibration(ds.cam0, ds.cam1)
    pick = np.unique(np.linspace(0, idx_l.size - 1, min(pairs, idx_l.size)).round().astype(int))
    images = []
    for k in pick:
        try:
            left, right = ds.left.load(int(idx_l[k])), ds.right.load(int(idx_r[k]))
        except DatasetError:  # an unreadable file: the run drops that pair with a warning
            continue
        if left.shape == right.shape == (ds.cam0.resolution[1], ds.cam0.resolution[0]):
            images.append(rect.rectify_pair(left, right))
    return check_pairs(images)


def check_stereo_images(ds: Dataset) -> StereoCheck | None:
    """Refuse a recording whose left and right images look swapped (``DatasetError`` naming
    the folders); the check (None without stereo images) for the caller to report."""
    check = recorded_stereo_check(ds)
    if check is not None and check.swapped:
        raise DatasetError(f"{ds.root}: cam0/cam1: {check.problem()}")
    return check
