"""HELIOS's hierarchical map: occupancy + frontiers, value maps, object Gaussians, instances.

Names are imported on first use, so light users (the planner needs only ``GridGeometry``) do not
load torch."""

from helios._lazy import lazy_getattr

_LAZY = {
    "ClassSet": "classes", "UnknownClassError": "classes", "Frontier": "frontiers", "find_frontiers": "frontiers",
    "GaussianMap": "gaussians", "GaussianUpdate": "gaussians", "RenderedImages": "gaussians", "GridGeometry": "grid",
    "HierarchicalMap": "hierarchical", "MapUpdate": "hierarchical", "MapInputError": "inputs",
    "Instance": "instances", "OccupancyGrid": "occupancy", "Rendering": "renderer",
    "render_gaussians": "renderer", "ValueMap": "value_map",
}
__getattr__ = lazy_getattr(__name__, _LAZY)
__all__ = sorted(_LAZY)
