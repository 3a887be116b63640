"""Bad input gets a clear error naming the problem; the tracker keeps flying its current plan."""

import numpy as np
import pytest

from uavmpc import (
    ConfigError,
    DynamicLimits,
    InvalidReferenceError,
    MpcTracker,
    Reference,
    TrackerConfig,
)
from uavmpc.reference import MAX_POINTS
from uavmpc.tracker import InvalidStateError

T3 = np.array([0.0, 0.2, 0.4])
P3 = np.zeros((3, 4))


@pytest.mark.parametrize(
    ("times", "points", "match"),
    [
        (T3, np.zeros((3, 3)), r"shape \(N, 4\)"),
        (T3, np.zeros(4), r"shape \(N, 4\)"),
        (T3, np.zeros((3, 4, 1)), r"shape \(N, 4\)"),
        (np.zeros((3, 1)), P3, "times_s must be 1-D"),
        (T3[:2], P3, "2 stamps but points has 3 rows"),
        (np.array([]), np.zeros((0, 4)), "empty"),
        (T3, np.where(np.arange(12).reshape(3, 4) == 6, np.nan, 0.0), r"points\[1\] z is nan"),
        (T3, np.where(np.arange(12).reshape(3, 4) == 3, np.inf, 0.0),
         r"points\[0\] heading is inf"),
        (np.array([0.0, np.nan, 0.4]), P3, "times_s contains NaN"),
        (np.array([0.0, 0.4, 0.2]), P3, r"times_s\[1\]=0.4 then times_s\[2\]=0.2"),
        (np.array([0.0, 0.2, 0.2]), P3, "must increase"),
        (T3, np.full((3, 4), 1e9), "beyond the sane bound"),
        (T3, [["a", 0, 0, 0]] * 3, "not numeric"),
    ],
)
def test_bad_reference_is_rejected_with_a_named_problem(times, points, match) -> None:
    with pytest.raises(InvalidReferenceError, match=match):
        Reference(times, points)


def test_absurd_sizes_and_periods_are_rejected() -> None:
    with pytest.raises(InvalidReferenceError, match="more than the limit"):
        Reference.sampled(np.zeros((MAX_POINTS + 1, 4)), 0.2)
    with pytest.raises(InvalidReferenceError, match="sample_period_s"):
        Reference.sampled(P3, 0.0)
    with pytest.raises(InvalidReferenceError, match="sample_period_s must be finite"):
        Reference.sampled(P3, float("nan"))
    with pytest.raises(InvalidReferenceError, match="start_s must be finite"):
        Reference.goto(1.0, 2.0, 3.0, start_s=float("inf"))
    with pytest.raises(InvalidReferenceError, match="looping reference needs at least two"):
        Reference(np.array([0.0]), np.zeros((1, 4)), loop=True)


@pytest.mark.parametrize("field", ["horizontal_speed_mps", "descend_accel_mps2",
                                   "heading_rate_radps"])
@pytest.mark.parametrize("value", [0.0, -1.0, float("nan"), float("inf"), 1e6, "fast"])
def test_bad_limits_are_rejected_naming_the_field(field: str, value: object) -> None:
    with pytest.raises(ConfigError, match=f"limits.{field}"):
        DynamicLimits(**{field: value})


@pytest.mark.slow
def test_tracker_keeps_its_reference_and_state_after_bad_input() -> None:
    tracker = MpcTracker(position_m=(0.0, 0.0, 10.0))
    good = Reference.goto(20.0, 0.0, 10.0)
    tracker.set_reference(good)
    for _ in range(200):
        tracker.step()
    state, t = tracker.state, tracker.time_s
    with pytest.raises(TypeError, match=r"must be a uavmpc\.Reference"):
        tracker.set_reference(np.zeros((3, 4)))  # type: ignore[arg-type]
    with pytest.raises(InvalidReferenceError):
        tracker.set_reference(Reference(T3, np.full((3, 4), np.nan)))
    with pytest.raises(TypeError, match="DynamicLimits"):
        tracker.set_limits({"horizontal_speed_mps": 1.0})  # type: ignore[arg-type]
    with pytest.raises(InvalidStateError, match="shape"):
        tracker.set_state(np.zeros((3, 3)))
    with pytest.raises(InvalidStateError, match="NaN"):
        tracker.set_state(np.full((4, 3), np.nan))
    with pytest.raises(InvalidStateError, match="outside the limits"):
        tracker.set_state(np.array([[0, 50.0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0]]))
    assert tracker.reference is good
    np.testing.assert_array_equal(tracker.state, state)
    assert tracker.time_s == t
    for _ in range(1500):
        tracker.step()
    assert tracker.state[0, 0] == pytest.approx(20.0, abs=0.01)


