"""Validation of the raw arrays the map layers accept, so bad input fails once, clearly.

The layers take plain arrays (not only HAL ``Observation``s, which already reject NaN/inf) so
they can be fed from recordings and tests. Depth follows the Spot convention: metres along the
optical axis, 0 = no return. NaN, inf and non-positive depths are read as "no return" rather
than rejected: real sensors emit them and dropping a pixel is the only safe interpretation.
Wrong shapes are rejected with :class:`MapInputError`.
"""

from __future__ import annotations

import math

import numpy as np

from robots.hal import CameraIntrinsics
from robots.transforms import is_valid_transform


class MapInputError(ValueError):
    """An array or argument given to a map layer is malformed; the message names it."""


def sanitize_depth(depth: np.ndarray, intrinsics: CameraIntrinsics) -> np.ndarray:
    """Float32 depth of the camera's shape with every NaN/inf/non-positive pixel set to 0."""
    if not isinstance(depth, np.ndarray) or depth.ndim != 2:
        raise MapInputError(f"depth must be a 2-D array, got {getattr(depth, 'shape', type(depth))}")
    expected = (intrinsics.height, intrinsics.width)
    if depth.shape != expected:
        raise MapInputError(f"depth has shape {depth.shape} but the intrinsics describe {expected} (H, W)")
    if not np.issubdtype(depth.dtype, np.number):
        raise MapInputError(f"depth must be numeric, got dtype {depth.dtype}")
    out = depth.astype(np.float32, copy=True)
    out[~np.isfinite(out) | (out <= 0)] = 0.0
    return out


def check_image_mask(mask: np.ndarray, shape: tuple[int, int], what: str) -> np.ndarray:
    """A boolean mask of exactly ``shape`` (H, W), or MapInputError naming ``what``."""
    if not isinstance(mask, np.ndarray) or mask.shape != tuple(shape):
        raise MapInputError(
            f"{what} has shape {getattr(mask, 'shape', type(mask))}, expected {tuple(shape)} (H, W) "
            f"to match the depth image")
    return mask.astype(bool, copy=False)


def check_rgb(rgb: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray | None:
    if rgb is None:
        return None
    if not isinstance(rgb, np.ndarray) or rgb.shape != (*shape, 3):
        raise MapInputError(f"rgb has shape {getattr(rgb, 'shape', type(rgb))}, expected {(*shape, 3)}")
    return rgb


def check_pose(T_world_cam: np.ndarray) -> np.ndarray:
    T = np.asarray(T_world_cam, dtype=float)
    if not is_valid_transform(T):
        raise MapInputError("T_world_cam must be a finite 4x4 rigid transform")
    return T


def subsample_factor(width: int, max_width: int) -> int:
    """Smallest integer factor that brings ``width`` to at most ``max_width`` pixels."""
    return max(1, math.ceil(width / max_width))


def subsampled_intrinsics(intrinsics: CameraIntrinsics, factor: int) -> CameraIntrinsics:
    """Intrinsics of ``image[::factor, ::factor]``: pixel u' is the original pixel factor * u'."""
    if factor == 1:
        return intrinsics
    return CameraIntrinsics(
        width=-(-intrinsics.width // factor), height=-(-intrinsics.height // factor),
        fx=intrinsics.fx / factor, fy=intrinsics.fy / factor,
        cx=intrinsics.cx / factor, cy=intrinsics.cy / factor)
