"""HELIOS: hierarchical maps (occupancy, value maps, sparse semantic Gaussians) and the search that
trades exploration against information gathering for language-specified pick-and-place.

This package is the method only: it never imports PyBullet or bosdyn. It talks to robots through
``robots.hal`` types.
"""

__version__ = "0.1.0"
