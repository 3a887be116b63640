"""The reference of the scenario and airframe files, generated from their loaders.

Which fields each table takes is asked of the loader itself: a valid file gets one unknown
field in a table, and the loader's error lists the fields it knows there
(:func:`uavmpc.config.reject_unknown`). The defaults come from the dataclasses behind the
tables that have one; the descriptions from their docstrings (``Attributes:``) or from
:data:`DESCRIPTIONS`. ``uavmpc file-reference`` prints the page (``docs/reference/files.md``);
``tests/test_fileref.py`` checks that it covers every field the loaders accept.
"""

from __future__ import annotations

import copy
import dataclasses
import re
import tomllib
from collections.abc import Callable
from importlib import resources
from typing import Any

from uavmpc.config import ConfigError
from uavmpc.drivers.summary import SECTIONS, SUMMARY_VERSION, summary_fields

_PROBE = "zz_not_a_field"

#: Descriptions of fields whose table has no dataclass docstring to say it (unit in the
#: name where it has one). Keys: (table, field).
DESCRIPTIONS: dict[tuple[str, str], str] = {
    ("", "name"): "the scenario's name (default: the file's stem)",
    ("", "duration_s"): "how long it is flown; (0, 7 days]",
    ("", "link"): "the simulated link (table below)",
    ("", "avoidance"): "the avoidance's parameters (table below; default: the reference "
                       "design's)",
    ("", "uavs"): "the UAVs, one `[[uavs]]` table each (1 to 1000)",
    ("", "limits"): "every UAV's nominal dynamic limits (table below; default: "
                    "`data/tracker.toml`)",
    ("", "ground_vehicle"): "a car on a figure-eight track carrying a landing deck",
    ("", "target_sensor"): "the lander's fixes of the car",
    ("", "landing"): "a UAV that lands on the car's deck",
    ("", "formation"): "a formation: a leader and followers flying slots around it",
    ("", "geofence"): "the operational volume: missions outside are refused, a UAV found "
                      "outside flies back in and holds, offsets stay under its ceiling",
    ("link", "latency_s"): "one-way latency of every message [s], ≥ 0",
    ("link", "jitter_s"): "uniform extra latency in [0, jitter_s] [s], ≥ 0",
    ("link", "loss"): "probability that a message is lost, in [0, 1)",
    ("link", "range_m"): "messages beyond this distance are lost; 0: unlimited [m]",
    ("link", "burst_len"): "mean length of a burst of losses (a Gilbert channel) in "
                           "messages; 0: independent losses",
    ("uavs[]", "id"): "the UAV's id, 1–32 characters of `[A-Za-z0-9_-]`, unique",
    ("uavs[]", "priority"): "its priority, unique; a lower number yields less (1 is highest)",
    ("uavs[]", "airframe"): "`f550`, `x500` or an airframe file (default `f550`)",
    ("uavs[]", "start"): "[x, y, z] where it starts, ENU [m]",
    ("uavs[]", "heading_rad"): "its heading at the start [rad] (default 0)",
    ("uavs[]", "goto"): "[x, y, z, heading]: a point to fly to and hold",
    ("uavs[]", "trajectory"): "a desired trajectory as points (table below)",
    ("uavs[]", "path"): "waypoints flown at a speed (table below)",
    ("uavs[]", "avoidance"): "false: it flies without avoidance, its flag down, and the others "
                             "yield to it (default true)",
    ("uavs[].path", "waypoints"): "[[x, y, z], ...] at least two [m]",
    ("uavs[].path", "speed_mps"): "speed along the path [m/s], > 0",
    ("uavs[].path", "start_s"): "when it sets off [s] (default 0)",
    ("uavs[].path", "sample_period_s"): "spacing of the sampled trajectory [s] (default 0.2)",
    ("uavs[].trajectory", "points"): "[[x, y, z, heading], ...] one per sample",
    ("uavs[].trajectory", "sample_period_s"): "time between points [s], ≥ 0.001 (default 0.2)",
    ("uavs[].trajectory", "start_s"): "time of the first point [s] (default 0)",
    ("uavs[].trajectory", "times_s"): "instead of sample_period_s and start_s: each point's "
                                      "time [s], increasing",
    ("uavs[].trajectory", "loop"): "start again after the last point (default false)",
    ("ground_vehicle", "speed_kmh"): "the car's speed [km/h], > 0",
    ("ground_vehicle", "track_length_m"): "the figure eight's length [m] (default 90)",
    ("ground_vehicle", "track_width_m"): "its width [m] (default 60)",
    ("ground_vehicle", "track_centre"): "[x, y] its centre [m] (default [0, 0])",
    ("ground_vehicle", "start_arc_m"): "where along the track the car starts [m] (default 0)",
    ("ground_vehicle", "deck_size_m"): "side of the square deck [m] (default 1.5)",
    ("ground_vehicle", "deck_height_m"): "the deck's top above the ground [m] (default 1.5)",
    ("target_sensor", "rate_hz"): "fixes per second of the car's position [Hz]",
    ("target_sensor", "sigma_m"): "white noise per horizontal axis of a fix [m]",
    ("target_sensor", "dropout"): "probability that a fix is missing, in [0, 1)",
    ("landing", "uav"): "the id of the UAV that lands",
    ("landing", "touchdown_speed_mps"): "how fast the wanted height drops below "
                                        "`flare_height_m` (a soft touchdown) [m/s]",
    ("landing", "flare_height_m"): "height above the deck where the flare starts [m]",
    ("formation", "leader"): "the id of the UAV the others keep their slots around",
    ("formation", "followers"): "the ids of the followers, in slot order",
    ("formation", "spacing_m"): "distance between neighbouring slots [m], > 0",
    ("formation", "shape"): "`line` or `square` at the start",
    ("formation", "changes"): "shape changes in flight: `[{ t_s, shape }, ...]`",
    ("formation", "transition_s"): "how long a change of shape takes [s]",
    ("formation", "member_radius_m"): "the avoidance cylinder's radius between members [m] "
                                      "(smaller than the spacing)",
    ("formation", "heading_rad"): "the formation's heading when the leader hovers [rad]",
    ("formation.changes[]", "t_s"): "when the change starts [s]",
    ("formation.changes[]", "shape"): "the new shape, `line` or `square`",
    ("geofence", "polygon"): "[[x, y], ...] the volume's outline, a simple polygon [m] (or "
                             "`box`)",
    ("geofence", "box"): "[x0, y0, x1, y1] the volume's outline as a rectangle [m] (or "
                         "`polygon`)",
    ("geofence", "min_altitude_m"): "the volume's floor [m]",
    ("geofence", "max_altitude_m"): "its ceiling [m]; avoidance offsets stay below it",
    ("geofence", "margin_m"): "how far outside a UAV may be before the failsafe acts [m]",
    ("geofence", "inset_m"): "how far inside the boundary a UAV is brought back to [m]",
    # airframes
    ("airframe", "name"): "the airframe's name",
    ("airframe", "mass_kg"): "take-off mass [kg]",
    ("airframe", "inertia"): "the inertia tensor (table below)",
    ("airframe", "rotors"): "the rotors (table below)",
    ("airframe", "drag"): "linear drag (table below)",
    ("airframe", "se3"): "the SE(3) controller's gains (table below)",
    ("airframe", "attitude"): "the attitude loop's gains (table below)",
    ("airframe", "max_touchdown_speed_mps"): "a touchdown faster than this is a hard one "
                                             "[m/s]",
    ("airframe.inertia", "ixx_kgm2"): "body-frame inertia [kg m²]",
    ("airframe.inertia", "iyy_kgm2"): "body-frame inertia [kg m²]",
    ("airframe.inertia", "izz_kgm2"): "body-frame inertia [kg m²]",
    ("airframe.inertia", "ixy_kgm2"): "product of inertia [kg m²] (default 0)",
    ("airframe.inertia", "ixz_kgm2"): "product of inertia [kg m²] (default 0)",
    ("airframe.inertia", "iyz_kgm2"): "product of inertia [kg m²] (default 0)",
    ("airframe.rotors", "arm_length_m"): "distance from the centre to each rotor [m]",
    ("airframe.rotors", "angles_deg"): "each rotor's angle from +x (FLU body frame) [deg]",
    ("airframe.rotors", "spin"): "each rotor's spin, +1 counter-clockwise, −1 clockwise",
    ("airframe.rotors", "k_f_n_per_radps2"): "thrust per squared rotor speed [N/(rad/s)²]",
    ("airframe.rotors", "k_m_nm_per_radps2"): "drag torque per squared rotor speed "
                                              "[N m/(rad/s)²]",
    ("airframe.rotors", "motor_tau_s"): "the motors' first-order time constant [s]",
    ("airframe.rotors", "omega_max_radps"): "top rotor speed [rad/s]",
    ("airframe.rotors", "omega_idle_radps"): "idle rotor speed [rad/s]",
    ("airframe.drag", "linear_n_per_mps"): "[x, y, z] body-frame linear drag [N/(m/s)]",
    ("airframe.se3", "kp_n_per_m"): "[x, y, z] position gain [N/m]",
    ("airframe.se3", "kv_n_per_mps"): "[x, y, z] velocity gain [N/(m/s)]",
    ("airframe.se3", "ki_world_n_per_ms"): "[x, y, z] world-frame integral gain [N/(m s)]",
    ("airframe.se3", "ki_body_n_per_ms"): "[x, y, z] body-frame integral gain [N/(m s)]",
    ("airframe.se3", "integral_limit_world_ms"): "[x, y, z] world integral's bound [m s]",
    ("airframe.se3", "integral_limit_body_ms"): "[x, y, z] body integral's bound [m s]",
    ("airframe.se3", "max_tilt_deg"): "largest tilt commanded [deg], (0, 80]",
    ("airframe.se3", "thrust_min_fraction"): "lowest collective thrust, as a fraction of the "
                                             "rotors' maximum",
    ("airframe.se3", "thrust_max_fraction"): "highest collective thrust, as a fraction of the "
                                             "rotors' maximum, ≤ 1",
    ("airframe.attitude", "angle_p_per_s"): "[roll, pitch, yaw] attitude gain [1/s]",
    ("airframe.attitude", "max_rate_dps"): "[roll, pitch, yaw] body-rate bound [deg/s]",
    ("airframe.attitude", "rate_p_per_s"): "[roll, pitch, yaw] rate gain [1/s]",
    ("airframe.attitude", "rate_i_per_s2"): "[roll, pitch, yaw] rate integral gain [1/s²]",
    ("airframe.attitude", "rate_d"): "[roll, pitch, yaw] rate derivative gain",
    ("airframe.attitude", "rate_integral_limit_radps2"): "[roll, pitch, yaw] the rate "
                                                         "integral's bound [rad/s²]",
    ("airframe.attitude", "yaw_weight"): "share of the yaw error in the attitude error, (0, 1]",
}

