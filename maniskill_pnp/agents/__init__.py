"""The learning agents, one sub-package per family, on TorchRL:

* :mod:`~maniskill_pnp.agents.tabular`: tabular Q-learning / SARSA on the conveyor task (thesis part I);
* :mod:`~maniskill_pnp.agents.pixel`: pixelwise DQN agents on the clutter tasks (thesis parts II and III).

Shared by both: :mod:`~maniskill_pnp.agents.collection` (the collectors: one env, env processes or Ray workers),
:mod:`~maniskill_pnp.agents.run_io` (run folders: configs, loggers, atomic writes) and
:mod:`~maniskill_pnp.agents.video_frames` (frame helpers of the videos).
"""
