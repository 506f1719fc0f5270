"""Input checks shared by every detector and scorer (real or simulated)."""

from __future__ import annotations

from typing import Iterable, Sequence

import numpy as np

from helios.perception.errors import ImageInputError, UnknownCategoryError


def check_rgb(rgb: np.ndarray) -> tuple[int, int]:
    """An (H, W, 3) uint8 image; returns (H, W)."""
    if not isinstance(rgb, np.ndarray) or rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ImageInputError(f"rgb must be an (H, W, 3) uint8 array, got "
                              f"{getattr(rgb, 'dtype', type(rgb).__name__)} {getattr(rgb, 'shape', '')}")
    if rgb.shape[0] < 1 or rgb.shape[1] < 1:
        raise ImageInputError(f"rgb is empty: shape {rgb.shape}")
    return int(rgb.shape[0]), int(rgb.shape[1])


def check_rgb_depth(rgb: np.ndarray, depth: np.ndarray) -> tuple[int, int]:
    """RGB (H, W, 3) uint8 plus depth (H, W) floating-point metres of the same size; returns (H, W)."""
    h, w = check_rgb(rgb)
    if not isinstance(depth, np.ndarray) or depth.ndim != 2 or not np.issubdtype(depth.dtype, np.floating):
        raise ImageInputError(f"depth must be an (H, W) float array in metres, got "
                              f"{getattr(depth, 'dtype', type(depth).__name__)} {getattr(depth, 'shape', '')}")
    if depth.shape != (h, w):
        raise ImageInputError(f"rgb and depth sizes differ: rgb is {w}x{h} (W x H), depth is "
                              f"{depth.shape[1]}x{depth.shape[0]}; they must be registered images of one size")
    return h, w


def check_class_names(class_names: Sequence[str], known: Iterable[str] | None = None) -> list[str]:
    """A non-empty list of distinct, non-empty class names; with ``known``, each must be one of them."""
    if isinstance(class_names, (str, bytes)):
        raise UnknownCategoryError(f"class_names must be a list of names, got a single string {class_names!r}; "
                                   f"wrap it in a list")
    try:
        names = list(class_names)
    except TypeError:
        raise UnknownCategoryError(f"class_names must be a list of names, got {type(class_names).__name__}") from None
    if not names:
        raise UnknownCategoryError("class_names is empty; name at least one class to detect")
    for i, n in enumerate(names):
        if not isinstance(n, str) or not n.strip():
            raise UnknownCategoryError(f"class_names[{i}] must be a non-empty string, got {n!r}")
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise UnknownCategoryError(f"class_names lists {', '.join(map(repr, dup))} more than once")
    if known is not None:
        valid = list(known)
        valid_set = set(valid)
        unknown = [n for n in names if n not in valid_set]
        if unknown:
            raise UnknownCategoryError(f"unknown class name{'s' if len(unknown) > 1 else ''} "
                                       f"{', '.join(map(repr, unknown))}; valid: {', '.join(valid)}")
    return names
