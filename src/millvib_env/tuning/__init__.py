"""Tuning the classical baselines: the search for one gain set or an oracle table (`search`: grid, Nelder-Mead,
Optuna) and every baseline of a task, as `millvib tune` writes them to configs/control/ (`baselines`)."""

#: every entry `millvib tune` tunes, in its order (`baselines.TUNERS`; a test holds them equal). Here, where the
#: command line's parser reads it without loading the controllers that `baselines` imports
ENTRIES = ("pid-nominal", "pid-robust", "pid-oracle", "lqr-oracle", "pid-adaptive", "pid-pf-robust", "pid-pf-ff",
           "pid-pf-oracle", "pid-pf-preview")
