"""Scripted agents that see the simulator's shapes (privileged information no learned agent gets): the clutter oracle
(a grasp at the top of an object that fits) and the slide oracle (a slide that frees a locked object, then grasps).

They measure what a task allows, as upper references for the learned agents; benchmarks and tests use them.
"""
