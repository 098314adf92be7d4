"""Method ``tc``: entry point the runner imports; logic in ``vision.py``."""

from __future__ import annotations

from typing import Any

from svains.datasets.types import Dataset
from svains.navigation.vision import LcUpdater, PixelUpdater, make_vision_updater


def make_updater(dataset: Dataset, options: Any) -> PixelUpdater | LcUpdater:
    """The ``tc`` vision updater for ``dataset`` (``options``: a ``RunOptions``)."""
    return make_vision_updater("tc", dataset, options)
