"""Information gain and predicted object score of hypothetical views of an instance."""

import numpy as np
import pytest
import torch
from scipy import stats

from helios.config import HeliosConfig
from helios.maps import ClassSet, GridGeometry, MapInputError, UnknownClassError
from helios.maps.gaussians import GaussianMap
from helios.search.information import (dirichlet_entropy, fifty_fifty_information_gain, information_gain,
                                       optimistic_evidence, optimistic_information_gain, predicted_object_score,
                                       predicted_object_score_of_views)
from robots.transforms import look_at_camera as look_at
from sim.synthetic_boxes import pinhole

CAM = pinhole(160, 120)
POSE = look_at([0.0, 0.0, 1.0], [2.0, 0.0, 1.0])


def blob_map(concentration) -> tuple[GaussianMap, int]:
    """A 5 x 5 sheet of Gaussians 2 m ahead of POSE, all one instance with ``concentration``."""
    cfg = HeliosConfig()
    classes = ClassSet.from_task(["cup", "table"])
    gmap = GaussianMap(classes, cfg.gaussians, cfg.instances, cfg.scoring, GridGeometry(0.025, 400, -5, -5))
    ys, zs = np.meshgrid(np.linspace(-0.05, 0.05, 5), np.linspace(0.95, 1.05, 5))
    means = np.stack([np.full(25, 2.0), ys.ravel(), zs.ravel()], axis=1)
    gmap.add_gaussians(means, 0.02, 0.5, concentrations=np.tile(concentration, (25, 1)))
    gmap.instance_ids[:] = 4
    return gmap, 4


def test_information_gain_is_float64_exact_at_large_counts():
    before = np.array([[1e4, 1.0, 1.0, 1.0]])
    after = before.copy()
    after[0, 0] += 0.3
    ig = information_gain(before, after)
    reference = stats.dirichlet.entropy(before[0]) - stats.dirichlet.entropy(after[0])
    assert ig == pytest.approx(reference, rel=1e-6)
    assert ig > 5e-5                 # float32 entropies would cancel to exactly 0 here
    assert ig == pytest.approx(float(dirichlet_entropy(before)[0] - dirichlet_entropy(after)[0]), rel=1e-12)


def test_optimistic_ig_positive_for_uncertain_and_near_zero_for_saturated():
    uncertain, iid = blob_map([1.0, 1.0, 1.0])
    saturated, _ = blob_map([1e7, 1.0, 1.0])
    ig_u = optimistic_information_gain(uncertain, iid, "cup", CAM, POSE)
    ig_s = optimistic_information_gain(saturated, iid, "cup", CAM, POSE)
    assert ig_u > 1.0
    assert abs(ig_s) < 1e-4 * ig_u


def test_optimistic_evidence_is_alpha_cpa_times_silhouette_weighted_kappa():
    gmap, iid = blob_map([1.0, 1.0, 1.0])
    idx, delta = optimistic_evidence(gmap, iid, CAM, POSE)
    cam, _ = gmap.working_intrinsics(CAM)
    r = gmap.render(cam, POSE, indices=idx)
    manual = torch.zeros(idx.size, dtype=torch.float64)
    manual.index_add_(0, r.gaussian_index, r.weight.double() * r.silhouette.reshape(-1)[r.pixel_index].double())
    np.testing.assert_allclose(delta.numpy(), 3.0 * manual.numpy(), rtol=1e-12)
    assert float(delta.min()) > 0


def test_more_views_give_more_information_and_fifty_fifty_gives_less_than_optimistic():
    gmap, iid = blob_map([1.0, 1.0, 1.0])
    one = optimistic_information_gain(gmap, iid, "cup", CAM, POSE, views=1)
    three = optimistic_information_gain(gmap, iid, "cup", CAM, POSE, views=3)
    half = fifty_fifty_information_gain(gmap, iid, "cup", CAM, POSE)
    assert three > one > 0
    assert 0 < half <= one + 1e-12   # symmetric prior: both outcomes gain the same here
    believer, _ = blob_map([6.0, 1.0, 1.0])
    assert fifty_fifty_information_gain(believer, iid, "cup", CAM, POSE) < \
        optimistic_information_gain(believer, iid, "cup", CAM, POSE)


