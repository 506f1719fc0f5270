"""Boston Dynamics Spot with arm: model facts, URDF, kinematics, ruckig motion and backends.

Importing this package pulls in neither PyBullet nor bosdyn; the backends import them lazily.
"""
