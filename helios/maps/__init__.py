"""HELIOS's hierarchical map: occupancy + frontiers, value maps, object Gaussians, instances.

Names are imported on first use, so light users (the planner needs only ``GridGeometry``) do not
load torch."""

_LAZY = {
    "ClassSet": "classes", "UnknownClassError": "classes", "Frontier": "frontiers", "find_frontiers": "frontiers",
    "GaussianMap": "gaussians", "GaussianUpdate": "gaussians", "RenderedImages": "gaussians", "GridGeometry": "grid",
    "HierarchicalMap": "hierarchical", "MapUpdate": "hierarchical", "MapInputError": "inputs",
    "Instance": "instances", "OccupancyGrid": "occupancy", "Rendering": "renderer",
    "render_gaussians": "renderer", "ValueMap": "value_map",
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f"helios.maps.{_LAZY[name]}"), name)
    raise AttributeError(name)


__all__ = sorted(_LAZY)
