"""The one typed JSON decoder (summary.json, launch specifications and reports)."""

import dataclasses
import enum
import json

import pytest

from uavmpc.typed_json import check_fields, decode, plain


class Bad(ValueError):
    pass


class Colour(enum.Enum):
    RED = "red"
    BLUE = "blue"


@dataclasses.dataclass(frozen=True)
class Inner:
    n: int
    xs: tuple[float, ...] = ()


@dataclasses.dataclass(frozen=True)
class Outer:
    name: str
    colour: Colour
    pair: tuple[int, str]
    inner: Inner
    by_id: dict[str, Inner]
    maybe: float | None = None
    tags: list[str] = dataclasses.field(default_factory=list)


def test_a_dataclass_round_trips_through_json_every_type_restored() -> None:
    o = Outer("a", Colour.BLUE, (1, "x"), Inner(2, (0.5, 1.0)), {"u": Inner(3)}, 2.0, ["t"])
    back = decode(Outer, json.loads(json.dumps(plain(dataclasses.asdict(o)))), "o", Bad)
    assert back == o and isinstance(back.pair, tuple) and isinstance(back.inner.xs, tuple)
    assert decode(Outer, {"name": "a", "colour": "red", "pair": [1, "x"], "inner": {"n": 1},
                          "by_id": {}}, "o", Bad).maybe is None  # defaults fill in
    assert decode(float, 3, "x", Bad) == 3.0 and isinstance(decode(float, 3, "x", Bad), float)


@pytest.mark.parametrize(("value", "message"), [
    ({"name": "a"}, "o: missing field 'colour'"),
    ({"name": "a", "colour": "red", "pair": [1, "x"], "inner": {"n": 1}, "by_id": {},
      "extra": 1}, "o: unknown field 'extra'"),
    ({"name": "a", "colour": "green", "pair": [1, "x"], "inner": {"n": 1}, "by_id": {}},
     "o.colour: must be one of 'red', 'blue', not 'green'"),
    ({"name": "a", "colour": "red", "pair": [1], "inner": {"n": 1}, "by_id": {}},
     "o.pair: must have 2 items, not 1"),
    ({"name": "a", "colour": "red", "pair": [1, "x"], "inner": {"n": True}, "by_id": {}},
     "o.inner.n: must be an integer, not True"),
    ({"name": "a", "colour": "red", "pair": [1, "x"], "inner": {"n": 1, "xs": [1.0, "y"]},
      "by_id": {}}, "o.inner.xs[1]: must be a number, not 'y'"),
    ({"name": "a", "colour": "red", "pair": [1, "x"], "inner": {"n": 1},
      "by_id": {"u": {"n": "2"}}}, "o.by_id.u.n: must be an integer, not '2'"),
    ({"name": 5, "colour": "red", "pair": [1, "x"], "inner": {"n": 1}, "by_id": {}},
     "o.name: must be a string, not 5"),
    ([1, 2], "o: must be an object, not an array of 2"),
])
def test_a_bad_value_is_named_by_its_path(value, message: str) -> None:
    with pytest.raises(Bad) as err:
        decode(Outer, value, "o", Bad)
    assert str(err.value) == message


def test_fields_checked_after_construction_become_what_their_annotations_say() -> None:
    @dataclasses.dataclass(frozen=True)
    class Spec:
        at: tuple[float, float]
        n: int = 1

        def __post_init__(self) -> None:
            check_fields(self, "spec", Bad)

    assert Spec([1.0, 2.0]).at == (1.0, 2.0)  # type: ignore[arg-type]
    with pytest.raises(Bad, match=r"spec\.n: must be an integer, not 1\.5"):
        Spec((0.0, 0.0), 1.5)  # type: ignore[arg-type]
