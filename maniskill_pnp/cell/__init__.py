"""The work cell's fixed geometry: the workspace and its heightmap grid, the cameras that see it, the place bin, and
the mapping between heightmap pixels and actions.

The lowest layer above :mod:`maniskill_pnp.planning`: scenes, tasks and agents all read these constants from one
:class:`~maniskill_pnp.cell.workspace.WorkspaceSpec`, so an env and an agent never disagree about a pixel.
"""
