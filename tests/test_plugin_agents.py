"""Agents of your own in ``tools trials`` (``--agent FILE.py:FACTORY``, tasks.plugin_agents): a trial
batch runs one in spawned workers and names it in every record, the factory gets the settings of
the sections it reads and nothing else, a resume with changed source says so, and the example
policy (examples/nearest_first.py) searches nearest first. Bad specs are in the bad-input corpus."""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from cli_helpers import run_cli
from helios.config import SearchConfig
from helios.search.objective import CandidateLocation, FrontierOption, GlobalObjective
from tasks.plugin_agents import PluginAgentError, load_factory
from tasks.registry import RunContext, check_agent, make_agent

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "nearest_first.py"

QUICK_AGENT = """
class Agent:
    name = "quick"
    def reset(self, task, rng):
        self.task = task
    def act(self, robot):
        return True          # gives up at once: an episode costs its home's build only


def make(context, **options):
    return Agent()
"""


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def _module(spec: str):
    """The module a plugin's factory was imported as."""
    return sys.modules[load_factory(spec).__module__]


def _records(run: Path) -> list[dict]:
    return [json.loads(line) for line in (run / "episodes.jsonl").read_text().splitlines()]


def test_a_trial_batch_runs_the_example_in_spawned_workers_and_names_it(tmp_path, monkeypatch):
    """Two workers (spawned processes, which import the file themselves) run the example; the
    spelling ``./examples/...`` becomes the canonical ``examples/...`` in config.yaml and in every
    record, and invocations.jsonl keeps the sha256 of the file the episodes came from."""
    monkeypatch.chdir(ROOT)
    out = tmp_path / "nf"
    rc, stdout, err = run_cli(["trials", "--agent", "./examples/nearest_first.py:make", "--split", "smoke",
                               "--episodes", "2", "--workers", "2", "--out", str(out), "--progress", "none",
                               "--no-pictures", "runner.max_sim_time=25"])
    assert rc == 0, err[-2000:]
    records = _records(out)
    assert sorted(r["episode_id"] for r in records) == ["smoke-00000", "smoke-00001"]
    assert {r["agent"] for r in records} == {"examples/nearest_first.py:make"}
    assert all(r["error"] is None and r["extra"]["decisions"]["gaze_point_visits"] >= 0 for r in records)
    assert "agent: examples/nearest_first.py:make" in (out / "config.yaml").read_text()
    logged = json.loads((out / "invocations.jsonl").read_text().splitlines()[-1])
    assert logged["agent_source"] == hashlib.sha256(EXAMPLE.read_bytes()).hexdigest()[:16]


