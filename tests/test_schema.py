"""The one configuration validator (core/schema.py) and the schemas built on it."""

import dataclasses
import math

import pytest

from jaxnav.apps.car_config import SCHEMA as CAR_SCHEMA
from jaxnav.apps.car_config import CarConfig
from jaxnav.core import schema
from jaxnav.study import config as sc


def test_every_car_config_field_has_exactly_one_rule():
    fields = {f.name for f in dataclasses.fields(CarConfig)}
    rules = {f"{section}_{key}" for section, table in CAR_SCHEMA.items() for key in table}
    assert fields == rules


def test_every_study_field_has_a_rule():
    names = {f.name for f in dataclasses.fields(sc.StudyConfig)}
    assert set(sc._STUDY_KEYS) == names - {"placement", "metrics", "scenario"}
    assert set(sc._PLACEMENT_SCHEMA) == {f.name for f in dataclasses.fields(sc.PlacementConfig)}
    assert set(sc._METRICS_SCHEMA) == {f.name for f in dataclasses.fields(sc.MetricsConfig)}


@pytest.mark.parametrize("table, message", [
    ({"x": [1, 2, -3]}, "s.x[2] = -3: expected a number > 0"),
    ({"x": [1, 2, 1]}, "s.x[2] = 1: expected distinct values (duplicate)"),
    ({"x": []}, "s.x = []: expected a non-empty list (a number > 0)"),
    ({"y": 2.0}, "s.y = 2.0: expected a whole number >= 1"),
    ({"y": True}, "s.y = True: expected a whole number >= 1"),
    ({"z": "end"}, "s.z = 'end': expected \"start\" or a number >= 0 (or \"inf\")"),
    ({"w": float("nan")}, "s.w = nan: expected a number"),
    ({"q": 1}, "unknown key s.q (value 1); allowed keys in [s]: x, y, z, w"),
])
def test_messages_name_key_value_and_rule(table, message):
    rules = {"x": schema.items(schema.number(0, strict=True)), "y": schema.whole(1),
             "z": schema.either(schema.literal("start"),
                                schema.number(0, specials={"inf": math.inf})),
             "w": schema.number()}
    with pytest.raises(schema.SchemaError) as err:
        schema.check_section("s", table, rules)
    assert str(err.value) == message


def test_conversions_and_required_keys():
    rules = {"v": schema.items(schema.number(), length=3, unique=False),
             "g": schema.number(0, specials={"inf": math.inf}), "n": schema.whole(0)}
    got = schema.check_section("s", {"v": [1, 1, 2], "g": "inf", "n": 3}, rules, required=("v",))
    assert got == {"v": (1.0, 1.0, 2.0), "g": math.inf, "n": 3}
    assert isinstance(got["v"][0], float) and isinstance(got["n"], int)
    with pytest.raises(schema.SchemaError, match=r"missing key s.v \(why\)"):
        schema.check_section("s", {"n": 1}, rules, required=("v",), note="why")


def test_the_config_module_docstring_example_is_a_valid_study(tmp_path):
    """The example in ``jaxnav.study.config``'s docstring passes every pre-run check of
    ``jaxnav sweep --check`` (its ``[scenario]`` once named a key no factory knows)."""
    import textwrap

    from jaxnav import cli

    example = sc.__doc__.split("Example::\n", 1)[1].split("\n\nEvery error", 1)[0]
    path = tmp_path / "example.toml"
    path.write_text(textwrap.dedent(example))
    assert "[scenario]" in path.read_text()
    assert cli.main(["sweep", str(path), "--check"]) == 0
