"""Configuration values that only a run could reveal as wrong, checked at the command's boundary
instead (QA 2026-12-04): before the run folder is made, one ``error:`` line, exit status 2."""

from __future__ import annotations

import pytest

from cli_helpers import run_cli
from helios.schema import ConfigError, with_overrides
from tasks.trial_config import TrialConfig, check_devices


@pytest.mark.parametrize("agent", ["helios", "helios-gt"])
def test_helios_device_cuda_without_cuda_is_refused_before_the_run_folder(agent, tmp_path, monkeypatch):
    """It used to exit 0 with every episode recording the ConfigError as a failure (SR 0 %)."""
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    out = tmp_path / "run"
    rc, stdout, err = run_cli(["trials", "--agent", agent, "--episodes", "1", "--progress", "none", "--no-pictures",
                               "--out", str(out), "helios.device=cuda"])
    assert rc == 2, err
    assert err.splitlines() == ["error: helios.device=cuda: device 'cuda' was configured but torch sees no CUDA "
                                "device; use 'cpu' or 'auto'"]
    assert not out.exists()


def test_device_check_applies_where_the_device_is_used(monkeypatch):
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    check_devices(with_overrides(TrialConfig(agent="oracle"), ["helios.device=cuda"]))    # the oracle ignores it
    check_devices(with_overrides(TrialConfig(agent="helios"), ["helios.device=auto"]))
    check_devices(TrialConfig(agent="helios"))
    with pytest.raises(ConfigError, match="no CUDA device"):
        check_devices(with_overrides(TrialConfig(agent="helios"), ["helios.device=cuda"]))
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    check_devices(with_overrides(TrialConfig(agent="helios"), ["helios.device=cuda"]))


def test_a_background_class_that_names_a_category_is_refused():
    """The map refuses a task class named like the background class (MapInputError in every
    episode that names it); every task class is a category of the simulator."""
    from sim.scenes.catalog import ALL_CATEGORIES

    for name in ALL_CATEGORIES:
        with pytest.raises(ConfigError, match="background_class .* is a category of the simulator"):
            with_overrides(TrialConfig(), [f"helios.background_class={name}"])
    assert with_overrides(TrialConfig(), ["helios.background_class=background"]).helios.background_class == "background"
