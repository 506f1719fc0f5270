"""HELIOS's hierarchical map: occupancy + frontiers, value maps, object Gaussians, instances."""

from helios.maps.classes import ClassSet, UnknownClassError
from helios.maps.frontiers import Frontier, find_frontiers
from helios.maps.gaussians import GaussianMap, GaussianUpdate, RenderedImages
from helios.maps.grid import GridGeometry
from helios.maps.hierarchical import HierarchicalMap, MapUpdate
from helios.maps.inputs import MapInputError
from helios.maps.instances import Instance
from helios.maps.occupancy import OccupancyGrid
from helios.maps.renderer import Rendering, render_gaussians
from helios.maps.value_map import ValueMap

__all__ = ["ClassSet", "Frontier", "GaussianMap", "GaussianUpdate", "GridGeometry", "HierarchicalMap", "Instance",
           "MapInputError", "MapUpdate", "OccupancyGrid", "RenderedImages", "Rendering", "UnknownClassError",
           "ValueMap", "find_frontiers", "render_gaussians"]