#: The dynamic limits' fields (one docstring for all: "Box limits of the virtual UAV").
_LIMIT_WORDS = {"horizontal": "horizontal (x and y each)", "ascend": "upwards",
                "descend": "downwards", "heading": "of the heading"}


def _limit_doc(field: str) -> str:
    kind, quantity = field.split("_", 1)
    what, unit = {"speed_mps": ("speed", "m/s"), "accel_mps2": ("acceleration", "m/s²"),
                  "rate_radps": ("rate", "rad/s"), "accel_radps2": ("acceleration", "rad/s²")
                  }[quantity]
    return f"largest {what} {_LIMIT_WORDS[kind]} [{unit}], > 0"


def _markdown(rst: str) -> str:
    """A docstring's inline markup as Markdown (``x`` → `x`, :class:`~a.B` → `B`)."""
    text = re.sub(r":[a-z]+:`~?([^`]*)`", lambda m: f"`{m.group(1).split('.')[-1]}`", rst)
    return text.replace("``", "`")


def attribute_docs(cls: type) -> dict[str, str]:
    """``name: text`` entries of a class docstring's ``Attributes:`` section (names joined by
    commas share their text)."""
    doc = cls.__doc__ or ""
    if "Attributes:" not in doc:
        return {}
    out: dict[str, str] = {}
    names: list[str] = []
    for line in doc.split("Attributes:", 1)[1].splitlines():
        if not line.strip():
            continue
        m = re.match(r"^ {8}([a-z][a-z_0-9]*(?:, [a-z][a-z_0-9]*)*):\s*(.*)$", line)
        if m:
            names = [n.strip() for n in m.group(1).split(",")]
            for n in names:
                out[n] = m.group(2).strip()
        elif line.startswith(" " * 10) and names:
            for n in names:
                out[n] += " " + line.strip()
        else:
            break
    return out


