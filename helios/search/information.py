"""Information gain of hypothetical views of an instance, and the score they would give.

The paper's optimistic assumption (App. "Expanded explanation of how we calculate information
gain"): copy the instance's Gaussians with class probability one-hot on the target class o,
render them from the candidate pose, and use that image as the measurement Y*. Every copy carries
e_o, so Y*(p) = S(p) e_o with S the instance's rendered silhouette, and the Eq. 3 update of a copy
of the concentrations is ``delta gamma_n^o = alpha_cpa * sum_p S(p) kappa_n(p)``: one render per
pose, only component o changes. IG = sum_n H(gamma_n) - H(gamma_n + delta_n) in float64.

Only the instance is rendered: occlusion by the rest of the scene is not modelled (as in HELIOS,
whose gaze points are pruned by line of sight on the occupancy map beforehand). Renders use the
map's working resolution so hypothetical evidence has the same scale as real updates.

The "50-50" ablation assigns probability 1/2 to the view labelling the instance as o and 1/2 to
it labelling it background; we return that expected information gain. With a prior >= 1,
evidence for a minority class can raise entropy, so IG may be negative for such outcomes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from helios.maps import dirichlet
from helios.maps.gaussians import GaussianMap
from robots.hal import CameraIntrinsics

dirichlet_entropy = dirichlet.entropy


def information_gain(gamma_before, gamma_after) -> float:
    """sum over Gaussians of H(before) - H(after), float64 (numpy arrays or tensors)."""
    h_before = torch.as_tensor(dirichlet.entropy(gamma_before))
    h_after = torch.as_tensor(dirichlet.entropy(gamma_after))
    return float((h_before - h_after).sum())


def optimistic_evidence(gmap: GaussianMap, instance_id: int, intrinsics: CameraIntrinsics,
                        T_world_cam: np.ndarray) -> tuple[np.ndarray, torch.Tensor]:
    """(Gaussian indices of the instance, (n,) float64 evidence one view from the pose adds)."""
    idx = gmap.instance_indices(instance_id)
    return idx, gmap.view_evidence(idx, intrinsics, T_world_cam)


def _gain_for_class(gamma: torch.Tensor, cls: int, delta: torch.Tensor) -> float:
    after = gamma.clone()
    after[:, cls] += delta
    return float((dirichlet.entropy(gamma) - dirichlet.entropy(after)).sum())


def optimistic_information_gain(gmap: GaussianMap, instance_id: int, target_class: str,
                                intrinsics: CameraIntrinsics, T_world_cam: np.ndarray, views: int = 1) -> float:
    """IG_o of ``views`` identical views from the pose, all labelling the instance ``target_class``."""
    cls = gmap.classes.index(target_class)
    idx, delta = optimistic_evidence(gmap, instance_id, intrinsics, T_world_cam)
    return _gain_for_class(gmap.concentrations[torch.as_tensor(idx, device=gmap.device)], cls, views * delta)


def fifty_fifty_information_gain(gmap: GaussianMap, instance_id: int, target_class: str,
                                 intrinsics: CameraIntrinsics, T_world_cam: np.ndarray, views: int = 1) -> float:
    """Expected IG when the views label the instance ``target_class`` or background, 1/2 each."""
    cls = gmap.classes.index(target_class)
    idx, delta = optimistic_evidence(gmap, instance_id, intrinsics, T_world_cam)
    gamma = gmap.concentrations[torch.as_tensor(idx, device=gmap.device)]
    return 0.5 * _gain_for_class(gamma, cls, views * delta) + \
        0.5 * _gain_for_class(gamma, gmap.classes.background_index, views * delta)


@dataclass(frozen=True)
class PredictedScore:
    """Class score, uncertainty and Psi of an instance now and after hypothetical views."""

    class_score: float
    uncertainty: float
    psi: float
    predicted_class_score: float
    predicted_uncertainty: float
    predicted_psi: float

    @property
    def psi_increase(self) -> float:
        return self.predicted_psi - self.psi


def predicted_object_score(gmap: GaussianMap, instance_id: int, target_class: str,
                           intrinsics: CameraIntrinsics, T_world_cam: np.ndarray, views: int = 1,
                           assumption: str = "optimistic") -> PredictedScore:
    """Psi'_o after ``views`` views from the pose (paper App., 'Once the target object has been
    detected'): S', U' from the updated copy of the concentrations. ``optimistic``: the paper's
    best case, every view labels the instance ``target_class``; ``fifty_fifty``: the expectation
    over the views labelling it ``target_class`` or background, 1/2 each (the 50-50 ablation's
    assumption carried into the decision rule)."""
    if views < 0:
        raise ValueError(f"views must be >= 0, got {views}")
    _check_assumption(assumption)
    idx, delta = optimistic_evidence(gmap, instance_id, intrinsics, T_world_cam)
    return _predicted(gmap, idx, target_class, views * delta, assumption)


def predicted_object_score_of_views(gmap: GaussianMap, instance_id: int, target_class: str,
                                    intrinsics: CameraIntrinsics, T_world_cams,
                                    assumption: str = "optimistic") -> PredictedScore:
    """Psi'_o after one view from each pose together (the paper's "m observations Y from poses
    P"): the evidence of all views is added to one copy of the concentrations, as
    ``views_information_gain`` does for IG. No pose: Psi' = Psi."""
    _check_assumption(assumption)
    idx = gmap.instance_indices(instance_id)
    return _predicted(gmap, idx, target_class, _summed_evidence(gmap, instance_id, intrinsics, T_world_cams, idx.size),
                      assumption)


