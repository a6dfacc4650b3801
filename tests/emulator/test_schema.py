"""emulator.schema: msgspec's errors in our words (exact lines), and no input that makes
convert raise anything but SchemaError."""

from __future__ import annotations

import math
from typing import Annotated, Literal

import msgspec
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from emulator.schema import (
    Finite,
    Hinted,
    Int,
    Number,
    SchemaError,
    Strict,
    Text,
    Vector3,
    convert,
    given as given_fields,
    join_key,
)


class Point(Strict):
    t: Finite
    position: Vector3


class Thing(Strict):
    id: Int(0, 65535)
    rate: Number(1e-3, 1e4, unit="Hz") = 1.0
    gain: Number(0.0, 100.0, positive=True) | None = None
    limit: Number(-5.0, 5.0) = 0.0
    pose: Hinted(Vector3, "3 numbers [x, y, z] in metres") | None = None
    talker: Text(r"\A[A-Z]{2}\Z", "two upper-case letters") = "GP"
    kind: Literal["a", "b"] = "a"
    mode: Literal["resume"] | None = None
    on: bool = False
    path: Annotated[list[Point], msgspec.Meta(min_length=1)] | None = None


@pytest.mark.parametrize(
    "data, message",
    [
        ({"id": -3}, "id: must be in 0..65535, got -3"),
        ({"id": "3"}, "id: expected an integer, got a string"),
        ({"id": True}, "id: expected an integer, got a boolean"),
        ({}, "id: missing"),
        ({"id": 1, "colour": 3}, "colour: unknown key"),
        ({"id": 1, "rate": 0}, "rate: must be within [0.001, 10000] Hz, got 0"),
        ({"id": 1, "gain": 0}, "gain: must be > 0, got 0"),
        ({"id": 1, "gain": 1e300}, "gain: must be <= 100, got 1e+300"),
        ({"id": 1, "limit": -6}, "limit: must be >= -5, got -6"),
        ({"id": 1, "limit": math.nan}, "limit: must be finite, got nan"),
        ({"id": 1, "pose": 3}, "pose: expected 3 numbers [x, y, z] in metres, got an integer"),
        ({"id": 1, "pose": [1, 2]}, "pose: expected 3 numbers [x, y, z] in metres, got 2"),
        ({"id": 1, "pose": [1, "2", 3]}, "pose[1]: expected a number, got a string"),
        ({"id": 1, "pose": [1, 2, math.inf]}, "pose[2]: must be finite, got inf"),
        ({"id": 1, "talker": "gp"}, "talker: expected two upper-case letters, got 'gp'"),
        ({"id": 1, "kind": "c"}, 'kind: must be one of a, b, got "c"'),
        ({"id": 1, "mode": "pause"}, 'mode: must be "resume", got "pause"'),
        ({"id": 1, "on": 1}, "on: expected true or false, got an integer"),
        ({"id": 1, "path": []}, "path: expected a non-empty array"),
        ({"id": 1, "path": {}}, "path: expected an array of tables, got a table"),
        ({"id": 1, "path": [3]}, "path[0]: expected a table, got an integer"),
        ({"id": 1, "path": [{"t": 0}]}, "path[0].position: missing"),
        ({"id": 1, "path": [{"t": 0, "position": [0, 0]}]}, "path[0].position: expected 3 numbers, got 2"),
        ([1], "expected a table, got an array"),
    ],
)
def test_errors_name_the_key_and_the_rule(data, message):
    with pytest.raises(SchemaError) as info:
        convert(data, Thing)
    assert str(info.value) == message


class Tables(Strict):
    names: dict[str, dict] = {}
    nested: dict[str, dict[str, Point]] = {}
    listed: list[dict[str, int]] = []


@pytest.mark.parametrize(
    "data, message",
    [
        ({"names": {"arva": 5}}, "names.arva: expected a table, got an integer"),
        ({"names": {"a": {}, "b": {}, "arva": [], "c": 1}}, "names.arva: expected a table, got an array"),
        ({"nested": {"a": {"x": {"t": 0, "position": [0, 0, 0]}}, "b": {"y": {"t": 0}}}}, "nested.b.y.position: missing"),
        ({"nested": {"a": {"x": {"t": 0, "position": [0, 0, 0], "q": 1}}}}, "nested.a.x.q: unknown key"),
        ({"nested": {"a": {"x": 1}, "b": {"y": 2}}}, "nested.a.x: expected a table, got an integer"),
        ({"nested": {"a": {"x": {"t": 0, "position": [0, 0, 0]}}, "b": {"y": {"t": 0, "position": [0, 0, "z"]}}}},
         "nested.b.y.position[2]: expected a number, got a string"),
        ({"listed": [{"a": 1}, {"b": 2, "c": "x"}]}, "listed[1].c: expected an integer, got a string"),
    ],
)
def test_errors_name_a_mappings_key(data, message):
    """msgspec writes a mapping's key as ``[...]``; the message names it (was ``names.]``, got null)."""
    with pytest.raises(SchemaError) as info:
        convert(data, Tables)
    assert str(info.value) == message


def test_a_mappings_key_among_many_is_found_by_bisection():
    data = {"names": {f"n{i}": {} for i in range(100_000)} | {"last": None}}
    with pytest.raises(SchemaError, match=r"^names\.last: expected a table, got null$"):
        convert(data, Tables)


def test_a_good_table_and_its_given_fields():
    thing = convert({"id": 7, "pose": [1, 2, 3], "path": [{"t": 0, "position": [0, 0, 0]}]}, Thing)
    assert thing.pose == (1.0, 2.0, 3.0) and type(thing.pose[0]) is float
    assert given_fields(thing) == {
        "id": 7, "rate": 1.0, "limit": 0.0, "pose": (1.0, 2.0, 3.0), "talker": "GP", "kind": "a", "on": False,
        "path": [Point(0.0, (0.0, 0.0, 0.0))],
    }  # fmt: skip


def test_the_mapping_word_is_the_callers():
    with pytest.raises(SchemaError, match=r"^expected an object, got an integer$"):
        convert(3, Thing, "an object")


def test_join_key():
    assert [join_key("a", "b"), join_key("a", "[0].b"), join_key("", "b"), join_key("a", "")] == ["a.b", "a[0].b", "b", "a"]


values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=6),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(
        st.sampled_from(["id", "rate", "gain", "pose", "talker", "kind", "mode", "on", "path", "t", "position", "x",
                         "names", "nested", "listed"]),
        inner, max_size=5),
    max_leaves=16,
)


@pytest.mark.slow
@settings(max_examples=400, deadline=None)
@given(data=values)
def test_any_value_is_a_thing_or_one_schema_error(data):
    try:
        thing = convert(data, Thing)
    except SchemaError as exc:
        assert "\n" not in str(exc) and str(exc)
        return
    assert 0 <= thing.id <= 65535 and 1e-3 <= thing.rate <= 1e4
    assert thing.pose is None or all(math.isfinite(v) for v in thing.pose)


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(data=values)
def test_any_value_is_tables_or_one_schema_error_naming_real_keys(data):
    try:
        convert(data, Tables)
    except SchemaError as exc:
        assert "\n" not in str(exc) and "..." not in exc.key and ".]" not in exc.key
