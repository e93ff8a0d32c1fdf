"""Pixelwise DQN agents of the clutter tasks (thesis parts II and III) on TorchRL.

The agent:

* :mod:`~maniskill_pnp.agents.pixel.fcn`: the rotated fully convolutional Q networks over RGB-D heightmaps;
* :mod:`~maniskill_pnp.agents.pixel.equivariant`: the rotation-equivariant Q network (the ``"equivariant"`` backbone);
* :mod:`~maniskill_pnp.agents.pixel.rotations`: the rotation indices of a Q-map query, shared by both networks;
* :mod:`~maniskill_pnp.agents.pixel.policy`: the greedy and ε-greedy actors over their maps;
* :mod:`~maniskill_pnp.agents.pixel.mask`: the actions that can touch something;
* :mod:`~maniskill_pnp.agents.pixel.loss`: the executed-pixel DQN loss and the binary-classification baseline;
* :mod:`~maniskill_pnp.agents.pixel.replay`: the prioritized replay of packed heightmaps.

A run of it:

* :mod:`~maniskill_pnp.agents.pixel.config`: :class:`~maniskill_pnp.agents.pixel.config.ClutterConfig` and its
  presets (``presets.yaml``);
* :mod:`~maniskill_pnp.agents.pixel.factories`: workspace, env, network, mask, actors and checkpoint loading, built
  from a config;
* :mod:`~maniskill_pnp.agents.pixel.checkpoint`: checkpoints (RNG states, replay folder, export);
* :mod:`~maniskill_pnp.agents.pixel.metrics`: running training metrics and ``actions.csv``;
* :mod:`~maniskill_pnp.agents.pixel.recipe`: the training run (``maniskill-pnp train-clutter``);
* :mod:`~maniskill_pnp.agents.pixel.evaluate`: greedy evaluation per scenario (``maniskill-pnp eval-clutter``);
* :mod:`~maniskill_pnp.agents.pixel.video`: one filmed greedy episode (``maniskill-pnp record-clutter``);
* :mod:`~maniskill_pnp.agents.pixel.curves`: training curves from ``actions.csv`` (``maniskill-pnp plot-clutter``).
"""
