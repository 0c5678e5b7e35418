"""Figures of many equal panels (the benchmark's planes, the sweep's maps) placed at fixed margins.

matplotlib's constrained layout measures every text of a figure before it draws it: on a 4 x 3 grid of log-scaled
scatter panels that pass is a large part of the figure's cost (docs/performance.md). The panels here all carry the
same things (a title of up to two lines, axis labels, log tick labels such as 2 x 10^6), so their margins are known
in advance and `panel_grid` places them in inches: the same picture, drawn once.
"""

from __future__ import annotations

import numpy as np

__all__ = ["panel_grid", "log_span"]

#: space around each panel's axes, inches: left (y tick labels and label), right, bottom (x tick labels and label),
#: top (a title of two lines)
_LEFT, _RIGHT, _BOTTOM, _TOP = 0.95, 0.2, 0.6, 0.5
#: the gap below a panel whose x axis the panel below shows (`sharex`), inches
_SHARED_GAP = 0.12
#: the colorbar's strip at the figure's right: its gap, its width and the room for its ticks and label, inches
_CBAR_GAP, _CBAR_W, _CBAR_LABEL = 0.3, 0.18, 0.9


def panel_grid(rows: int, cols: int, *, width: float, height: float, colorbar: bool = True,
               suptitle: float = 0.0, margins: tuple[float, float, float, float] | None = None,
               sharex: bool = False):
    """A figure of `rows` x `cols` panels of `width` x `height` inches each (the axes inside at fixed margins:
    `margins` = (left, right, bottom, top) inches, default room for two-line titles and log tick labels), a
    colorbar axes at the right spanning the middle 60 % of the grid's height when `colorbar`, and `suptitle`
    inches of room above the grid. `sharex`: every panel shares the first one's x axis, and only the bottom row
    labels it. Returns (figure, axes as a rows x cols array, colorbar axes or None)."""
    import matplotlib.pyplot as plt

    left, right, bottom, top = margins if margins is not None else (_LEFT, _RIGHT, _BOTTOM, _TOP)
    strip = _CBAR_GAP + _CBAR_W + _CBAR_LABEL if colorbar else 0.0
    fig_w, grid_h = cols * width + strip, rows * height
    fig_h = grid_h + suptitle
    # the panels' titles sit at their axes' top (axes.titley = 1.0): left to matplotlib, the title's height is
    # found at every draw by measuring the top axis's tick labels to lift it above them (a fifth of a study
    # figure's cost), and these panels have none there, so the title sits where it would anyway
    with plt.rc_context({"axes.titley": 1.0}):
        fig = plt.figure(figsize=(fig_w, fig_h))
        axes = np.empty((rows, cols), dtype=object)
        # shared x: the x labels only below the grid, so the rows above keep a small gap, not the bottom margin
        gap = _SHARED_GAP if sharex else bottom
        ax_h = (grid_h - bottom - rows * top - (rows - 1) * gap) / rows
        for r in range(rows):
            for c in range(cols):
                x0 = c * width + left
                y0 = bottom + (rows - 1 - r) * (ax_h + top + gap)
                ax = fig.add_axes((x0 / fig_w, y0 / fig_h, (width - left - right) / fig_w, ax_h / fig_h))
                if sharex and (r, c) != (0, 0):
                    ax.sharex(axes[0, 0])
                if sharex and r < rows - 1:
                    ax.tick_params(labelbottom=False)
                axes[r, c] = ax
        cax = None
        if colorbar:
            span = 0.6 * grid_h
            cax = fig.add_axes(((cols * width + _CBAR_GAP) / fig_w, (grid_h - span) / 2 / fig_h, _CBAR_W / fig_w,
                                span / fig_h))
    return fig, axes, cax


def log_span(ax, axis: str, values, min_decades: float = 1.0, pad: float = 1.25) -> None:
    """Log-scale `axis` ("x" or "y") of `ax` over `values`, at least `min_decades` wide (around their geometric
    middle) and padded by the factor `pad` each side: a few close values would otherwise get ticks at 1.2 x 10^6,
    1.4 x 10^6, ..., whose labels outgrow the fixed margins."""
    import math

    finite = [float(v) for v in values if v > 0 and math.isfinite(v)]
    getattr(ax, f"set_{axis}scale")("log")
    if not finite:
        return
    lo, hi = min(finite), max(finite)
    if hi / lo < 10.0 ** min_decades:
        mid, half = math.sqrt(lo * hi), 10.0 ** (min_decades / 2)
        lo, hi = mid / half, mid * half
    getattr(ax, f"set_{axis}lim")(lo / pad, hi * pad)
