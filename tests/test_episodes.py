"""Episode files: committed splits load and regenerate identically; bad records name file and line."""

from __future__ import annotations

import json

import pytest

from tasks.episodes import (
    SCHEMA_VERSION,
    SPLIT_RECIPES,
    DatasetError,
    generate_episodes,
    load_episodes,
    load_split,
    save_episodes,
    split_path,
)


def test_committed_splits_load_with_the_promised_sizes():
    smoke, val, train = load_split("smoke"), load_split("val"), load_split("train")
    assert len(smoke) == 20 and all(e.difficulty == "easy" for e in smoke)
    assert len(val) >= 1000 and len(train) >= 1000
    assert not {e.scene.seed for e in val} & {e.scene.seed for e in train}, "val and train share homes"
    large = load_split("large")         # the split where search policies rank: large homes only
    assert len(large) == 500 and all((e.scene.min_size, e.scene.max_size) == (18.0, 24.0) for e in large)
    assert not {e.scene.seed for e in large} & {e.scene.seed for e in val + train}, "large shares homes"
    for e in smoke + val[:50]:
        assert e.target_object.startswith(e.object_category.replace(" ", "_"))
        assert e.goal_receptacles and all(g.startswith(e.goal_receptacle_category.replace(" ", "_"))
                                          for g in e.goal_receptacles)


@pytest.mark.parametrize("split,n", [("smoke", 3), ("val", 6), ("large", 2)])
def test_committed_splits_regenerate_bit_for_bit(split, n):
    seed, count, difficulty, home_size = SPLIT_RECIPES[split]
    assert len(load_split(split)) == count
    regenerated = generate_episodes(split, seed, n, difficulty, home_size=home_size)
    committed = split_path(split).read_text().splitlines()[:n]
    assert [e.to_json() for e in regenerated] == committed


def test_files_of_an_older_schema_get_a_clear_error(tmp_path):
    """Version 1 files name instances of homes the generator no longer builds: refused, with why."""
    old = dict(_good(), schema_version=1)
    path = _write(tmp_path, [json.dumps(old)])
    with pytest.raises(DatasetError, match=r":1: schema_version 1 is not supported \(this version reads 2: in "
                                           r"version 2 homes from the same seed changed .*\); regenerate the file "
                                           r"with `python -m tools episodes generate"):
        load_episodes(path)


def test_round_trip(tmp_path):
    eps = load_split("smoke")[:3]
    path = tmp_path / "mine.jsonl"
    save_episodes(eps, path)
    assert load_episodes(path) == eps


def _write(tmp_path, lines):
    p = tmp_path / "eps.jsonl"
    p.write_text("\n".join(lines) + "\n")
    return p


def _good() -> dict:
    return json.loads(load_split("smoke")[0].to_json())


@pytest.mark.parametrize("mutate,match", [
    (lambda d: json.dumps(d)[:-20], r":2: not valid JSON.*truncated or corrupted"),
    (lambda d: json.dumps({**d, "schema_version": 99}), r":2: schema_version 99 is not supported"),
    (lambda d: json.dumps({k: v for k, v in d.items() if k != "robot_start"}), r":2: missing field\(s\) robot_start"),
    (lambda d: json.dumps({**d, "extra": 1}), r":2: unknown field\(s\) extra"),
    (lambda d: json.dumps({**d, "robot_start": [0, "x", 1]}), r":2: robot_start must be 3 finite numbers"),
    (lambda d: json.dumps({**d, "task": "Move the unicorn from the table to the desk"}), r":2: unknown object 'unicorn'"),
    (lambda d: json.dumps({**d, "object_category": "cup" if d["object_category"] != "cup" else "mug"}),
     r":2: the task string disagrees"),
    (lambda d: json.dumps({**d, "scene": {"seed": "abc"}}), r":2: field 'scene' must be"),
    (lambda d: json.dumps({**d, "goal_receptacles": []}), r":2: goal_receptacles must be a non-empty list"),
    (lambda d: "[1, 2, 3]", r":2: expected a JSON object"),
])
def test_bad_records_name_the_file_and_line(tmp_path, mutate, match):
    good = _good()
    other = dict(good, episode_id="smoke-99999")
    path = _write(tmp_path, [json.dumps(good), mutate(other)])
    with pytest.raises(DatasetError, match=match):
        load_episodes(path)


def test_duplicates_missing_and_empty_files(tmp_path):
    good = json.dumps(_good())
    with pytest.raises(DatasetError, match=r":2: duplicate episode_id"):
        load_episodes(_write(tmp_path, [good, good]))
    with pytest.raises(DatasetError, match="does not exist"):
        load_episodes(tmp_path / "nope.jsonl")
    empty = tmp_path / "empty.jsonl"
    empty.write_text("\n")
    with pytest.raises(DatasetError, match="holds no episodes"):
        load_episodes(empty)
    with pytest.raises(DatasetError, match="unknown split 'vall'; valid splits: smoke, val, train, large"):
        load_split("vall")
    assert SCHEMA_VERSION == 2


def test_generation_is_deterministic_and_validates_arguments():
    a = generate_episodes("demo", 5, 2, "easy")
    b = generate_episodes("demo", 5, 2, "easy")
    assert a == b and len(a) == 2 and a[0].episode_id == "demo-00000"
    assert generate_episodes("demo", 6, 1, "easy") != a[:1]
    with pytest.raises(DatasetError, match="unknown difficulty"):
        generate_episodes("demo", 5, 2, "hard")
    with pytest.raises(DatasetError, match="count must be positive"):
        generate_episodes("demo", 5, 0)


def test_home_size_bounds_the_generated_homes_and_bad_bounds_are_refused(capsys, tmp_path):
    from sim.scenes.layout import generate_layout
    from tools.cli import main

    eps = generate_episodes("large", 8, 2, home_size=(12.0, 15.0))
    for ep in eps:
        assert (ep.scene.min_size, ep.scene.max_size) == (12.0, 15.0)
        layout = generate_layout(ep.scene.seed, ep.scene.layout_config())
        assert 12.0 <= layout.width <= 15.0 and 12.0 <= layout.depth <= 15.0
    assert generate_episodes("large", 8, 2, home_size=(12.0, 15.0)) == eps        # deterministic
    with pytest.raises(DatasetError, match="home sizes must satisfy 6 <= min <= max <= 40"):
        generate_episodes("large", 8, 1, home_size=(15.0, 12.0))
    out = tmp_path / "x.jsonl"
    assert main(["episodes", "generate", "--name", "x", "--seed", "1", "--count", "1",
                 "--home-size", "3", "12", "--out", str(out)]) == 2
    assert "--home-size needs 6 <= MIN <= MAX <= 40 (m), got 3 12" in capsys.readouterr().err
    assert not out.exists()
