"""``python -m tools unchanged``: the same episodes with two trees' code, compared record by record.

The end-to-end tests run a committed tree (``git archive HEAD``) on both sides, so they do not
depend on what is edited in this checkout: the same code must give identical records, and a
scenario that differs must be reported as a change with exit status 1.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tools.commit_tree import extract_commit, resolve_commit
from tools.unchanged import MARKER, compare, prepare


def _head() -> str:
    from tools.cli import CliError

    try:
        commit = resolve_commit("HEAD", "HEAD")
    except CliError as exc:  # no git here
        pytest.skip(f"git is not usable in this checkout ({exc})")
    if commit is None:
        pytest.skip("this checkout has no commit (not a git clone)")
    return commit


@pytest.fixture(scope="module")
def head_tree(tmp_path_factory) -> Path:
    return extract_commit(_head(), tmp_path_factory.mktemp("head") / "tree", "HEAD")


def _cut(tree: Path, to: Path, seconds: int) -> Path:
    """A copy of ``tree`` whose trusting scenario stops at ``seconds`` of simulated time: the
    check's machinery is the same on a short episode, at a fraction of a whole one's time."""
    shutil.copytree(tree, to)
    scenario = to / "configs" / "val_trusting.yaml"
    scenario.write_text((tree / "configs" / "val_trusting.yaml").read_text() + f"\nrunner:\n  max_sim_time: {seconds}\n")
    return to


def test_the_same_code_gives_identical_records_and_a_changed_scenario_is_a_change(head_tree, tmp_path, capsys):
    short = _cut(head_tree, tmp_path / "short", 60)
    out = tmp_path / "check"
    same = compare(out, ["trusting"], 1, 1, frozenset(), base=(short, "HEAD"), now=(short, "HEAD again"))
    text = capsys.readouterr().out
    assert same, text
    assert "trusting: 1 of 1 records identical" in text and "unchanged: every record is the same" in text
    assert "[unchanged] trusting (HEAD again): 1/1 val-00000" in text          # each side's progress
    assert (out / "trusting" / "base" / "episodes.jsonl").is_file()
    # the extracted tree has no .git; its run still records the commit it is (it said "unknown": audit)
    assert f"git_commit: {_head()}" in (out / "trusting" / "base" / "config.yaml").read_text()

    # The base side's scenario cut to 20 s: the same episode ends differently, and that is a change.
    changed = _cut(head_tree, tmp_path / "changed", 20)
    same = compare(tmp_path / "check2", ["trusting"], 1, 1, frozenset(), base=(changed, "cut"),
                   now=(short, "HEAD"))
    text = capsys.readouterr().out
    assert not same
    assert "val-00000" in text and "sim_time" in text and "CHANGED" in text


def test_a_new_check_reruns_the_working_tree_side_and_keeps_the_commits(tmp_path):
    """The commit's side resumes (same commit) or starts afresh (another commit, --fresh); the
    working tree's side is always run again, since the code may have changed in between."""
    commit = _head()
    out = tmp_path / "u"
    tree = prepare(out, commit, ["trusting"], fresh=False)
    assert (tree / "tasks" / "trials.py").is_file() and (out / MARKER).is_file()
    for side in ("base", "now"):
        (out / "trusting" / side).mkdir(parents=True)
        (out / "trusting" / side / "episodes.jsonl").write_text("{}\n")
    prepare(out, commit, ["trusting"], fresh=False)
    assert (out / "trusting" / "base" / "episodes.jsonl").is_file()
    assert not (out / "trusting" / "now").exists()
    (out / "base-commit").write_text("0" * 40 + "\n")          # the last check was of another commit
    prepare(out, commit, ["trusting"], fresh=False)
    assert not (out / "trusting" / "base").exists()
    assert (out / "base-commit").read_text().strip() == commit
    (out / "trusting" / "base").mkdir(parents=True)
    prepare(out, commit, ["trusting"], fresh=True)
    assert not (out / "trusting" / "base").exists()



def test_a_side_that_fails_is_one_line_with_its_own_error(head_tree, tmp_path):
    from tools.cli import CliError

    broken = tmp_path / "broken"
    shutil.copytree(head_tree, broken)
    scenario = broken / "configs" / "val_trusting.yaml"
    scenario.write_text(scenario.read_text() + "\nrunner:\n  max_sim_tme: 20\n")
    with pytest.raises(CliError, match=r"trusting \(broken\): `tools trials` exited with status 2: .*max_sim_tme"):
        compare(tmp_path / "c", ["trusting"], 1, 1, frozenset(), base=(broken, "broken"), now=(head_tree, "HEAD"))


def test_a_relative_out_is_made_absolute_before_the_sides_run_in_their_own_trees(tmp_path, monkeypatch):
    """The default --out is relative; each side runs `tools trials` with its tree as the working
    directory, so the scenario path under --out must not be relative (it named nothing there)."""
    import argparse

    from tools.unchanged import check_arguments

    _head()
    monkeypatch.chdir(tmp_path)
    args = argparse.Namespace(base="HEAD", runs="helios", out="runs/unchanged", ignore="", episodes=3, workers=1)
    _, runs, out, _ = check_arguments(args)
    assert runs == ["helios"] and out.is_absolute() and out == tmp_path / "runs" / "unchanged"


def test_a_commit_too_old_or_without_a_runs_scenario_is_refused_before_anything_is_extracted(tmp_path):
    """Both were found only after `git archive` had written the commit's tree under --out."""
    import argparse
    import subprocess

    from tools.cli import CliError
    from tools.commit_tree import ROOT
    from tools.unchanged import check_arguments

    _head()
    log = subprocess.run(["git", "-C", str(ROOT), "log", "--reverse", "--format=%H", "--", "configs/val_helios-earlier.yaml"],
                         capture_output=True, text=True, timeout=30).stdout.split()
    roots = subprocess.run(["git", "-C", str(ROOT), "rev-list", "--max-parents=0", "HEAD"],
                           capture_output=True, text=True, timeout=30).stdout.split()
    if not log or not roots:
        pytest.skip("this checkout's history is too short (a shallow clone)")

    def args(base, runs):
        return argparse.Namespace(base=base, runs=runs, out=str(tmp_path / "unch"), ignore="", episodes=3, workers=1)

    with pytest.raises(CliError, match=r"has no tasks/trials.py: too old to run trials"):
        check_arguments(args(roots[-1], "helios"))
    with pytest.raises(CliError, match=r"has no configs/val_helios-earlier.yaml$"):
        check_arguments(args(log[0] + "^", "helios,helios-earlier"))
    assert not (tmp_path / "unch").exists()