def test_bad_constructor_arguments() -> None:
    with pytest.raises(InvalidStateError, match="position_m"):
        MpcTracker(position_m=(0.0, np.nan, 0.0))
    with pytest.raises(InvalidStateError, match="heading_rad"):
        MpcTracker(heading_rad=np.inf)
    with pytest.raises(ValueError, match="one per axis"):
        MpcTracker(solvers=[])


def test_tracker_config_files_are_validated(tmp_path) -> None:
    good = TrackerConfig.from_toml()
    assert good.steps == 40 and good.limits.horizontal_speed_mps == 8.3
    cases = {
        "[weights]\nposition = -5.0\n": "weights.position: must be > 0",
        "[horizon]\nsteps = 1\n": "horizon.steps",
        "[horizon]\nstep = 0.2\n": "horizon.step: unknown field \\(did you mean 'steps'\\?",
        "[limits]\nhorizontal_speed_mps = 8.3\n": "limits.horizontal_accel_mps2: missing",
        "[solver]\nname = 'cvxgen'\n": "solver.name",
        "[model]\ntau_s = 0\n": "model.tau_s: must be > 0",
        "[weights\n": "invalid TOML",
    }
    for i, (text, match) in enumerate(cases.items()):
        path = tmp_path / f"t{i}.toml"
        path.write_text(text)
        with pytest.raises(ConfigError, match=match):
            TrackerConfig.from_toml(path)
    with pytest.raises(ConfigError, match="file not found"):
        TrackerConfig.from_toml(tmp_path / "missing.toml")


def test_a_bad_estimate_is_refused_by_name_and_changes_nothing() -> None:
    """An autopilot link or a simulator may hand over anything: the stack names the field and
    its state stays as it was (the next good estimate flies on)."""
    import dataclasses

    from uavmpc.onboard import OnboardStack
    from uavmpc.plant import Airframe, Multirotor

    af = Airframe.packaged("x500")
    plant = Multirotor(af, position_m=(0.0, 0.0, 5.0))
    stack = OnboardStack(af, position_m=(0.0, 0.0, 5.0))
    good = plant.state()
    stack.tick(0.0, good)
    before = stack.tracker.state
    for field, value, match in [("position_m", np.array([0.0, np.nan, 5.0]), "position_m"),
                                ("velocity_mps", np.zeros(2), "velocity_mps"),
                                ("attitude_wxyz", "level", "attitude_wxyz")]:
        with pytest.raises(ValueError, match=match):
            stack.tick(0.01, dataclasses.replace(good, **{field: value}))
    assert np.array_equal(stack.tracker.state, before)
    assert stack.report().ticks == 1
    # A read-only, strided view (as a driver may hand over) is taken as the same numbers.
    wide = np.zeros(6)
    wide[::2] = good.position_m
    wide.flags.writeable = False
    stack.tick(0.01, dataclasses.replace(good, position_m=wide[::2]))
    assert stack.report().ticks == 2


@pytest.mark.slow
def test_batch_rows_out_of_range_are_refused() -> None:
    from uavmpc.tracker import TrackerBatch

    batch = TrackerBatch(n=2)
    with pytest.raises(IndexError, match="rows"):
        batch.step(np.array([0, 2]))
    batch.step([1])  # any sequence of indices
    assert batch.rows.t_s[1] > 0.0 and batch.rows.t_s[0] == 0.0


def test_an_airframe_is_named_by_its_package_name_or_its_file(tmp_path) -> None:
    from importlib import resources

    from uavmpc.config import ConfigError
    from uavmpc.plant import Airframe

    path = tmp_path / "mine.toml"
    path.write_text(resources.files("uavmpc.data").joinpath("airframes/x500.toml").read_text())
    assert Airframe.named("x500").mass_kg == Airframe.packaged("x500").mass_kg
    assert Airframe.named(str(path)).mass_kg == Airframe.packaged("x500").mass_kg
    with pytest.raises(ConfigError, match="no such packaged airframe"):
        Airframe.named("x501")


def test_a_value_that_should_be_a_table_is_named_not_iterated() -> None:
    from uavmpc import scenarios
    from uavmpc.config import reject_unknown

    for value, got in [(5, "5"), ([], "an array of 0"), ("loss", "'loss'"), (None, "None")]:
        with pytest.raises(ConfigError, match=rf"^link: must be a table, got {got}$"):
            reject_unknown(value, {"loss"}, "link")
    # The loader's reproducers: [link], a [[uavs]] entry, a trajectory that is a number.
    one = {"id": "a", "priority": 1, "start": [0, 0, 1]}
    for doc, field in [({"link": 5}, "link"), ({"uavs": [1]}, r"uavs\[0\]"),
                       ({"uavs": [{**one, "trajectory": 1}]}, r"uavs\[0\]\.trajectory"),
                       ({"limits": 1}, "limits")]:
        with pytest.raises(ConfigError, match=rf"^{field}: must be a table"):
            scenarios.from_dict({"duration_s": 10.0, "uavs": [one], **doc})


