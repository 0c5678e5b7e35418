"""Tuning the classical baselines: the search for one gain set or an oracle table (`search`: grid, Nelder-Mead,
Optuna) and every baseline of a task, as `millvib tune` writes them to configs/control/ (`baselines`)."""