def test_predicted_psi_rises_with_views_and_matches_moments():
    gmap, iid = blob_map([2.0, 1.0, 1.0])
    now = predicted_object_score(gmap, iid, "cup", CAM, POSE, views=0)
    assert now.predicted_psi == pytest.approx(now.psi)
    assert now.class_score == pytest.approx(0.5)
    assert now.uncertainty == pytest.approx(np.sqrt(0.5 * 0.5 / 5.0))
    one = predicted_object_score(gmap, iid, "cup", CAM, POSE, views=1)
    four = predicted_object_score(gmap, iid, "cup", CAM, POSE, views=4)
    assert four.predicted_psi > one.predicted_psi > one.psi
    assert four.predicted_uncertainty < one.predicted_uncertainty < one.uncertainty
    assert one.psi_increase == pytest.approx(one.predicted_psi - one.psi)


def test_ig_of_an_instance_out_of_view_is_zero():
    gmap, iid = blob_map([1.0, 1.0, 1.0])
    behind = look_at([0.0, 0.0, 1.0], [-2.0, 0.0, 1.0])
    assert optimistic_information_gain(gmap, iid, "cup", CAM, behind) == 0.0


def test_unknown_class_and_instance_are_clear_errors():
    gmap, iid = blob_map([1.0, 1.0, 1.0])
    with pytest.raises(UnknownClassError, match="'knife'.*'cup', 'table', 'other'"):
        optimistic_information_gain(gmap, iid, "knife", CAM, POSE)
    with pytest.raises(MapInputError, match="no instance with id 99"):
        optimistic_information_gain(gmap, 99, "cup", CAM, POSE)


def test_fifty_fifty_prediction_can_send_the_agent_elsewhere_where_the_optimistic_one_looks():
    """The decision rule's Psi' under each measurement assumption, on a hand-built instance
    (Dirichlet (8, 1, 8) over cup / table / other on every Gaussian: Psi 0.35). Optimistic: the view says
    "cup" and Psi' clears Psi + tau_inc, so take another view. 50-50: the expectation over the view
    saying "cup" or "other", which does not clear it, so search elsewhere."""
    from helios.search.decisions import Verdict, decide

    gmap, iid = blob_map([8.0, 1.0, 8.0])
    opt = predicted_object_score(gmap, iid, "cup", CAM, POSE, assumption="optimistic")
    half = predicted_object_score(gmap, iid, "cup", CAM, POSE, assumption="fifty_fifty")
    # by hand: the same evidence added to "cup" or to "other", scores averaged
    idx, delta = optimistic_evidence(gmap, iid, CAM, POSE)
    gamma = gmap.concentrations[torch.as_tensor(idx)].clone()
    alpha_cs = gmap.scoring.alpha_cs

    def psi_after(col):
        g = gamma.clone()
        g[:, col] += delta
        total = g.sum(dim=1)
        mean = g[:, 0] / total
        std = torch.sqrt(mean * (1 - mean) / (total + 1))
        return float(mean.mean() - alpha_cs * std.mean())

    background = gmap.classes.background_index
    assert opt.predicted_psi == pytest.approx(psi_after(0), rel=1e-9)
    assert half.predicted_psi == pytest.approx(0.5 * (psi_after(0) + psi_after(background)), rel=1e-9)
    assert half.psi == pytest.approx(opt.psi)
    tau, tau_inc = 0.5, 0.05
    assert decide(opt.psi, opt.predicted_psi, tau, tau_inc) is Verdict.LOOK
    assert decide(half.psi, half.predicted_psi, tau, tau_inc) is Verdict.IGNORE
    with pytest.raises(ValueError, match="assumption"):
        predicted_object_score(gmap, iid, "cup", CAM, POSE, assumption="pessimistic")


