"""Completion marker of a data set written by svains (``mav0/svains_complete.yaml``).

``svains simulate`` writes the marker last, inside a folder that is renamed into place only
when whole (``svains.outputs``). A data set that carries svains' own simulator metadata
(``state_groundtruth_estimate0/scenario.yaml``) but no marker was cut short (or copied in
part): readers warn. Data sets from elsewhere (EuRoC, KITTI, ...) have no metadata and are
never warned about.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import yaml

log = logging.getLogger(__name__)

MARKER = "svains_complete.yaml"
SIM_METADATA = "state_groundtruth_estimate0/scenario.yaml"


def write_marker(mav0: Path, streams: Sequence[str], writer: str) -> Path:
    """Write the marker listing the stream folders written (call it last)."""
    path = mav0 / MARKER
    text = yaml.safe_dump({"complete": True, "writer": writer, "streams": list(streams)})
    path.write_text(text, encoding="utf-8")
    return path


def incomplete_reason(mav0: Path) -> str | None:
    """Why the svains data set in ``mav0`` may be partial, or None (complete or not svains')."""
    marker = mav0 / MARKER
    if not marker.is_file():
        if (mav0 / SIM_METADATA).is_file():
            return (
                f"{mav0}: svains simulator data without the completion marker {MARKER}: it may "
                "be partial (an interrupted 'svains simulate' or an incomplete copy)"
            )
        return None
    try:
        listed = yaml.safe_load(marker.read_text(encoding="utf-8")) or {}
    except yaml.YAMLError:
        return f"{marker}: unreadable completion marker"
    streams = listed.get("streams", []) if isinstance(listed, dict) else []
    absent = [s for s in streams if not (mav0 / str(s)).is_dir()]
    if absent:
        return f"{mav0}: stream folder(s) {', '.join(map(str, absent))} listed in {MARKER} absent"
    return None


def warn_if_incomplete(mav0: Path) -> None:
    """Log a warning when :func:`incomplete_reason` finds one."""
    reason = incomplete_reason(mav0)
    if reason is not None:
        log.warning("%s", reason)
