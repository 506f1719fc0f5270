"""PyBullet simulation: the world, cameras, grasp/drop physics and (later) scenes and perception.

Nothing here is global: every function takes the ``World`` it acts on.
"""