def two_sided_map() -> tuple[GaussianMap, int]:
    """One instance of two 5 x 5 sheets 2 m ahead, 1 m to the left and right of the x axis."""
    cfg = HeliosConfig()
    classes = ClassSet.from_task(["cup", "table"])
    gmap = GaussianMap(classes, cfg.gaussians, cfg.instances, cfg.scoring, GridGeometry(0.025, 400, -5, -5))
    ys, zs = np.meshgrid(np.linspace(-0.05, 0.05, 5), np.linspace(0.95, 1.05, 5))
    sheets = [np.stack([np.full(25, 2.0), ys.ravel() + side, zs.ravel()], axis=1) for side in (1.0, -1.0)]
    gmap.add_gaussians(np.concatenate(sheets), 0.02, 0.5, concentrations=np.tile([1.0, 1.0, 1.0], (50, 1)))
    gmap.instance_ids[:] = 7
    return gmap, 7


def test_candidate_gain_per_gaussian_takes_the_size_out_of_the_sum():
    """SearchConfig.candidate_gain: the paper sums IG over an instance's Gaussians, so a candidate
    the map holds twice as much of is worth twice as much; per_gaussian divides by the count."""
    from helios.config import SearchConfig
    from helios.search.information import views_information_gain

    gmap, iid = two_sided_map()                           # 50 Gaussians, two sheets of 25
    both = [look_at([1.0, 1.0, 1.0], [2.0, 1.0, 1.0]), look_at([1.0, -1.0, 1.0], [2.0, -1.0, 1.0])]
    total = views_information_gain(gmap, iid, "table", CAM, both)
    assert total > 0
    assert views_information_gain(gmap, iid, "table", CAM, both, aggregate="per_gaussian") == pytest.approx(total / 50)
    gmap.instance_ids[25:] = 8                            # the same sheets as two instances of 25
    left, right = (views_information_gain(gmap, i, "table", CAM, both) for i in (7, 8))
    assert left + right == pytest.approx(total) and left == pytest.approx(total / 2, rel=0.2)
    assert views_information_gain(gmap, 7, "table", CAM, both, aggregate="per_gaussian") == pytest.approx(left / 25)
    assert SearchConfig().candidate_gain == "sum"        # the paper's definition stays the default
    with pytest.raises(ValueError, match="aggregate"):
        views_information_gain(gmap, 7, "table", CAM, both, aggregate="mean")
    with pytest.raises(ValueError, match="candidate_gain"):
        SearchConfig(candidate_gain="mean")


def test_informative_views_skip_repeats_and_blind_views_but_cover_every_side():
    from helios.search.information import informative_views, views_information_gain

    gmap, iid = two_sided_map()
    left = look_at([1.0, 1.0, 1.0], [2.0, 1.0, 1.0])          # sees only the left sheet
    right = look_at([1.0, -1.0, 1.0], [2.0, -1.0, 1.0])       # only the right one
    away = look_at([1.0, 0.0, 1.0], [0.0, 0.0, 1.0])          # looks away: no evidence
    cams = [left, left, away, right, left]
    total = views_information_gain(gmap, iid, "table", CAM, cams)
    chosen = informative_views(gmap, iid, "table", CAM, cams, 0.2)
    assert sorted(chosen) in ([0, 3], [1, 3], [3, 4]), chosen      # one left view and the right one
    assert views_information_gain(gmap, iid, "table", CAM, [cams[i] for i in chosen]) > 0.5 * total
    assert 2 not in informative_views(gmap, iid, "table", CAM, cams, 0.01)
    assert sorted(informative_views(gmap, iid, "table", CAM, cams, 0.0)) == [0, 1, 2, 3, 4]
    assert informative_views(gmap, iid, "table", CAM, cams, 0.2, "fifty_fifty") == chosen
    assert informative_views(gmap, iid, "table", CAM, [away, away], 0.5) == [0, 1]   # no information anywhere
    with pytest.raises(ValueError, match="min_fraction"):
        informative_views(gmap, iid, "table", CAM, cams, 1.5)


