"""Gaussian layer: creation, re-observation (negative evidence), occlusion, bad input."""

import numpy as np
import pytest
import torch

from helios.config import HeliosConfig
from helios.schema import with_overrides
from helios.maps import ClassSet, GridGeometry, MapInputError, UnknownClassError
from helios.maps.gaussians import GaussianMap
from helios.maps.hierarchical import HierarchicalMap
from helios.maps.labels import label_detections
from helios.perception.detection import Detection
from robots.hal import Observation
from robots.transforms import look_at_camera as look_at
from sim.synthetic_boxes import Box, pinhole, render_boxes

CAM = pinhole(160, 120)
POSE = look_at([0.0, 0.0, 1.0], [3.0, 0.0, 0.6])
CUP = Box((2.9, -0.1, 0.5), (3.1, 0.1, 0.7), "cup")
FLOOR = Box((-1.0, -3.0, -0.02), (6.0, 3.0, 0.0), "floor")
CLASSES = ClassSet.from_task(["cup", "table"])


def make_map(overrides=()) -> GaussianMap:
    cfg = with_overrides(HeliosConfig(), list(overrides))
    return GaussianMap(CLASSES, cfg.gaussians, cfg.instances, cfg.scoring, GridGeometry(0.025, 400, -5, -5))


def frame(boxes, pose=POSE, detected=None):
    """Render boxes; ``detected`` maps box index -> class name to report as detections."""
    rgb, depth, hit = render_boxes(boxes, CAM, pose)
    dets = [Detection(hit == k, name, 0.9) for k, name in (detected or {}).items()]
    lab = label_detections(dets, CLASSES, depth.shape)
    return depth, rgb, lab


def update(gmap, boxes, pose=POSE, detected=None):
    depth, rgb, lab = frame(boxes, pose, detected)
    return gmap.update(depth, CAM, pose, lab.labels, lab.objects, rgb)


def test_gaussians_are_created_only_inside_eroded_detection_masks_on_the_measured_surface():
    gmap = make_map()
    result = update(gmap, [FLOOR, CUP], detected={1: "cup"})
    assert result.n_created == len(gmap) > 50
    means = gmap.means.numpy()
    # every centre lies on the cup's visible face (x = 2.9) inside its extent, none on the floor
    assert np.all(np.abs(means[:, 0] - 2.9) < 1e-3)
    assert np.all((means[:, 1] > -0.1) & (means[:, 1] < 0.1) & (means[:, 2] > 0.5) & (means[:, 2] < 0.7))
    # scale = one pixel footprint at the creation depth
    depth = np.linalg.norm(means - POSE[:3, 3], axis=1)
    z_cam = (means - POSE[:3, 3]) @ POSE[:3, 2]
    np.testing.assert_allclose(gmap.scales.numpy(), z_cam / CAM.fx, rtol=1e-5)
    assert depth.min() > 2.9
    # and they were updated towards "cup" in the same frame
    assert float(gmap.expectations()[:, CLASSES.index("cup")].min()) > 0.5


def test_the_same_view_again_creates_nothing_new():
    gmap = make_map()
    update(gmap, [FLOOR, CUP], detected={1: "cup"})
    n = len(gmap)
    second = update(gmap, [FLOOR, CUP], detected={1: "cup"})
    assert second.n_created == 0 and len(gmap) == n and second.n_updated == n


def test_full_scene_mode_models_every_depth_pixel():
    obj, full = make_map(), make_map(["gaussians.full_scene=true"])
    update(obj, [FLOOR, CUP], detected={1: "cup"})
    update(full, [FLOOR, CUP], detected={1: "cup"})
    assert len(full) > 20 * len(obj)


