"""HELIOS's hierarchical map: occupancy + frontiers, value maps, object Gaussians, instances.

The package exports the torch-free layers. The torch-based ones are imported from their modules
(``helios.maps.hierarchical.HierarchicalMap``, ``helios.maps.gaussians.GaussianMap``,
``helios.maps.renderer.render_gaussians``), so light users (the planner needs only
``GridGeometry``, the oracle agent only the planner) do not load torch."""

from helios.maps.classes import ClassSet, UnknownClassError
from helios.maps.frontiers import Frontier, find_frontiers
from helios.maps.grid import GridGeometry
from helios.maps.inputs import MapInputError
from helios.maps.instances import Instance
from helios.maps.occupancy import OccupancyGrid
from helios.maps.value_map import ValueMap

__all__ = ["ClassSet", "Frontier", "GridGeometry", "Instance", "MapInputError", "OccupancyGrid", "UnknownClassError",
           "ValueMap", "find_frontiers"]