def test_an_integer_beyond_the_float_range_is_named_too_large() -> None:
    from uavmpc import scenarios
    from uavmpc.config import finite, positive

    with pytest.raises(ConfigError, match=r"^duration_s: an integer of about 401 digits is too "
                                          r"large \(beyond the float range\)$"):
        scenarios.from_dict({"duration_s": 10**400,
                             "uavs": [{"id": "a", "priority": 1, "start": [0, 0, 1]}]})
    with pytest.raises(ConfigError, match=r"^x: an integer of about 5001 digits is too large"):
        positive(10**5000, "x")  # (its repr() would raise: more than 4300 digits)
    with pytest.raises(ConfigError, match=r"^x: must be a finite number, got an integer"):
        finite(-(10**400), "x")
    with pytest.raises(ConfigError, match=r"^x: must be a finite number within ±10, got 11"):
        finite(11, "x", 10.0)
    with pytest.raises(ConfigError, match=r"^x: must be a finite number, got nan"):
        finite(float("nan"), "x")
    assert positive(10**300, "x") == 1e300 and finite(-3, "x") == -3.0


def test_unreadable_and_undecodable_files_are_named(tmp_path, monkeypatch) -> None:
    import re
    from pathlib import Path

    from uavmpc.config import read_toml

    def refused(path, needle: str) -> None:
        with pytest.raises(ConfigError, match=rf"^{re.escape(str(path))}: .*{needle}"):
            read_toml(path)

    latin = tmp_path / "latin.toml"
    latin.write_bytes('name = "\xff"\nduration_s = 10.0\n'.encode("latin-1"))
    refused(latin, r"not UTF-8 text \(byte 0xff at offset 8\)")
    refused(tmp_path, "cannot read: Is a directory")
    refused(tmp_path / ("x" * 300 + ".toml"), "cannot read: File name too long")
    refused(tmp_path / "a\x00b.toml", "cannot read: embedded null byte")
    deep = tmp_path / "deep.toml"
    deep.write_text("a = " + "[" * 5000 + "]" * 5000)
    refused(deep, "invalid TOML: nested too deeply")
    deep.write_text("a = 1" + "0" * 5000)
    refused(deep, "invalid TOML: Exceeds the limit")
    good = tmp_path / "good.toml"
    good.write_text("a = 1\n")
    assert read_toml(good) == {"a": 1}

    def denied(self: Path) -> bytes:  # (chmod 000 does not stop root, who may run the tests)
        raise PermissionError(13, "Permission denied", str(self))

    monkeypatch.setattr(Path, "read_bytes", denied)
    refused(good, "cannot read: Permission denied")


@pytest.mark.parametrize("name", ["a\x00b", "x" * 300, "../tracker", "../airframes/f550",
                                  "airframes/f550", "", "F550", "f550 "])
def test_an_airframe_name_is_only_looked_up_among_the_packaged_ones(name: str) -> None:
    from uavmpc.plant import Airframe

    # Never joined into a path: NUL and overlong names made the OS raise, "../tracker" read
    # another file of the package's data folder.
    for load in (Airframe.named, Airframe.packaged):
        with pytest.raises(ConfigError, match=r"^airframe .*: no such packaged airframe "
                                              r"\(packaged: f550, x500\)$"):
            load(name)


def test_an_airframe_file_that_cannot_be_read_is_named(tmp_path, monkeypatch) -> None:
    import re
    import tomllib
    from importlib import resources

    from uavmpc.plant import Airframe

    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match=r"^f550\.toml: file not found$"):
        Airframe.named("f550.toml")  # a file (of the current directory), not the package's
    folder = tmp_path / "dir.toml"
    folder.mkdir()
    with pytest.raises(ConfigError, match=rf"^{re.escape(str(folder))}: cannot read: Is a "
                                          r"directory$"):
        Airframe.named(str(folder))
    with pytest.raises(ConfigError, match=r"cannot read: embedded null byte"):
        Airframe.named("a\x00b.toml")
    text = resources.files("uavmpc.data").joinpath("airframes/x500.toml").read_text()
    d = tomllib.loads(text)
    d["inertia"]["ixy_kgm2"] = 10**400
    with pytest.raises(ConfigError, match=r"^airframe\.inertia\.ixy_kgm2: must be a finite "
                                          r"number, got an integer of about 401 digits$"):
        Airframe.from_dict(d)
