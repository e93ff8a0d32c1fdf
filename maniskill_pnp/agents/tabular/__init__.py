"""Tabular agents of the conveyor task (thesis part I) on TorchRL.

* :mod:`~maniskill_pnp.agents.tabular.qtable`: the Q-table module, its masked greedy / ε-greedy policies and the
  TD(0) updates of Q-learning and SARSA.
* :mod:`~maniskill_pnp.agents.tabular.recipe`: the training run (``maniskill-pnp train-conveyor``).
* :mod:`~maniskill_pnp.agents.tabular.evaluate`: greedy evaluation on the random test cases and per-category tables
  (``maniskill-pnp eval-conveyor``).
* :mod:`~maniskill_pnp.agents.tabular.video`: one filmed greedy episode (``maniskill-pnp record-conveyor``).
"""