def test_reobserved_but_undetected_object_loses_probability_for_its_class():
    gmap = make_map()
    update(gmap, [FLOOR, CUP], detected={1: "cup"})
    cup = CLASSES.index("cup")
    before = gmap.expectations()[:, cup].clone()
    result = update(gmap, [FLOOR, CUP], detected={})
    after = gmap.expectations()[:, cup]
    assert result.n_updated == len(gmap)
    assert torch.all(after < before - 0.05)
    bg = gmap.expectations()[:, CLASSES.background_index]
    assert float(bg.mean()) > 0.3


def test_occluded_object_is_not_updated():
    gmap = make_map()
    update(gmap, [FLOOR, CUP], detected={1: "cup"})
    gamma = gmap.concentrations.clone()
    wall = Box((1.5, -1.0, 0.0), (1.6, 1.0, 2.0), "wall")        # between the camera and the cup
    result = update(gmap, [FLOOR, CUP, wall], detected={})
    assert result.n_updated == 0 and result.reobserved_pixels == 0
    torch.testing.assert_close(gmap.concentrations, gamma, rtol=0, atol=0)


def test_concentration_update_is_alpha_cpa_times_summed_kappa():
    gmap = make_map(["gaussians.alpha_cpa=2.5", "gaussians.reobservation_closing_px=1"])
    update(gmap, [FLOOR, CUP], detected={1: "cup"})
    gamma0 = gmap.concentrations.clone()
    depth, rgb, lab = frame([FLOOR, CUP], detected={1: "table"})
    cam, _ = gmap.working_intrinsics(CAM)
    r = gmap.render(cam, POSE)
    expected_depth = r.expected_depth(1e-3).numpy()
    mask = torch.as_tensor(((depth > 0) & (r.silhouette.numpy() > 1e-3)
                            & (np.abs(depth - expected_depth) < 0.5)).reshape(-1))
    inside = mask[r.pixel_index]
    table_mass = torch.zeros(len(gmap), dtype=torch.float64).index_add_(
        0, r.gaussian_index[inside], (r.weight[inside] * torch.as_tensor(lab.labels.reshape(-1) == 1)[r.pixel_index[inside]]).double())
    gmap.update(depth, CAM, POSE, lab.labels, lab.objects, rgb)
    delta = gmap.concentrations - gamma0
    np.testing.assert_allclose(delta[:, CLASSES.index("table")].numpy(), 2.5 * table_mass.numpy(), rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(delta[:, CLASSES.index("cup")].numpy(), 0.0)


def test_rendered_semantic_images_are_distributions_with_uncertainty():
    gmap = make_map()
    update(gmap, [FLOOR, CUP], detected={1: "cup"})
    images = gmap.render_images(CAM, POSE)
    np.testing.assert_allclose(images.semantic_mean.sum(axis=-1), 1.0, atol=1e-5)
    covered = images.silhouette > 0.9
    assert covered.sum() > 30
    assert images.semantic_mean[covered][:, CLASSES.index("cup")].min() > 0.5
    assert images.semantic_std[covered].max() > 0 and images.semantic_std[~(images.silhouette > 0)].max() == 0
    assert np.all(np.abs(images.depth[covered] - 3.0) < 0.2)
    cup_rgb = 180 / 255 * (1 - 3.0 / 40)            # render_boxes shades colour by depth
    np.testing.assert_allclose(images.color[covered] / images.silhouette[covered][:, None], cup_rgb, rtol=0.05)


# ------------------------------------------------------------------------------ bad input
def test_nan_inf_zero_and_negative_depth_are_no_return():
    gmap = make_map()
    depth, rgb, lab = frame([FLOOR, CUP], detected={1: "cup"})
    cup_pixels = lab.objects
    depth[cup_pixels] = np.where(np.arange(cup_pixels.sum()) % 4 == 0, np.nan,
                                 np.where(np.arange(cup_pixels.sum()) % 4 == 1, np.inf,
                                          np.where(np.arange(cup_pixels.sum()) % 4 == 2, 0.0, -1.0)))
    result = gmap.update(depth, CAM, POSE, lab.labels, lab.objects, rgb)
    assert result.n_created == 0 and len(gmap) == 0 and torch.isfinite(gmap.concentrations).all()


def test_empty_detection_masks_are_a_no_op():
    gmap = make_map()
    depth, rgb, _ = frame([FLOOR, CUP])
    lab = label_detections([Detection(np.zeros(depth.shape, dtype=bool), "cup", 0.9)], CLASSES, depth.shape)
    assert lab.n_used == 0 and not lab.objects.any()
    result = gmap.update(depth, CAM, POSE, lab.labels, lab.objects, rgb)
    assert result.n_created == 0 and len(gmap) == 0


def test_wrong_shapes_and_unknown_classes_are_one_clear_error():
    depth, rgb, lab = frame([FLOOR, CUP])
    with pytest.raises(MapInputError, match=r"detections\[0\].mask \('cup'\) has shape \(60, 80\), expected \(120, 160\)"):
        label_detections([Detection(np.ones((60, 80), dtype=bool), "cup", 0.9)], CLASSES, depth.shape)
    with pytest.raises(UnknownClassError, match="unknown class 'knife'; this episode's classes are 'cup', 'table', 'other'"):
        label_detections([Detection(np.ones(depth.shape, dtype=bool), "knife", 0.9)], CLASSES, depth.shape)
    gmap = make_map()
    with pytest.raises(MapInputError, match="depth has shape"):
        gmap.update(depth[:-1], CAM, POSE, lab.labels, lab.objects)
    with pytest.raises(MapInputError, match="objects mask has shape"):
        gmap.update(depth, CAM, POSE, lab.labels, lab.objects[:, :-1])
    with pytest.raises(MapInputError, match="labels must lie in"):
        gmap.update(depth, CAM, POSE, np.full(depth.shape, 7), lab.objects)
    with pytest.raises(MapInputError, match="T_world_cam"):
        gmap.update(depth, CAM, np.full((4, 4), np.nan), lab.labels, lab.objects)


def test_hierarchical_map_rejects_bad_detections_before_touching_any_layer():
    hmap = HierarchicalMap(with_overrides(HeliosConfig(), ["occupancy.grid_size=400"]), ["cup", "table"], ["table"])
    rgb, depth, hit = render_boxes([FLOOR, CUP], CAM, POSE)
    obs = Observation(rgb=rgb, depth=depth, intrinsics=CAM, T_world_cam=POSE, T_world_body=np.eye(4), stamp=0.0)
    good = Detection(hit == 1, "cup", 0.9)
    with pytest.raises(UnknownClassError, match="'sofa'"):
        hmap.update(obs, [good, Detection(hit == 0, "sofa", 0.9)], {"table": 0.3})
    with pytest.raises(MapInputError, match="missing \\['table'\\]"):
        hmap.update(obs, [good], {"counter": 0.3})
    assert len(hmap.objects) == 0 and not hmap.occupancy.explored.any() and hmap.frame == 0
    hmap.update(obs, [good], {"table": 0.3})
    assert len(hmap.objects) > 0 and hmap.occupancy.explored.any()


def test_score_thresholds_drop_weak_detections_and_overlaps_go_to_the_most_confident():
    depth, _, _ = frame([FLOOR, CUP])
    left = np.zeros(depth.shape, dtype=bool)
    left[:, :100] = True
    right = np.zeros(depth.shape, dtype=bool)
    right[:, 60:] = True
    dets = [Detection(left, "cup", 0.3), Detection(right, "table", 0.6), Detection(right, "cup", 0.2)]
    lab = label_detections(dets, CLASSES, depth.shape, {"cup": 0.25, "table": 0.5})
    assert lab.n_used == 2
    assert np.all(lab.labels[:, :60] == CLASSES.index("cup")) and np.all(lab.labels[:, 60:] == CLASSES.index("table"))
    assert lab.objects.all()
    with pytest.raises(UnknownClassError, match="'sofa'"):
        HierarchicalMap(HeliosConfig(), ["cup"], score_thresholds={"sofa": 0.5})