def test_a_resume_with_changed_agent_source_warns_and_replace_stale_starts_afresh(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    agent = _write(tmp_path / "mine.py", QUICK_AGENT)
    base = ["trials", "--agent", "mine.py:make", "--split", "smoke", "--out", "runs/mine", "--progress", "none",
            "--no-pictures"]
    rc, _, err = run_cli([*base, "--episodes", "1"])
    assert rc == 0 and "warning" not in err, err
    rc, _, err = run_cli([*base, "--episodes", "2"])                 # same source: a plain resume
    assert rc == 0 and "warning" not in err, err
    first = hashlib.sha256(agent.read_bytes()).hexdigest()[:16]
    _write(agent, QUICK_AGENT + "\n# tuned\n")
    rc, _, err = run_cli([*base, "--episodes", "3"])
    assert rc == 0
    assert f"another version of its agent's source file (sha256 {first}" in err, err
    assert len(_records(tmp_path / "runs/mine")) == 3
    rc, out, err = run_cli([*base, "--episodes", "3", "--replace-stale"])
    assert rc == 0, err
    assert "held results of other source of agent mine.py:make" in out and "moved it to" in out, out
    assert "resuming" not in out and len(_records(tmp_path / "runs/mine")) == 3
    logged = [json.loads(line) for line in (tmp_path / "runs/mine/invocations.jsonl").read_text().splitlines()]
    assert [e["agent_source"] for e in logged] == [hashlib.sha256(agent.read_bytes()).hexdigest()[:16]]


def test_the_default_run_folder_is_named_after_the_file_and_factory(tmp_path, monkeypatch):
    from tasks.trial_config import TrialConfig
    from tools.trials import default_out

    assert default_out(TrialConfig(agent="examples/nearest_first.py:make")) == Path("runs/nearest_first-make_smoke_s0")
    assert default_out(TrialConfig(agent="lab.agents:build", split="val", seed=3)) == Path("runs/lab.agents-build_val_s3")


@pytest.mark.parametrize("reads, given", [((), set()), (("helios",), {"method_config"}),
                                          (("agent_config", "helios", "perception"),
                                           {"agent_config", "method_config", "perception_config"})])
def test_the_factory_gets_the_options_of_the_sections_it_reads_and_no_others(tmp_path, reads, given):
    path = _write(tmp_path / f"reads_{len(reads)}.py", QUICK_AGENT + f"\nmake.reads = {reads!r}\n"
                  "SEEN = []\n_make = make\n\ndef make(context, **options):\n    SEEN.append(sorted(options))\n"
                  "    return _make(context)\n\n\n" + f"make.reads = {reads!r}\n")
    spec = f"{path}:make"
    factory = check_agent(spec).factory
    agent = factory(SimpleNamespace(), agent_config="a", method_config="m", perception_config="p", perception=None)
    module = _module(spec)
    assert module.SEEN == [sorted(given)]
    assert agent.name == spec                      # the records name the run's agent


def test_an_agent_whose_name_cannot_be_set_runs_under_the_spec(tmp_path):
    path = _write(tmp_path / "fixed.py", "class Agent:\n    @property\n    def name(self):\n        return 'fixed'\n"
                  "    def reset(self, task, rng): pass\n    def act(self, robot): return True\n\n\n"
                  "def make(context, **options):\n    return Agent()\n")
    agent = make_agent(f"{path}:make", RunContext(task="t", seed=0))
    assert agent.name == f"{path}:make" and agent.act(None) is True


def test_a_factory_that_raises_or_returns_no_agent_is_one_line_naming_its_file_line(tmp_path):
    path = _write(tmp_path / "broken.py", "def make(context, **options):\n    raise RuntimeError('my bug')\n\n\n"
                                          "def other(context, **options):\n    return 42\n")
    with pytest.raises(PluginAgentError, match=r"make\(\) raised RuntimeError \(line 2\): 'my bug'"):
        make_agent(f"{path}:make", RunContext(task="t", seed=0))
    with pytest.raises(PluginAgentError, match=r"other\(\) returned an object of type int without reset\(\) and act"):
        make_agent(f"{path}:other", RunContext(task="t", seed=0))


def test_a_changed_file_is_imported_again():
    """A long-lived process (a test run, a notebook) sees the agent's file as it is now."""
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        path = _write(Path(d) / "v.py", "def make(context, **options):\n    return 1\n")
        first = load_factory(f"{path}:make")
        _write(path, "def make(context, **options):\n    return 2\n\n\n# a longer file\n")
        import os

        os.utime(path, ns=(path.stat().st_atime_ns, path.stat().st_mtime_ns + 10**9))
        assert load_factory(f"{path}:make")(None) == 2 and first(None) == 1


# ------------------------------------------------------------------------------------------------
# The example: HomeRobot's nearest-first order as HELIOS's pick-phase search policy
# ------------------------------------------------------------------------------------------------
def _example():
    return _module(f"{EXAMPLE}:make")


def _cand(i: int, x: float, y: float, score: float = 0.5, gain: float = 1.0) -> CandidateLocation:
    return CandidateLocation(i, np.array([x, y]), score, gain)


def test_nearest_first_takes_the_nearest_candidate_before_any_frontier_then_the_nearest_frontier():
    policy = _example().NearestFirst(None, 0.025, "objective")
    far_likely, near_unlikely = _cand(1, 6.0, 0.0, score=0.9, gain=50.0), _cand(2, 0.0, 3.0, score=0.36, gain=1.0)
    near_frontier, far_frontier = FrontierOption(np.array([1.0, 0.0]), 0.1, 7), FrontierOption(np.array([9.0, 0.0]), 0.9, 8)
    choice = policy.choose(np.zeros(2), [far_likely, near_unlikely], [near_frontier, far_frontier])
    assert (choice.kind, choice.index, choice.value) == ("candidate", 2, -3.0)
    choice = policy.choose(np.zeros(2), [], [far_frontier, near_frontier])
    assert (choice.kind, choice.index) == ("frontier", 7)
    assert not policy.calibrated
    policy.note_frontier_chosen(near_frontier)
    assert policy.calibrated
    assert policy.choose(np.zeros(2), [], []) is None
    only = _example().NearestFirst(None, 0.025, "frontiers_only")
    assert only.choose(np.zeros(2), [near_unlikely], [far_frontier]).kind == "frontier"
    # the "w/o global objective" ablation, also candidates first, weighs score and information gain instead
    paper = GlobalObjective(SearchConfig(), 0.025,
                            "prefer_candidates")
    assert paper.choose(np.zeros(2), [far_likely, near_unlikely], [near_frontier, far_frontier]).index == 1


def test_the_example_builds_helios_with_its_policy_and_the_default_keeps_the_papers():
    from tasks.episodes import load_split
    from tasks.runner import SimEpisode

    sim = SimEpisode.create(load_split("smoke")[0])
    try:
        task = sim.episode.spec
        mine = make_agent(f"{EXAMPLE}:make", sim)
        mine.reset(task, np.random.default_rng(0))
        assert type(mine.pick_objective).__name__ == "NearestFirst" and mine.name == f"{EXAMPLE}:make"
        paper = make_agent("helios", sim)
        paper.reset(task, np.random.default_rng(0))
        assert type(paper.pick_objective) is GlobalObjective and paper.name == "helios"
        assert type(mine.detector) is type(paper.detector)
        # perception.mode=gt: the ground-truth twin (the registered name sets the detector's mode)
        from sim.perception import SimPerceptionConfig

        gt = check_agent(f"{EXAMPLE}:make").factory(RunContext.for_episode(sim),
                                                   perception_config=SimPerceptionConfig(mode="gt"))
        assert type(gt.detector).__name__ == "GroundTruthDetector" and type(mine.detector).__name__ != "GroundTruthDetector"
    finally:
        sim.close()


def test_a_module_on_the_python_path_is_an_agent_too(tmp_path, monkeypatch):
    """``package.module:FACTORY``: a module the command's Python path reaches (the folder it runs
    from, PYTHONPATH); its source file's digest is what a run logs."""
    from tasks.plugin_agents import source_digest

    pkg = tmp_path / "lab_agents"
    pkg.mkdir()
    _write(pkg / "__init__.py", "")
    policy = _write(pkg / "policy.py", QUICK_AGENT)
    monkeypatch.syspath_prepend(str(tmp_path))
    agent = make_agent("lab_agents.policy:make", RunContext(task="t", seed=0))
    assert agent.name == "lab_agents.policy:make" and agent.act(None) is True
    assert source_digest("lab_agents.policy:make") == hashlib.sha256(policy.read_bytes()).hexdigest()[:16]


def test_a_changed_module_is_imported_again(tmp_path, monkeypatch):
    import os

    pkg = tmp_path / "lab_agents_v"
    pkg.mkdir()
    _write(pkg / "__init__.py", "")
    policy = _write(pkg / "policy.py", "def make(context, **options):\n    return 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert load_factory("lab_agents_v.policy:make")(None) == 1
    _write(policy, "def make(context, **options):\n    return 2\n")
    os.utime(policy, ns=(policy.stat().st_atime_ns, policy.stat().st_mtime_ns + 10**9))
    assert load_factory("lab_agents_v.policy:make")(None) == 2
