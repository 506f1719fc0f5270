"""Task strings: forgiving about style, strict about structure and vocabulary."""

from __future__ import annotations

import pytest

from tasks.spec import TaskSpec, TaskSpecError, parse_task


@pytest.mark.parametrize("text,expected", [
    ("Move the mug from the stool to the table", ("mug", "stool", "table")),
    ("move mug from stool to table.", ("mug", "stool", "table")),
    ("  MOVE a Cup from THE filing cabinet to an plastic box ", ("cup", "filing cabinet", "plastic box")),
    ("Move the spray_bottle from the filing_cabinet to the counter", ("spray bottle", "filing cabinet", "counter")),
])
def test_parse_accepts_style_variants(text, expected):
    spec = parse_task(text)
    assert (spec.object, spec.start_receptacle, spec.goal_receptacle) == expected
    assert parse_task(str(spec)) == spec
    assert spec.classes == expected


@pytest.mark.parametrize("text,match", [
    ("", "empty task"),
    ("   ", "empty task"),
    ("Put the mug on the table", "malformed task 'Put the mug on the table'; expected"),
    ("Move the mug to the table", "malformed task"),
    ("Move the mgu from the stool to the table", r"unknown object 'mgu'.*did you mean 'mug'\?.*valid objects: mug, cup"),
    ("Move the mug from the stoool to the table", r"unknown start receptacle 'stoool'.*did you mean 'stool'"),
    ("Move the mug from the stool to the moon", "unknown goal receptacle 'moon'"),
    ("Move the table from the stool to the desk", "unknown object 'table'"),
    ("Move the mug from the table to the desk to the bed", "'from' and 'to' must each appear exactly once"),
])
def test_malformed_or_unknown_tasks_get_one_clear_error(text, match):
    with pytest.raises(TaskSpecError, match=match):
        parse_task(text)


def test_non_string_task_is_rejected():
    with pytest.raises(TaskSpecError):
        parse_task(None)  # type: ignore[arg-type]


def test_spec_constructor_validates_categories():
    with pytest.raises(TaskSpecError, match="unknown object 'dragon'"):
        TaskSpec("dragon", "table", "desk")
