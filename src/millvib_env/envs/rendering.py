"""A figure of the first environment's recent motion: displacement, velocity, gains or valve command,
and the severity so far. Used by `render()` (rgb_array and human) and works with RecordVideo.

The figure is built once per environment (axes, lines, layout); each frame only replaces the lines' data,
rescales the axes and redraws. A full rebuild with a layout pass per frame made recording an episode take
minutes (the timing suite's `test_render_frame` measures a frame: `python scripts/timing_suite.py -k render`,
docs/performance.md)."""

from __future__ import annotations

import math
import time

import numpy as np

from millvib_env.severity import vibration_severity

_GAINS = ("KP", "KI", "KD")


def _build(figure, mode: str) -> dict:
    figure.clf()
    ax_x, ax_v, ax_c = figure.subplots(3, 1, sharex=True)
    art = {"axes": (ax_x, ax_v, ax_c), "mode": mode}
    (art["x"],) = ax_x.plot([], [], lw=0.8)
    ax_x.set_ylabel("x (um)")
    (art["v"],) = ax_v.plot([], [], lw=0.8, color="tab:orange")
    ax_v.set_ylabel("v (mm/s)")
    if mode == "gain":
        art["c"] = [ax_c.step([], [], where="post", label=f"log10 {name}")[0] for name in _GAINS]
        ax_c.legend(fontsize=7, loc="upper left")
        ax_c.set_ylabel("gains")
    else:
        art["c"] = [ax_c.step([], [], where="post", color="tab:green")[0]]
        ax_c.set_ylabel("u (V)")
    ax_c.set_xlabel("t (ms)")
    for ax in (ax_x, ax_v, ax_c):
        ax.grid(alpha=0.3)
    art["title"] = figure.suptitle("", fontsize=9)
    figure.tight_layout(rect=(0, 0, 1, 0.95))  # once: the layout does not change from frame to frame
    return art


def render_frame(core, figure=None, *, human: bool = False, fps: float | None = None):
    """Draw the frame of `core`'s first environment. rgb_array: returns (the frame, the figure). human: shows it
    and returns (None, the figure), paced to at most `fps` frames a second of wall time (Gymnasium's
    ``render_fps``: a frame that comes early waits for its moment; one that comes late is shown at once, so a
    machine that draws slower than `fps` shows fewer)."""
    import matplotlib

    if not human:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    core.keep_history = True  # from now on, where no render mode asked for it at the start
    h = core.history[0]
    if figure is None:
        figure = plt.figure(figsize=(6.4, 4.8), dpi=80)
    art = getattr(figure, "_millvib_artists", None)
    if art is None or art["mode"] != core.settings.mode:
        art = figure._millvib_artists = _build(figure, core.settings.mode)
    t_end = h["t"][-1]
    xs = np.concatenate(h["x"])
    vs = np.concatenate(h["v"])
    ts = (t_end - core.settings.dt_sample * np.arange(xs.size)[::-1]) * 1e3
    art["x"].set_data(ts, xs * 1e6)
    art["v"].set_data(ts, vs * 1e3)
    steps = np.array(h["t"]) * 1e3
    if core.settings.mode == "gain":
        gains = np.array(h["gains"])
        for j, line in enumerate(art["c"]):
            line.set_data(steps, np.log10(np.maximum(gains[:, j], 1e-12)))
    else:
        art["c"][0].set_data(steps, np.asarray(h["u"], float))
    for ax in art["axes"]:
        ax.relim()
        ax.autoscale_view()
    n_tr = int(core.n_trace[0])
    try:  # the band's 10 Hz edge needs 0.1 s of record
        sev = vibration_severity(core.acc_trace[0, :n_tr], core.settings.cfg.sample_rate_hz)
    except ValueError:
        sev = math.nan
    p = core.params[0]
    art["title"].set_text(f"t = {t_end * 1e3:.0f} ms   severity so far {sev:.3g} mm/s   "
                          f"c1 = {p.c1:.3g}, Ct = {p.Ct:.2g}")
    if human:
        now = time.perf_counter()
        due = getattr(figure, "_millvib_due", now)
        plt.pause(max(1e-3, due - now))
        figure._millvib_due = max(due, now) + (1.0 / fps if fps else 0.0)
        return None, figure
    canvas = figure.canvas if isinstance(figure.canvas, FigureCanvasAgg) else FigureCanvasAgg(figure)
    canvas.draw()
    frame = np.asarray(canvas.buffer_rgba())[:, :, :3].copy()
    return frame, figure
