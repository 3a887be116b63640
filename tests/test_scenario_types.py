"""A scenario's [avoidance] and [limits] are validated objects once loaded, parsed once."""

import pytest

from uavmpc import scenarios
from uavmpc.avoidance import AvoidanceParams
from uavmpc.config import ConfigError
from uavmpc.scenarios import LimitOverrides
from uavmpc.tracker import DynamicLimits

BASE = {"name": "x", "duration_s": 10.0,
        "uavs": [{"id": "a", "priority": 1, "start": [0.0, 0.0, 5.0]}]}


def test_avoidance_and_limits_are_loaded_as_objects() -> None:
    sc = scenarios.from_dict({**BASE, "avoidance": {"radius_m": 7.0},
                              "limits": {"ascend_speed_mps": 3.0}})
    assert sc.avoidance == AvoidanceParams(radius_m=7.0)
    assert sc.limits and sc.limits.as_dict() == {"ascend_speed_mps": 3.0}
    plain = scenarios.from_dict(BASE)
    assert plain.avoidance == AvoidanceParams() and not plain.limits


def test_limits_override_only_the_fields_they_set() -> None:
    over = LimitOverrides.from_dict({"horizontal_speed_mps": 12, "ascend_speed_mps": 3.0})
    base = DynamicLimits(horizontal_speed_mps=5.0, descend_speed_mps=0.5)
    out = over.apply(base)
    assert out.horizontal_speed_mps == 12.0 and out.ascend_speed_mps == 3.0
    assert out.descend_speed_mps == 0.5  # the base's own, not the default 1.5
    assert over == LimitOverrides.from_dict({"ascend_speed_mps": 3.0,
                                             "horizontal_speed_mps": 12.0})


@pytest.mark.parametrize(("table", "match"), [
    ({"limits": {"horizontal_speed_mps": -1.0}}, r"limits\.horizontal_speed_mps"),
    ({"limits": {"top_speed": 3.0}}, r"limits\.top_speed: unknown field"),
    ({"limits": 5}, "limits: must be a table"),
    ({"avoidance": {"radius_m": -2.0}}, r"avoidance\.radius_m"),
    ({"avoidance": {"radius": 2.0}}, r"avoidance\.radius: unknown field"),
    ({"avoidance": [1]}, "avoidance: must be a table"),
])
def test_a_bad_table_is_named_on_load(table: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        scenarios.from_dict({**BASE, **table})