def test_psi_prime_of_several_views_adds_their_evidence():
    """``predicted_object_score_of_views``: one copy of the concentrations takes the evidence of
    every pose (the paper's m observations from poses P); one pose is ``predicted_object_score``,
    the same pose twice is two views from it, and no pose leaves Psi as it is."""
    gmap, iid = blob_map([2.0, 1.0, 1.0])
    side = look_at([0.6, 0.9, 1.0], [2.0, 0.0, 1.0])         # oblique: sees the sheet, less of it
    for assumption in ("optimistic", "fifty_fifty"):
        single = predicted_object_score(gmap, iid, "cup", CAM, POSE, assumption=assumption)
        assert predicted_object_score_of_views(gmap, iid, "cup", CAM, [POSE], assumption) == single
        twice = predicted_object_score(gmap, iid, "cup", CAM, POSE, views=2, assumption=assumption)
        assert predicted_object_score_of_views(gmap, iid, "cup", CAM, [POSE, POSE], assumption).predicted_psi == \
            pytest.approx(twice.predicted_psi, rel=1e-12)
        none = predicted_object_score_of_views(gmap, iid, "cup", CAM, [], assumption)
        assert none.predicted_psi == pytest.approx(none.psi)
    both = predicted_object_score_of_views(gmap, iid, "cup", CAM, [POSE, side])
    assert both.predicted_psi > max(predicted_object_score(gmap, iid, "cup", CAM, T).predicted_psi for T in (POSE, side))
    with pytest.raises(ValueError, match="assumption"):
        predicted_object_score_of_views(gmap, iid, "cup", CAM, [POSE], "pessimistic")


def _with_view_width(width: int) -> tuple[GaussianMap, int]:
    from dataclasses import replace

    gmap, iid = blob_map([1.0, 1.0, 1.0])
    gmap.cfg = replace(gmap.cfg, view_evidence_max_width=width)
    return gmap, iid


def test_coarser_hypothetical_views_render_smaller_and_keep_the_evidence_scale(monkeypatch):
    """``view_evidence_max_width``: a cap at or above the working width changes nothing; half of it
    renders a quarter of the pixels, with footprints of the same solid angle (``coarser_render``),
    and counts each four times, so the total evidence stays that of the full render."""
    full_map, iid = blob_map([1.0, 1.0, 1.0])
    _, full = optimistic_evidence(full_map, iid, CAM, POSE)
    same_map, _ = _with_view_width(160)
    _, same = optimistic_evidence(same_map, iid, CAM, POSE)
    assert torch.equal(full, same)

    coarse_map, _ = _with_view_width(80)
    widths = []
    render = GaussianMap.render

    def spy(self, cam, pose, indices=None, pixel_mask=None, render_cfg=None, depth=True):
        widths.append(cam.width)
        return render(self, cam, pose, indices=indices, pixel_mask=pixel_mask, render_cfg=render_cfg, depth=depth)

    monkeypatch.setattr(GaussianMap, "render", spy)
    _, coarse = optimistic_evidence(coarse_map, iid, CAM, POSE)
    assert widths == [80]
    assert not torch.equal(coarse, full)
    assert float(coarse.sum()) == pytest.approx(float(full.sum()), rel=0.02)
    assert float(coarse.min()) > 0


def test_a_coarser_render_keeps_the_footprints_solid_angle():
    from helios.config import RenderConfig
    from helios.maps.gaussians import coarser_render

    cfg = RenderConfig()
    two = coarser_render(cfg, 2)
    assert two.blur_px2 == pytest.approx(cfg.blur_px2 / 4) and two.max_radius_px == 24
    assert coarser_render(cfg, 1) == cfg and coarser_render(cfg, 100).max_radius_px == 1
