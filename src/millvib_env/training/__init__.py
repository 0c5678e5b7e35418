"""Training learned controllers: SB3 / sbx agents and their seeds (`train`), the zoo-style hyperparameter files
(`hyperparams`) and the MPC's students (`distill`). Measuring controllers is `millvib_env.evaluation`; tuning the
classical ones is `millvib_env.tuning`."""
