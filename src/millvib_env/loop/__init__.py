"""The loop as a mill commissions it: sensors sampled at the control rate, a digital controller
(PID, pressure feedback, force feedforward, an agent's command) that holds its command between
samples, with saturation, anti-windup and a computation delay. It is not part of the plant: the
plant (`millvib_env.plant`) integrates between samples with the command held.

* `settings`: `LoopSettings` and `SensorSettings`, the config's ``loop`` section, typed;
* `kernel`: the compiled, batched sampled loop the environments step (`advance_loop_batch`).
"""

from millvib_env.loop.settings import LoopSettings, SensorSettings

__all__ = ["LoopSettings", "SensorSettings"]