def known_fields(load: Callable[[dict[str, Any]], object], doc: dict[str, Any],
                 path: tuple[str | int, ...]) -> list[str]:
    """The fields the loader ``load`` accepts in the table at ``path`` of the valid ``doc``."""
    probe = copy.deepcopy(doc)
    table: Any = probe
    for key in path:
        table = table[key]
    table[_PROBE] = 0
    try:
        load(probe)
    except ConfigError as exc:
        m = re.search(r"unknown field \(known: ([^)]*)\)", str(exc))
        if m and _PROBE in str(exc):
            return [f.strip() for f in m.group(1).split(",")]
        raise
    raise ConfigError(f"{'.'.join(map(str, path)) or 'top level'}: the loader accepted an "
                      f"unknown field")


def _builtin(name: str) -> dict[str, Any]:
    return tomllib.loads(resources.files("uavmpc.scenarios").joinpath(f"{name}.toml")
                         .read_text())


#: (table name, a valid document, the table's path in it, its dataclass if any)
_Probe = tuple[str, dict[str, Any], tuple[str | int, ...], type | None]


def _scenario_probes() -> list[_Probe]:
    """(table name, a valid document, the table's path in it, its dataclass if any)."""
    from uavmpc.avoidance import AvoidanceParams
    from uavmpc.geofence import Geofence
    from uavmpc.missions.formation import FormationSpec
    from uavmpc.missions.landing import LandingParams
    from uavmpc.scenarios import LinkSettings, TargetSensorSettings
    from uavmpc.tracker import DynamicLimits

    swap = _builtin("swap_through_static")
    swap["avoidance"], swap["limits"] = {}, {}
    swap["geofence"] = {"box": [-40, -20, 40, 20], "min_altitude_m": 1.0,
                        "max_altitude_m": 30.0}
    swap["uavs"][0].pop("goto")
    swap["uavs"][0]["path"] = {"waypoints": [[-25.0, 0.0, 5.0], [25.0, 0.0, 5.0]],
                               "speed_mps": 2.0}
    swap["uavs"][1].pop("goto")
    swap["uavs"][1]["trajectory"] = {"points": [[25.0, 0.0, 5.0, 0.0], [24.0, 0.0, 5.0, 0.0]],
                                     "sample_period_s": 1.0}
    landing = _builtin("moving_target_landing")
    formation = _builtin("formation")
    formation["formation"]["changes"] = [{"t_s": 10.0, "shape": "square"}]
    return [
        ("", swap, (), None),
        ("link", swap, ("link",), LinkSettings),
        ("avoidance", swap, ("avoidance",), AvoidanceParams),
        ("limits", swap, ("limits",), DynamicLimits),
        ("uavs[]", swap, ("uavs", 2), None),
        ("uavs[].path", swap, ("uavs", 0, "path"), None),
        ("uavs[].trajectory", swap, ("uavs", 1, "trajectory"), None),
        ("geofence", swap, ("geofence",), Geofence),
        ("ground_vehicle", landing, ("ground_vehicle",), None),
        ("target_sensor", landing, ("target_sensor",), TargetSensorSettings),
        ("landing", landing, ("landing",), LandingParams),
        ("formation", formation, ("formation",), FormationSpec),
        ("formation.changes[]", formation, ("formation", "changes", 0), None),
    ]


