"""Dirichlet class distributions of Gaussians: update, moments, entropy (paper Eqs. 3-5).

Concentrations are float64 throughout: counts reach 1e3-1e4 within an episode, and entropy
differences of a small update then vanish in float32 (information gain would read 0).
Functions accept torch tensors (any device) or numpy arrays and return the same kind.
"""

from __future__ import annotations

import numpy as np
import torch


def _as_tensor(gamma) -> tuple[torch.Tensor, bool]:
    if isinstance(gamma, torch.Tensor):
        return gamma.to(torch.float64), False
    return torch.as_tensor(np.asarray(gamma, dtype=np.float64)), True


def _back(t: torch.Tensor, to_numpy: bool):
    return t.cpu().numpy() if to_numpy else t


def expectation(gamma):
    """E[theta_c] = gamma_c / sum_j gamma_j, over the last axis."""
    g, np_out = _as_tensor(gamma)
    return _back(g / g.sum(-1, keepdim=True), np_out)


def variance(gamma):
    """Var[theta_c] = E_c (1 - E_c) / (1 + sum_j gamma_j), over the last axis."""
    g, np_out = _as_tensor(gamma)
    total = g.sum(-1, keepdim=True)
    e = g / total
    return _back(e * (1 - e) / (1 + total), np_out)


def most_likely_class(gamma, background_index: int):
    """argmax_c E[theta_c]; exact ties (e.g. an untouched flat prior) go to the background class,
    so a Gaussian with no evidence never claims to be an object of interest."""
    g, np_out = _as_tensor(gamma)
    e = g / g.sum(-1, keepdim=True)
    best = e.argmax(-1)
    top = e.gather(-1, best[..., None])[..., 0]
    tie = e[..., background_index] >= top * (1 - 1e-12)
    return _back(torch.where(tie, torch.full_like(best, background_index), best), np_out)


def entropy(gamma):
    """Differential entropy of Dirichlet(gamma) (paper Eq. 5), over the last axis.

    H = log B(gamma) + (T - C) psi(T) - sum_c (gamma_c - 1) psi(gamma_c), T = sum_c gamma_c,
    log B(gamma) = sum_c lgamma(gamma_c) - lgamma(T). Requires gamma > 0.
    """
    g, np_out = _as_tensor(gamma)
    if g.numel() and bool((g <= 0).any()):
        raise ValueError("Dirichlet concentrations must be > 0 for the entropy")
    C = g.shape[-1]
    T = g.sum(-1)
    log_b = torch.lgamma(g).sum(-1) - torch.lgamma(T)
    h = log_b + (T - C) * torch.digamma(T) - ((g - 1) * torch.digamma(g)).sum(-1)
    return _back(h, np_out)


def add_pixel_evidence(gamma: torch.Tensor, gaussian_index: torch.Tensor, labels: torch.Tensor,
                       weight: torch.Tensor, scale: float) -> None:
    """In place: gamma[n, y_i] += scale * kappa_i over pairs (Gaussian n, pixel i with label y_i).

    This is Eq. 3 with one-hot y (``scale`` = alpha_cpa times any per-pixel normalisation).
    """
    if weight.numel() == 0:
        return
    C = gamma.shape[1]
    flat = gaussian_index * C + labels
    gamma.view(-1).index_add_(0, flat, weight.to(torch.float64) * scale)
