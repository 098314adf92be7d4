"""Paper figure 8: tracked features on the left image, coloured by depth, outliers marked."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from numpy.typing import NDArray

from svains.frontend.types import StereoTracks
from svains.geometry.camera import RectifiedStereo


def figure_features_depth(
    img_left: NDArray[np.uint8],
    tracks: StereoTracks,
    rig: RectifiedStereo,
    path: Path,
    title: str = "",
    max_depth_m: float | None = None,
) -> Path:
    """Draw the features of ``tracks`` at time k on the rectified left image (H, W): inliers as
    dots coloured by depth (m, triangulated from the pair at k by eq. 10), outliers as red
    crosses. Writes a PNG to ``path`` and returns it."""
    fig = Figure(figsize=(img_left.shape[1] / 100.0, img_left.shape[0] / 100.0 + 0.6), dpi=100)
    ax = fig.add_axes((0.0, 0.0, 0.88, 0.92))
    cax = fig.add_axes((0.90, 0.05, 0.025, 0.82))
    ax.imshow(img_left, cmap="gray", vmin=0, vmax=255)
    depth = rig.triangulate(tracks.uv_left, tracks.uv_right)[:, 2]
    inl = tracks.inlier & np.isfinite(depth)
    vmax = (
        max_depth_m
        if max_depth_m is not None
        else (float(np.percentile(depth[inl], 95)) if inl.any() else 1.0)
    )
    sc = ax.scatter(
        tracks.uv_left[inl, 0],
        tracks.uv_left[inl, 1],
        c=depth[inl],
        s=14,
        cmap="jet",
        vmin=0.0,
        vmax=vmax,
        edgecolors="none",
        label="inlier",
    )
    out = ~tracks.inlier
    ax.scatter(
        tracks.uv_left[out, 0],
        tracks.uv_left[out, 1],
        marker="x",
        s=20,
        c="red",
        linewidths=1.0,
        label="outlier",
    )
    fig.colorbar(sc, cax=cax, label="depth [m]")
    ax.set_xlim(0, img_left.shape[1] - 1)
    ax.set_ylim(img_left.shape[0] - 1, 0)
    ax.set_axis_off()
    ax.legend(loc="lower left", fontsize=8)
    ax.set_title(title or f"{int(inl.sum())} inliers, {int(out.sum())} outliers", fontsize=9)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    return path
