"""Instances: Gaussians grouped into objects, and per-object class scores (paper Sec. 3.1, App.).

Clustering (HELIOS appendix): Gaussians of the same most likely class are put in 0.5 m voxels
aligned with the odometry frame; 26-connected voxels form a cluster; clusters inherit previous
instance labels or get fresh ones. Only Gaussians updated by the last frame, the rest of their
instances, and same-class Gaussians in voxels touching them are re-clustered, so the cost follows
what the frame saw, not the map size. Components are found exactly with ``scipy.sparse.csgraph``
(the paper's 20 rounds of min-pooling cap objects at 10 m).

Two deliberate deviations keep labels stable, which the later search stages rely on (they store
per-instance history): (1) the neighbour rule above; without it a view that sees only a new part
of an object starts a second instance. (2) Labels follow the largest overlap instead of the
paper's minimum: with the min rule a table absorbing a few Gaussians of a lower-numbered object
on it would take over that object's id, and the two parts of a split would share one label.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from helios.maps.classes import ClassSet
from helios.maps.grid import GridGeometry

_COORD_BITS = 18
_COORD_OFFSET = 1 << (_COORD_BITS - 1)
_MAX_CLASSES = 1 << (63 - 3 * _COORD_BITS)
_NEIGHBOUR_OFFSETS = np.array([(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)],
                              dtype=np.int64)
_NEIGHBOUR_OFFSETS.flags.writeable = False


def voxel_keys(means: np.ndarray, classes: np.ndarray, voxel_size: float) -> np.ndarray:
    """One int64 key per (class, voxel) of each Gaussian centre."""
    v = np.floor(np.asarray(means, dtype=np.float64) / voxel_size).astype(np.int64) + _COORD_OFFSET
    if v.size and (v.min() < 0 or v.max() >= (1 << _COORD_BITS)):
        raise ValueError(f"Gaussian centres lie beyond the +-{_COORD_OFFSET * voxel_size:.0f} m voxel range")
    if classes.size and classes.max() >= _MAX_CLASSES:
        raise ValueError(f"at most {_MAX_CLASSES} classes are supported by instance clustering")
    return _pack(classes.astype(np.int64), v)


def _pack(cls: np.ndarray, v: np.ndarray) -> np.ndarray:
    return (((cls << _COORD_BITS | v[..., 0]) << _COORD_BITS | v[..., 1]) << _COORD_BITS) | v[..., 2]


def _neighbour_keys(keys: np.ndarray) -> np.ndarray:
    """Keys of the 27 voxels around each key (same class), shape (K, 27)."""
    mask = (1 << _COORD_BITS) - 1
    v = np.stack([(keys >> (2 * _COORD_BITS)) & mask, (keys >> _COORD_BITS) & mask, keys & mask], axis=-1)
    cls = keys >> (3 * _COORD_BITS)
    nv = v[:, None, :] + _NEIGHBOUR_OFFSETS[None]
    return _pack(np.broadcast_to(cls[:, None], nv.shape[:2]), nv)


def _subset_to_recluster(keys: np.ndarray, instance_ids: np.ndarray, updated: np.ndarray) -> np.ndarray:
    """Updated Gaussians + their instances + touching same-class Gaussians (+ their instances)."""
    subset = updated.copy()
    while True:
        ids = np.unique(instance_ids[subset])
        ids = ids[ids >= 0]
        subset |= np.isin(instance_ids, ids)
        around = np.unique(_neighbour_keys(np.unique(keys[subset])))
        grown = subset | np.isin(keys, around)
        if grown.sum() == subset.sum():
            return subset
        subset = grown


def _components(keys: np.ndarray) -> tuple[np.ndarray, int]:
    """26-connected component per key (same class only), as an index per input key."""
    uniq, inverse = np.unique(keys, return_inverse=True)
    nb = _neighbour_keys(uniq)
    pos = np.searchsorted(uniq, nb).clip(max=uniq.size - 1)
    hit = uniq[pos] == nb
    src = np.broadcast_to(np.arange(uniq.size)[:, None], nb.shape)[hit]
    graph = coo_matrix((np.ones(src.size, dtype=np.int8), (src, pos[hit])), shape=(uniq.size, uniq.size))
    n, comp = connected_components(graph, directed=False)
    return comp[inverse], n


def assign_instances(means: np.ndarray, argmax_class: np.ndarray, instance_ids: np.ndarray,
                     updated: np.ndarray, voxel_size: float, next_id: int) -> tuple[np.ndarray, int]:
    """New instance id per Gaussian (those outside the re-clustered subset keep theirs)."""
    ids = instance_ids.copy()
    if not updated.any():
        return ids, next_id
    keys = voxel_keys(means, argmax_class, voxel_size)
    subset = np.nonzero(_subset_to_recluster(keys, instance_ids, updated))[0]
    comp, n = _components(keys[subset])
    label = _match_labels(comp, n, instance_ids[subset])
    fresh = np.nonzero(label < 0)[0]
    label[fresh] = next_id + np.arange(fresh.size)
    ids[subset] = label[comp]
    return ids, next_id + int(fresh.size)


def _match_labels(comp: np.ndarray, n: int, prev: np.ndarray) -> np.ndarray:
    """Previous label per component (-1: none), by largest overlap, each label used once.

    Pairs (component, previous label) are taken greedily by Gaussian count (ties: smaller label,
    the paper's min rule), so a merge keeps the label of the bigger part and a split leaves it
    with the part holding most of its Gaussians.
    """
    label = np.full(n, -1, dtype=np.int64)
    had = prev >= 0
    if not had.any():
        return label
    # (component, label) pairs packed into one int64 key: np.unique on rows (axis=0) sorts a void
    # view and cost ~30 ms per re-clustering; the keys give the same pairs, order and counts
    c, p = comp[had].astype(np.int64), prev[had].astype(np.int64)
    span = int(p.max()) + 1
    keys, counts = np.unique(c * span + p, return_counts=True)
    pairs = np.stack([keys // span, keys % span], axis=1)
    taken: set[int] = set()
    for k in np.lexsort((pairs[:, 1], -counts)):      # one entry per overlapping (instance, part)
        c, old = int(pairs[k, 0]), int(pairs[k, 1])
        if label[c] < 0 and old not in taken:
            label[c] = old
            taken.add(old)
    return label


@dataclass(frozen=True)
class Instance:
    """One object of the Gaussian layer, with the paper's per-class scores."""

    id: int
    class_name: str
    """Mode over its Gaussians of the most likely class."""
    class_scores: dict[str, float]
    """S_c: mean over its Gaussians of E[theta_c]."""
    uncertainties: dict[str, float]
    """U_c: mean over its Gaussians of sqrt(Var[theta_c])."""
    psi: dict[str, float]
    """Psi_c = S_c - alpha_cs * U_c (uncertainty-weighted object score)."""
    centre: np.ndarray = field(repr=False)
    """(3,) mean of the Gaussian centres (world, m)."""
    footprint_xy: np.ndarray = field(repr=False)
    """(K, 2) world (x, y) centres of the occupancy-grid cells its Gaussian centres fall in."""
    max_height: float
    """Highest Gaussian centre (world z, m)."""
    n_gaussians: int
    gaussian_indices: np.ndarray = field(repr=False)


def _group_sums(groups: np.ndarray, values: np.ndarray, k: int) -> np.ndarray:
    """(k, F) float64 sums of the rows of ``values`` (N, F) per group id in ``groups`` (N,)."""
    values = np.asarray(values, dtype=np.float64)
    return np.stack([np.bincount(groups, weights=values[:, j], minlength=k) for j in range(values.shape[1])], axis=1)


def summarize_instances(means: np.ndarray, expectations: np.ndarray, std: np.ndarray, most_likely: np.ndarray,
                        instance_ids: np.ndarray, classes: ClassSet, alpha_cs: float,
                        grid: GridGeometry) -> list[Instance]:
    """Instances with S_c, U_c, Psi_c, class, centre, footprint and height, ordered by id."""
    labelled = instance_ids >= 0
    if not labelled.any():
        return []
    idx = np.nonzero(labelled)[0]
    uniq, inv = np.unique(instance_ids[idx], return_inverse=True)
    K, C = uniq.size, len(classes)
    counts = np.bincount(inv, minlength=K).astype(np.float64)
    # Per-instance sums with bincount: the same sequential float64 additions as np.add.at, a
    # fraction of its cost; maxima per sorted group with reduceat (max is exact in any order).
    S = _group_sums(inv, expectations[idx], K)
    U = _group_sums(inv, std[idx], K)
    S /= counts[:, None]
    U /= counts[:, None]
    psi = S - alpha_cs * U
    votes = np.bincount(inv * C + most_likely[idx], minlength=K * C).reshape(K, C)
    mode = votes.argmax(axis=1)
    centre = _group_sums(inv, means[idx], K)
    centre /= counts[:, None]
    cells = np.stack(grid.world_to_cell(means[idx, :2]), axis=1)
    order = np.argsort(inv, kind="stable")
    splits = np.cumsum(np.bincount(inv, minlength=K))[:-1]
    top = np.maximum.reduceat(means[idx, 2][order].astype(np.float64), np.concatenate([[0], splits]))
    # One int64 key per cell, in (row, col) lexicographic order: np.unique on it gives the same
    # cells in the same order as np.unique(axis=0), several times faster.
    lo = cells.min(axis=0)
    width = int(cells[:, 1].max() - lo[1]) + 1
    keys = (cells[:, 0] - lo[0]) * width + (cells[:, 1] - lo[1])
    out = []
    for k, (members, member_keys) in enumerate(zip(np.split(idx[order], splits), np.split(keys[order], splits))):
        foot_keys = np.unique(member_keys)
        foot_cells = np.stack([foot_keys // width + lo[0], foot_keys % width + lo[1]], axis=1)
        foot = grid.cell_to_world(foot_cells[:, 0], foot_cells[:, 1])
        out.append(Instance(
            id=int(uniq[k]), class_name=classes.names[mode[k]],
            class_scores=dict(zip(classes.names, S[k].tolist())),
            uncertainties=dict(zip(classes.names, U[k].tolist())),
            psi=dict(zip(classes.names, psi[k].tolist())),
            centre=centre[k], footprint_xy=foot, max_height=float(top[k]),
            n_gaussians=int(counts[k]), gaussian_indices=members))
    return out