def best_view_prediction(gmap: GaussianMap, instance_id: int, target_class: str, intrinsics: CameraIntrinsics,
                         T_world_cams, assumption: str = "optimistic",
                         poses: str = "best") -> tuple[int | None, float | None]:
    """For "take another view?": the index of the camera whose one view promises the highest Psi'
    (the first of equals), and the Psi' that decides: that view's (``poses="best"``) or that of
    one view from every camera together (``"all"``, ``predicted_object_score_of_views``).
    (None, None) without cameras."""
    best, best_psi = None, None
    for i, T in enumerate(T_world_cams):
        p = predicted_object_score(gmap, instance_id, target_class, intrinsics, T, assumption=assumption).predicted_psi
        if best_psi is None or p > best_psi:
            best, best_psi = i, p
    if best is not None and poses == "all":
        best_psi = predicted_object_score_of_views(gmap, instance_id, target_class, intrinsics, T_world_cams,
                                                   assumption=assumption).predicted_psi
    return best, best_psi


def _check_assumption(assumption: str) -> None:
    if assumption not in ("optimistic", "fifty_fifty"):
        raise ValueError(f"unknown measurement assumption {assumption!r}")


def _predicted(gmap: GaussianMap, idx: np.ndarray, target_class: str, delta: torch.Tensor,
               assumption: str) -> PredictedScore:
    """S, U, Psi of the instance's Gaussians ``idx`` now and with ``delta`` evidence on the class
    (optimistic) or its 50-50 expectation with the evidence on background instead."""
    cls = gmap.classes.index(target_class)
    gamma = gmap.concentrations[torch.as_tensor(idx, device=gmap.device)]
    after = gamma.clone()
    after[:, cls] += delta
    alpha_cs = gmap.scoring.alpha_cs

    def score(g: torch.Tensor) -> tuple[float, float, float]:
        s = float(dirichlet.expectation(g)[:, cls].mean())
        u = float(torch.sqrt(dirichlet.variance(g)[:, cls]).mean())
        return s, u, s - alpha_cs * u

    s0, u0, p0 = score(gamma)
    s1, u1, p1 = score(after)
    if assumption == "fifty_fifty":
        against = gamma.clone()
        against[:, gmap.classes.background_index] += delta
        s2, u2, p2 = score(against)
        s1, u1, p1 = 0.5 * (s1 + s2), 0.5 * (u1 + u2), 0.5 * (p1 + p2)
    return PredictedScore(s0, u0, p0, s1, u1, p1)


