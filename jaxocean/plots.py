"""Pictures a person looks at: display conversions and contact sheets (matplotlib, PNG).

Protocol: functions take linear images / geometry as arrays (numpy or jax) and write PNG
files atomically; nothing here is differentiable or used inside a model.

* ``normal_to_rgb(normal (H,W,3), mask=None) -> uint8 (H,W,3)``: the usual (n + 1) / 2
  encoding.
* ``roughness_to_rgb(roughness (H,W), mask=None, vmin=1e-5, vmax=1e-1) -> uint8 (H,W,3)``:
  :func:`log_to_rgb` with the range of sea roughness.
* ``log_to_rgb(values (H,W), mask=None, vmin, vmax) -> uint8 (H,W,3)``: a log10 colour map
  (magma: black at ``vmin``, white at ``vmax``) of any positive per-pixel quantity (an
  error map, say).
* ``display(linear_image, exposure=1.0, mode="bruneton") -> uint8 (H,W,3)``: tone-mapped.
* ``contact_sheet(path, rows, col_titles=None, row_titles=None, title=None, cell_titles=None)``:
  a grid of images (each uint8 or float in [0, 1]) saved as one PNG; ``col_titles`` head the
  columns (above the first row), ``cell_titles`` (lists like ``rows``) name single images.
* ``polar_room(ax, radii)``: a polar axis from 0 to 15% past the largest radius.
* ``save_figure(fig, path, dpi=100) -> Path``: a matplotlib figure as PNG, atomically, then
  closed.

The uint8 conversions draw NaN pixels black, as they draw the pixels outside a ``mask``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jaxocean.files import atomic_write

__all__ = ["normal_to_rgb", "roughness_to_rgb", "log_to_rgb", "display", "contact_sheet", "save_figure",
           "polar_room"]


def _to_uint8(rgb, mask=None):
    """Colours in [0, 1] ``(..., 3)`` as uint8; pixels outside ``mask`` and pixels with a
    NaN channel black (a NaN's cast to uint8 is undefined, and a partly NaN normal would
    show as a colour of its own)."""
    rgb = np.asarray(rgb)
    keep = ~np.isnan(rgb).any(-1)
    if mask is not None:
        keep &= np.asarray(mask, bool)
    return (np.where(keep[..., None], rgb, 0.0) * 255 + 0.5).astype(np.uint8)


def normal_to_rgb(normal, mask=None):
    """Unit normals as the usual ``(n + 1) / 2`` colours; pixels outside ``mask`` (and NaN
    normals) black."""
    n = np.asarray(normal, np.float32)
    return _to_uint8(np.clip((n + 1.0) * 0.5, 0.0, 1.0), mask)


def roughness_to_rgb(roughness, mask=None, vmin=1e-5, vmax=1e-1):
    """Roughness sigma^2 on a log10 colour map from ``vmin`` to ``vmax`` (sky black)."""
    return log_to_rgb(roughness, mask, vmin, vmax)


def log_to_rgb(values, mask=None, vmin=1e-6, vmax=1e-1):
    """Positive values on a log10 magma colour map: black at ``vmin`` (and below), white at
    ``vmax`` (and above); pixels outside ``mask`` (and NaN values) black."""
    import matplotlib

    r = np.log10(np.clip(np.asarray(values, np.float64), vmin, vmax))
    s = (r - np.log10(vmin)) / (np.log10(vmax) - np.log10(vmin))
    rgb = matplotlib.colormaps["magma"](s)[..., :3]
    return _to_uint8(np.where(np.isnan(s)[..., None], np.nan, rgb), mask)


def display(linear_image, exposure=1.0, mode="bruneton"):
    """Tone-mapped uint8 image from linear radiance; pixels with a NaN channel black."""
    from jaxocean.shading import tonemap

    return _to_uint8(np.asarray(tonemap(np.asarray(linear_image, np.float32), exposure, mode)))


def contact_sheet(path, rows, col_titles=None, row_titles=None, title=None, cell_inches=2.6, cell_titles=None):
    """Save a grid of images (``rows``: list of lists of (H,W,3) arrays) as one PNG.

    ``cell_titles[i][j]`` (optional, None or missing: none) titles image ``j`` of row ``i``,
    in place of its column title: for rows whose images are not what their column says."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n_rows, n_cols = len(rows), max(len(r) for r in rows)
    fig, axes = plt.subplots(n_rows, n_cols, figsize=(cell_inches * n_cols, cell_inches * 0.8 * n_rows + 0.4),
                             squeeze=False)
    for i, row in enumerate(rows):
        for j in range(n_cols):
            ax = axes[i][j]
            ax.axis("off")
            if j < len(row) and row[j] is not None:
                ax.imshow(row[j])
            named = (cell_titles[i] if cell_titles and i < len(cell_titles) else None) or []
            own = named[j] if j < len(named) else None
            if own is not None:
                ax.set_title(own, fontsize=9)
            elif i == 0 and col_titles and j < len(col_titles):
                ax.set_title(col_titles[j], fontsize=9)
            if j == 0 and row_titles and i < len(row_titles):
                ax.text(-0.04, 0.5, row_titles[i], transform=ax.transAxes, ha="right", va="center", fontsize=8,
                        rotation=90)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)


def polar_room(ax, radii, margin: float = 0.15) -> None:
    """Set polar ``ax``'s radial axis from 0 to ``1 + margin`` times the largest finite of
    ``radii``: matplotlib's own limit puts the outermost point on the rim, its marker half
    clipped. No finite positive radius: the axis is left as it is."""
    r = np.asarray(radii, np.float64).ravel()
    r = r[np.isfinite(r)]
    if r.size and r.max() > 0:
        ax.set_rlim(0.0, (1.0 + margin) * float(r.max()))


def save_figure(fig, path, dpi: int = 100) -> Path:
    """Save a matplotlib figure as PNG atomically, close it, return the path."""
    import matplotlib.pyplot as plt

    try:
        return atomic_write(Path(path), lambda tmp: fig.savefig(tmp, dpi=dpi, format="png"))
    finally:
        plt.close(fig)
