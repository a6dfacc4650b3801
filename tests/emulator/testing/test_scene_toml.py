"""emulator.testing.scene_toml: a scene dict written as TOML reads back as the same dict."""

import tomllib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from emulator.testing.scene_toml import dumps

keys = st.text(alphabet=st.characters(codec="utf-8", exclude_categories=["Cs"]), min_size=1, max_size=8)
scalars = st.booleans() | st.integers(-(2**63), 2**63 - 1) | st.floats(allow_nan=False, allow_infinity=False) | st.text(max_size=10)
arrays = st.lists(st.floats(allow_nan=False, allow_infinity=False), max_size=4) | st.lists(st.text(max_size=5), max_size=3)
waypoints = st.lists(st.fixed_dictionaries({"t": st.floats(0, 10), "position": st.lists(st.floats(-9, 9), min_size=3, max_size=3)}),
                     min_size=1, max_size=3)
leaf = st.dictionaries(keys, scalars | arrays, max_size=4)
tables = st.dictionaries(keys, scalars | arrays | leaf, max_size=4)
items = st.dictionaries(keys, scalars | arrays | leaf, max_size=3).map(lambda d: {k: v for k, v in d.items() if k != "path"})
scenes = st.fixed_dictionaries(
    {"spec": st.just(1)},
    optional={
        "model": leaf,
        "effects": tables,
        "transmitters": st.lists(items, min_size=1, max_size=3),
        "receivers": st.lists(st.builds(lambda d, p: {**d, "path": p}, items, waypoints), min_size=1, max_size=2),
    },
)


@settings(max_examples=200, deadline=None)
@given(scenes)
def test_round_trip(scene):
    assert tomllib.loads(dumps(scene)) == scene


def test_a_scene_with_every_shape():
    scene = {
        "spec": 1, "seed": 7, "rate_hz": 2.0, "name": 'a "quoted" name',
        "model": {"q": [1.0, 0.5, 1.0]},
        "effects": {"pulses": True},
        "pulses": {"period_ms": [900.0, 1100.0]},
        "transmitters": [{"id": 1, "position": [1.0, 2.0, 3.0]}],
        "receivers": [{"id": 2, "path": [{"t": 0.0, "position": [0.0, 0.0, 0.0]}]}],
    }
    assert tomllib.loads(dumps(scene)) == scene


@pytest.mark.parametrize("bad", [{"spec": 1, "x": float("nan")}, {"spec": 1, "x": None}, ["spec"]])
def test_values_toml_cannot_carry_are_errors(bad):
    with pytest.raises(ValueError):
        dumps(bad)


@pytest.mark.parametrize("name", ["default.toml", "field_walk.toml", "case_study_1.toml"])
def test_shipped_scenes_round_trip(name):
    """Real scenes (a datetime, inline-table waypoints, arrays of tables) read back equal."""
    from importlib import resources

    scene = tomllib.loads(resources.files("emulator").joinpath("scenes", name).read_text())
    assert tomllib.loads(dumps(scene)) == scene


def test_none_and_infinities_are_value_errors_naming_the_value():
    with pytest.raises(ValueError, match=r"^TOML scene values must be finite, got -inf$"):
        dumps({"spec": 1, "receivers": [{"path": [{"t": float("-inf")}]}]})
    with pytest.raises(ValueError, match="NoneType"):
        dumps({"spec": 1, "model": {"q": [1.0, None]}})