def views_information_gain(gmap: GaussianMap, instance_id: int, target_class: str, intrinsics: CameraIntrinsics,
                           T_world_cams, assumption: str = "optimistic", aggregate: str = "sum") -> float:
    """IG of one view from each pose together (the gaze points of a local search): the
    evidence of all views is added to one copy of the concentrations. ``assumption`` is
    ``optimistic`` (all views say ``target_class``) or ``fifty_fifty`` (expected IG when they all
    say the class or all say background, 1/2 each). ``aggregate``: ``sum`` over the instance's
    Gaussians (the paper) or ``per_gaussian`` (that sum over their count; ``SearchConfig.candidate_gain``)."""
    if assumption not in ("optimistic", "fifty_fifty"):
        raise ValueError(f"unknown information-gain assumption {assumption!r}")
    if aggregate not in ("sum", "per_gaussian"):
        raise ValueError(f"unknown information-gain aggregate {aggregate!r}")
    cls = gmap.classes.index(target_class)
    idx = gmap.instance_indices(instance_id)
    if idx.size == 0:
        return 0.0
    gamma = gmap.concentrations[torch.as_tensor(idx, device=gmap.device)]
    delta = _summed_evidence(gmap, instance_id, intrinsics, T_world_cams, idx.size)
    gain = _views_gain(gamma, cls, gmap.classes.background_index, delta, assumption)
    return gain / idx.size if aggregate == "per_gaussian" else gain


def _summed_evidence(gmap: GaussianMap, instance_id: int, intrinsics: CameraIntrinsics, T_world_cams,
                     n: int) -> torch.Tensor:
    """(n,) float64: the evidence one view from each pose adds to the instance's n Gaussians."""
    delta = torch.zeros(n, dtype=torch.float64, device=gmap.device)
    for T in T_world_cams:
        delta += optimistic_evidence(gmap, instance_id, intrinsics, T)[1]
    return delta


def _views_gain(gamma: torch.Tensor, cls: int, background: int, delta: torch.Tensor, assumption: str) -> float:
    """IG of views whose summed evidence is ``delta``: all of it on ``cls`` (optimistic), or the
    mean of that and all of it on background (fifty_fifty)."""
    gain = _gain_for_class(gamma, cls, delta)
    if assumption == "fifty_fifty":
        gain = 0.5 * gain + 0.5 * _gain_for_class(gamma, background, delta)
    return gain


def informative_views(gmap: GaussianMap, instance_id: int, target_class: str, intrinsics: CameraIntrinsics,
                      T_world_cams, min_fraction: float, assumption: str = "optimistic") -> list[int]:
    """Indices of the views worth taking, in the order a greedy choice picks them: each next view
    is the one that raises the IG of the views chosen so far (``views_information_gain``'s
    measure: evidence added to one copy of the concentrations) the most, and views stop once
    that rise falls below ``min_fraction`` of the IG of all views together. A view that mostly
    sees Gaussians others already cover adds little (Dirichlet entropy falls ever more slowly with
    evidence), so the subset covers the instance with fewer gaze points: the paper's suggested
    improvement of local search ("filtering for informative gaze points", Discussion). At least
    one view is kept; all of them when they carry no information at all."""
    if assumption not in ("optimistic", "fifty_fifty"):
        raise ValueError(f"unknown information-gain assumption {assumption!r}")
    if not 0.0 <= min_fraction <= 1.0:
        raise ValueError(f"min_fraction must be in [0, 1], got {min_fraction}")
    cams = list(T_world_cams)
    idx = gmap.instance_indices(instance_id)
    if idx.size == 0 or len(cams) <= 1:
        return list(range(len(cams)))
    cls = gmap.classes.index(target_class)
    background = gmap.classes.background_index
    gamma = gmap.concentrations[torch.as_tensor(idx, device=gmap.device)]
    deltas = [optimistic_evidence(gmap, instance_id, intrinsics, T)[1] for T in cams]

    def gain(delta: torch.Tensor) -> float:
        return _views_gain(gamma, cls, background, delta, assumption)

    total = gain(torch.stack(deltas).sum(dim=0))
    if not total > 0.0:
        return list(range(len(cams)))
    chosen: list[int] = []
    acc = torch.zeros_like(deltas[0])
    current = 0.0
    remaining = list(range(len(cams)))
    while remaining:
        gains = [gain(acc + deltas[k]) for k in remaining]
        best = int(np.argmax(gains))
        if chosen and gains[best] - current < min_fraction * total:
            break
        k = remaining.pop(best)
        chosen.append(k)
        acc = acc + deltas[k]
        current = gains[best]
    return chosen
