"""What a scene is made of: object shapes (procedural, mesh, YCB), loosely packed clutter and its pool of actors,
scene files, layout checks, the shipped locking layouts and hard sets, and which top-down grasps fit.

Scenes build on :mod:`maniskill_pnp.cell` and :mod:`maniskill_pnp.planning`; the tasks in :mod:`maniskill_pnp.tasks`
build their episodes from them. Nothing here imports a task or an agent. The YAML folders beside the modules are the
shipped scene files: ``complicated/`` (the 8 locking layouts), ``hard/`` (the hard test set), ``hard_train/`` (the
training arrangements).
"""