def _airframe_probes() -> list[_Probe]:
    doc = tomllib.loads(resources.files("uavmpc").joinpath("data/airframes/x500.toml")
                        .read_text())
    out: list[_Probe] = [
        ("airframe", doc, (), None)]
    out += [(f"airframe.{t}", doc, (t,), None)
            for t in ("inertia", "rotors", "drag", "se3", "attitude") if t in doc]
    return out


def reference_tables() -> dict[str, list[tuple[str, str, str]]]:
    """Table name → [(field, default, description)] for every table of the scenario and
    airframe files, the fields as the loaders accept them."""
    from uavmpc import scenarios
    from uavmpc.plant import Airframe

    tables: dict[str, list[tuple[str, str, str]]] = {}
    loaders: list[tuple[Callable[[dict[str, Any]], object], list[_Probe]]] = [
        (lambda d: scenarios.from_dict(d, "probe"), _scenario_probes()),
        (lambda d: Airframe.from_dict(d), _airframe_probes()),
    ]
    for load, probes in loaders:
        for name, doc, path, cls in probes:
            fields = known_fields(load, doc, path)
            defaults: dict[str, Any] = {}
            docs: dict[str, str] = {}
            if cls is not None and dataclasses.is_dataclass(cls):
                defaults = {f.name: f.default for f in dataclasses.fields(cls)
                            if f.default is not dataclasses.MISSING}
                docs = attribute_docs(cls)
            if name == "limits":  # a scenario's limits default to the tracker set-up's
                from uavmpc.tracker import TrackerConfig

                defaults = dataclasses.asdict(TrackerConfig.from_toml().limits)
            rows = []
            for f in sorted(fields):
                text = DESCRIPTIONS.get((name, f)) or _markdown(docs.get(f, ""))
                if not text and name == "limits":
                    text = _limit_doc(f)
                default = defaults.get(f)
                shown = "" if default is None else repr(
                    list(default) if isinstance(default, tuple) else default)
                rows.append((f, shown, text))
            tables[name] = rows
    return tables


