"""Method ``3d``: entry point the runner imports; logic in ``vision.py``."""

from __future__ import annotations

from typing import Any

from svains.datasets.types import Dataset
from svains.navigation.vision import LcUpdater, PixelUpdater, make_vision_updater


def make_updater(dataset: Dataset, options: Any) -> PixelUpdater | LcUpdater:
    """The ``3d`` vision updater for ``dataset`` (``options``: a ``RunOptions``)."""
    return make_vision_updater("3d", dataset, options)
