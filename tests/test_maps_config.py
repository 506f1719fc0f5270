"""HELIOS hyper-parameters: the paper's table, YAML round trip, validation, devices."""

import pytest
import torch

from helios.config import HeliosConfig
from helios.schema import ConfigError, dump_yaml, from_dict, load_config, with_overrides
from helios.maps.hierarchical import resolve_device


def test_defaults_are_the_papers_hyperparameters():
    cfg = HeliosConfig()
    assert cfg.scoring.alpha_cs == 1.0
    assert cfg.search.alpha_d == 0.001 and cfg.search.cs_start_receptacle == 0.3
    assert (cfg.decision.tau_object, cfg.decision.tau_goal_receptacle, cfg.decision.tau_increase) == (0.5, 0.5, 0.05)
    assert (cfg.decision.cs_object, cfg.decision.cs_goal_receptacle) == (0.3, 0.3)
    assert (cfg.detection.od_start_receptacle, cfg.detection.od_object, cfg.detection.od_goal_receptacle) == (0.35, 0.25, 0.45)
    assert cfg.gaussians.alpha_cpa == 3.0
    assert cfg.gaussians.reobservation_depth_error == 0.5
    assert cfg.instances.voxel_size == 0.5
    assert (cfg.occupancy.cell_size, cfg.occupancy.grid_size) == (0.025, 2000)


def test_detection_thresholds_per_class_of_an_episode():
    from helios.perception.config import DetectionThresholds, role_thresholds

    det = HeliosConfig().detection
    assert type(det) is DetectionThresholds                      # one threshold type for the method and perception
    assert role_thresholds(det, "cup", "table", "counter") == {"cup": 0.25, "table": 0.35, "counter": 0.45}
    assert role_thresholds(det, "cup", "table", "table") == {"cup": 0.25, "table": 0.35}
    cfg = with_overrides(HeliosConfig(), ["detection.od_object=0.5"])      # the YAML keys are unchanged
    assert cfg.detection == DetectionThresholds(od_object=0.5)
    with pytest.raises(ConfigError, match="od_goal_receptacle must be in"):
        from_dict(HeliosConfig, {"detection": {"od_goal_receptacle": 2}})


def test_yaml_round_trip_and_overrides(tmp_path):
    cfg = with_overrides(HeliosConfig(), ["gaussians.prior_concentration=2", "value_map.fusion=max_confidence",
                                          "occupancy.origin_xy=[-1.5, 2]"])
    assert cfg.gaussians.prior_concentration == 2.0 and cfg.occupancy.origin_xy == (-1.5, 2.0)
    path = tmp_path / "helios.yaml"
    path.write_text(dump_yaml(cfg))
    assert load_config(HeliosConfig, path) == cfg


def test_invalid_values_and_unknown_keys_are_config_errors():
    with pytest.raises(ConfigError, match="prior_concentration must be > 0"):
        with_overrides(HeliosConfig(), ["gaussians.prior_concentration=0"])
    with pytest.raises(ConfigError, match="unknown config key 'gaussians.alpha'"):
        with_overrides(HeliosConfig(), ["gaussians.alpha=3"])
    with pytest.raises(ConfigError, match="fusion"):
        from_dict(HeliosConfig, {"value_map": {"fusion": "average"}})
    with pytest.raises(ConfigError, match="obstacle_min_height < obstacle_max_height"):
        with_overrides(HeliosConfig(), ["occupancy.obstacle_max_height=0.05"])


def test_every_field_is_documented():
    import ast
    import inspect

    import helios.config as module

    tree = ast.parse(inspect.getsource(module))
    for node in [n for n in tree.body if isinstance(n, ast.ClassDef)]:
        body = node.body
        assert isinstance(body[0], ast.Expr), f"{node.name} has no docstring"
        for i, stmt in enumerate(body):
            if isinstance(stmt, ast.AnnAssign) and not stmt.target.id.startswith("_"):
                nested = isinstance(stmt.value, ast.Call) and "default_factory" in ast.unparse(stmt.value)
                documented = i + 1 < len(body) and isinstance(body[i + 1], ast.Expr)
                assert nested or documented, f"{node.name}.{stmt.target.id} has no docstring"


def test_device_resolution():
    assert resolve_device("cpu").type == "cpu"
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="no CUDA device"):
            resolve_device("cuda")
    else:
        assert resolve_device("cuda").type == "cuda"