def _cell(text: str) -> str:
    """Text for a Markdown table cell: no column breaks, and brackets that no renderer takes
    for a link (``[0, 1) [s]``)."""
    parts = text.replace("|", "/").split("`")
    for i in range(0, len(parts), 2):  # outside code spans only
        parts[i] = parts[i].replace("[", "\\[").replace("]", "\\]")
    return "`".join(parts)


#: What each key of a campaign's ``campaign.json`` spec means, per kind (checked against the
#: specs' own ``to_json`` by :func:`campaign_tables`).
CAMPAIGN_KEYS: dict[str, dict[str, str]] = {
    "random_walk": {
        "scenario": "always `random_walk`",
        "uavs": "UAVs per trial", "area_m": "side of the square area [m]",
        "height_m": "the flight height [m]", "avoidance": "flown with avoidance or without",
        "seed": "the campaign seed (trial `i`: `SeedSequence(seed, spawn_key=(i,))`)",
        "loss": "the link's loss probability", "latency_s": "the link's latency [s]",
        "jitter_s": "the link's jitter [s]", "wind_mps": "mean wind along x [m/s]",
        "trial_s": "with avoidance: every trial's length [s]",
        "cap_s": "without avoidance: a trial's longest flight [s] (it ends at its first "
                 "collision)",
        "faults": "the fault fields not at their defaults (`--clock-offset`, ...)",
        "avoidance_params": "the `[avoidance]` fields not at their defaults",
        "launch_check_s": "the launch check's longest wait [s]",
        "ground_start": "`true`: every UAV starts on the ground and takes off to `height_m` "
                        "before its walk (`--ground-start`; times count from the ground); "
                        "absent: they start in the air at `height_m`",
    },
    "landing": {
        "scenario": "the landing scenario: a built-in name or a file",
        "seed": "the campaign seed", "speed_kmh": "the car's speed (null: the scenario's)",
        "duration_s": "each flight's length [s] (null: the scenario's)",
    },
    "traffic": {
        "uavs": "UAVs per trial", "seed": "the campaign seed",
        "duration_s": "each flight's length [s] (null: each scenario's own)",
        "options": "more arguments of the traffic scenario (density, cruise heights, ...)",
    },
}


def campaign_tables() -> dict[str, list[tuple[str, str]]]:
    """Per campaign kind: (key, meaning) of its spec in ``campaign.json``; every key a spec
    writes (with every option set) has its meaning, and no meaning is of a key none writes."""
    from uavmpc.apps.campaign import RandomWalkSpec
    from uavmpc.apps.landing_campaign import LandingSpec
    from uavmpc.apps.traffic_campaign import TrafficSpec
    from uavmpc.avoidance import AvoidanceParams
    from uavmpc.scenarios.faults import FaultSpec
    from uavmpc.scenarios.run import RunSettings

    full = {
        "random_walk": {**RandomWalkSpec(run=RunSettings(faults=FaultSpec(gnss="rtk"),
                                                         launch_check_s=1.0),
                                         avoidance_params=AvoidanceParams(radius_m=6.0),
                                         ground_start=True)
                        .to_json(), **{"cap_s": 0.0}},
        "landing": LandingSpec().to_json(),
        "traffic": TrafficSpec().to_json(),
    }
    out = {}
    for kind, spec in full.items():
        keys = CAMPAIGN_KEYS[kind]
        if set(spec) != set(keys):
            raise AssertionError(f"campaign.json {kind}: keys {sorted(spec)} against the "
                                 f"described {sorted(keys)}")
        out[kind] = list(keys.items())
    return out


