"""A figure of the first environment's recent motion: displacement, velocity, gains or valve command,
and the severity so far. Used by `render()` (rgb_array and human) and works with RecordVideo."""

from __future__ import annotations

import math

import numpy as np

from millvib_env.severity import vibration_severity


def render_frame(core, figure=None, *, human: bool = False):
    import matplotlib

    if not human:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    h = core.history[0]
    if figure is None:
        figure = plt.figure(figsize=(6.4, 4.8), dpi=80)
    figure.clf()
    ax_x, ax_v, ax_c = figure.subplots(3, 1, sharex=True)
    t_end = h["t"][-1]
    xs = np.concatenate(h["x"])
    vs = np.concatenate(h["v"])
    ts = t_end - core.dt_sample * np.arange(xs.size)[::-1]
    ax_x.plot(ts * 1e3, xs * 1e6, lw=0.8)
    ax_x.set_ylabel("x (um)")
    ax_v.plot(ts * 1e3, vs * 1e3, lw=0.8, color="tab:orange")
    ax_v.set_ylabel("v (mm/s)")
    steps = np.array(h["t"]) * 1e3
    if core.mode == "gain":
        gains = np.array(h["gains"])
        for j, name in enumerate(("KP", "KI", "KD")):
            ax_c.step(steps, np.log10(np.maximum(gains[:, j], 1e-12)), where="post", label=f"log10 {name}")
        ax_c.legend(fontsize=7, loc="upper left")
        ax_c.set_ylabel("gains")
    else:
        ax_c.step(steps, h["u"], where="post", color="tab:green")
        ax_c.set_ylabel("u (V)")
    ax_c.set_xlabel("t (ms)")
    n_tr = int(core.n_trace[0])
    try:  # the band's 10 Hz edge needs 0.1 s of record
        sev = vibration_severity(core.acc_trace[0, :n_tr], core.cfg.sample_rate_hz)
    except ValueError:
        sev = math.nan
    p = core.params[0]
    figure.suptitle(f"t = {t_end * 1e3:.0f} ms   severity so far {sev:.3g} mm/s   "
                    f"c1 = {p.c1:.3g}, Ct = {p.Ct:.2g}", fontsize=9)
    for ax in (ax_x, ax_v, ax_c):
        ax.grid(alpha=0.3)
    figure.tight_layout()
    if human:
        plt.pause(1e-3)
        return None, figure
    canvas = FigureCanvasAgg(figure)
    canvas.draw()
    frame = np.asarray(canvas.buffer_rgba())[:, :, :3].copy()
    return frame, figure