def _campaign_markdown() -> str:
    from uavmpc.apps.campaign_engine import FORMAT

    parts = [f"\n## `campaign.json` (a campaign folder)\n\n`{{\"format\": {FORMAT}, "
             "\"kind\": KIND, \"version\": UAVMPC, \"spec\": {...}}`: the campaign's "
             "specification, read back as the same object when the campaign continues. Format 1 "
             "(a random walk's `parameters`) is read as a random walk; any other format is an "
             "error naming it ([campaign.md](../campaign.md#running-it)).\n"]
    for kind, rows in campaign_tables().items():
        parts.append(f"\n### spec of kind `{kind}`\n\n| key | meaning |\n|---|---|\n")
        parts += [f"| `{k}` | {_cell(t)} |\n" for k, t in rows]
    return "".join(parts)


def reference_markdown() -> str:
    """The page ``docs/reference/files.md``."""
    head = (
        "# File reference\n\n"
        "Every field the scenario and airframe files take, table by table, as their loaders "
        "accept them (generated by `uavmpc file-reference` from the loaders themselves; "
        "`tests/test_fileref.py` checks that this page is current). SI units, ENU world "
        "frame; a field's unit is in its name where it has one. A field a loader does not "
        "know is an error naming it, as is a value out of its bounds.\n\n"
        "Scenario files: see `src/uavmpc/scenarios/*.toml` for examples. Airframe files: "
        "`src/uavmpc/data/airframes/*.toml`.\n\n"
        "**The mission format.** A UAV's `goto`, `trajectory` or `path` (exactly one; the "
        "`[uavs[]]` table and the two tables below) is the one mission format, whatever the "
        "source: a mission sent to a node (`uavmpc mission --goto …` or `--file mission.toml`"
        ", as JSON over the network), `uavmpc node --mission-file`, the files a swarm hands "
        "its nodes, and a ROS 2 goal or trajectory are each turned into such a table and "
        "checked by the one validator (`uavmpc.missions.format`). Times are on the UAV's "
        "clock: 0 is the scenario's start; for a node, Unix time, and a missing `start_s` "
        "means now. A go-to that waits for a time is a trajectory of one point.\n")
    parts = [head]
    for name, rows in reference_tables().items():
        title = ("scenario: top level" if name == "" else
                 "airframe: top level" if name == "airframe" else
                 f"`[{name}]`" if not name.startswith("airframe.") else
                 f"airframe: `[{name.split('.', 1)[1]}]`")
        parts.append(f"\n## {title}\n\n| field | default | meaning |\n|---|---|---|\n")
        parts += [f"| `{f}` | {f'`{d}`' if d else ''} | {_cell(t)} |\n" for f, d, t in rows]
    parts.append(_campaign_markdown())
    return "".join(parts) + summary_markdown()


def summary_rows() -> list[tuple[str, str, str]]:
    """``summary.json``'s fields as (dotted name, JSON type, meaning), from the dataclasses of
    :mod:`uavmpc.drivers.summary` and their docstrings."""
    rows = []
    for name, kind, cls, field in summary_fields():
        if name == "version":
            text = (f"the schema's version, {SUMMARY_VERSION}: a reader refuses another "
                    "(`RunSummary.read`)")
        else:
            text = attribute_docs(cls).get(field) or (cls.__doc__ or "").split("\n")[0]
        rows.append((name, kind, _markdown(text)))
    return rows


def summary_markdown() -> str:
    """The section of ``summary.json`` (written by ``uavmpc run``, ``demo`` and ``swarm``)."""
    parts = [
        "\n## `summary.json`\n\n"
        "What `uavmpc run`, `uavmpc demo` and `uavmpc swarm` write at the end of a run "
        "(`uavmpc.drivers.summary.RunSummary`), one schema for the simulated world (`driver` "
        "`world`) and for node processes (`swarm`). `a[].b`: field `b` of each item of the "
        "list `a`; `a{}.b`: of each value of the object `a` (keyed by UAV id). The status is "
        "the worst that applies, in this order: `collision` (two UAVs closer than 1 m), "
        "`vehicle_stopped` (a node died or its vehicle stopped being its to fly), "
        "`interrupted`, `goal_missed` (a UAV not at its goal, or a lander not landed, at the "
        "end), `complete`.\n\n| field | type | meaning |\n|---|---|---|\n"]
    parts += [f"| `{f}` | {_cell(k)} | {_cell(t)} |\n" for f, k, t in summary_rows()]
    parts.append("\n### `summary.json`: sections\n\n| section | what it holds |\n|---|---|\n")
    parts += [f"| `{k}` | {_cell(v)} |\n" for k, v in SECTIONS.items()]
    return "".join(parts)
