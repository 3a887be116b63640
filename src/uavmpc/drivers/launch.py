"""A node, or a stand-in PX4, as a process of the driver tier (issue 26).

``python -m uavmpc.drivers.launch SPEC.json`` runs what a launch specification says: a
:class:`NodeLaunch` (one UAV's :class:`~uavmpc.drivers.node.Node` over Zenoh, on its simulated
plant or on an autopilot over MAVLink) or a :class:`SitlLaunch` (a stand-in PX4 on
MAVLink/UDP). A specification is a frozen dataclass, written as one JSON object with its
``kind`` (:meth:`NodeLaunch.to_json`) and checked field by field when it is read
(:func:`load_launch`): a bad one is refused in one line that names the field.

A process started with a ``report_file`` writes its report there when it ends, as one typed
JSON object (``{"kind": "node", "report": {...NodeStats}}`` or ``{"kind": "sitl", ...}``),
read back and checked by :func:`read_report`; without one it prints the report as one JSON
line on its standard output (what ``uavmpc node`` and ``uavmpc sitl`` do).

The construction is written once, here: ``uavmpc node`` and ``uavmpc sitl``
(:mod:`uavmpc.apps.cli`) turn their flags into a specification and call :func:`run_node` or
:func:`run_sitl`; :mod:`uavmpc.drivers.swarm` writes a specification per process and launches
this module — a driver never launches the application tier.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import time
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias, TypeVar, cast

from uavmpc.avoidance import AvoidanceParams
from uavmpc.config import ConfigError, describe
from uavmpc.drivers.node import NodeStats
from uavmpc.geofence import Geofence
from uavmpc.scenarios import (
    LimitOverrides,
    LinkSettings,
    Scenario,
    avoidance_params,
    changed_fields,
)
from uavmpc.typed_json import check_fields, decode_dataclass

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

    from uavmpc.comms.auth import Identity, Roster
    from uavmpc.comms.ros2 import RosGraph, UavTopics
    from uavmpc.drivers.px4.vehicle import Px4Vehicle
    from uavmpc.missions.formation import FormationFollower
    from uavmpc.plant import Airframe
    from uavmpc.reference import Reference

    #: What a node's credential files give: (shared key, identity, roster), None if not given.
    Credentials: TypeAlias = tuple[bytes | None, Identity | None, Roster | None]

__all__ = ["LaunchError", "NodeLaunch", "SitlLaunch", "SitlReport", "launch_command",
           "load_credentials", "load_launch", "node_settings", "read_report", "run_node",
           "run_sitl", "write_report"]

#: The module a launch runs (``python -m`` this).
MODULE = "uavmpc.drivers.launch"
#: PX4 SITL's home: the stand-in's default origin on the globe (deg, deg, m AMSL).
PX4_SITL_HOME = (47.397742, 8.545594, 488.0)
SETPOINTS = ("attitude", "position")

Vec3 = tuple[float, float, float]


class LaunchError(ValueError):
    """A launch specification or a process report that does not hold (one line, naming the
    field)."""


@dataclass(frozen=True)
class NodeLaunch:
    """One UAV's node process (the flags of ``uavmpc node``, by the same names)."""

    uav_id: str
    priority: int
    airframe: str = "f550"
    swarm: str = "default"
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    start_m: Vec3 = (0.0, 0.0, 5.0)
    heading_rad: float = 0.0
    #: Seconds to fly (with ``mavlink``: then land); None: until SIGINT/SIGTERM.
    duration_s: float | None = None
    #: Initial mission: fly to (x, y, z, heading), or the trajectory in this JSON file.
    goto: tuple[float, float, float, float] | None = None
    mission_file: str | None = None
    #: ... or this mission table (one of goto, trajectory or path; times on Unix time).
    mission: dict[str, Any] | None = None
    formation_file: str | None = None
    avoidance: bool = True
    #: The run's safety settings, as the scenario gives them to every UAV of a world: the
    #: ``[avoidance]`` fields that differ from the defaults, the ``[geofence]`` table (None:
    #: no volume) and the ``[limits]`` (:func:`node_settings`). Checked on load, naming the
    #: field: a node flies what the world flies, or refuses.
    avoidance_params: dict[str, Any] = field(default_factory=dict)
    geofence: dict[str, Any] | None = None
    limits: dict[str, float] = field(default_factory=dict)
    key_file: str | None = None
    identity_file: str | None = None
    roster_file: str | None = None
    #: Fly an autopilot at this MAVLink address instead of the simulated plant.
    mavlink: str | None = None
    setpoints: str = "attitude"
    origin_m: Vec3 = (0.0, 0.0, 0.0)
    geo_origin: Vec3 | None = None
    hover_thrust: float | None = None
    system_id: int | None = None
    ros2: str | None = None
    ros2_commands: bool = False
    #: Where the report goes when the node ends (None: one JSON line on stdout).
    report_file: str | None = None

    KIND: typing.ClassVar[str] = "node"

    def __post_init__(self) -> None:
        _validate(self, "node launch")
        if self.setpoints not in SETPOINTS:
            raise LaunchError(f"{self.KIND} launch.setpoints: must be one of "
                              f"{', '.join(SETPOINTS)}, not {self.setpoints!r}")
        if self.duration_s is not None and not self.duration_s > 0:
            raise LaunchError(f"{self.KIND} launch.duration_s: must be > 0, "
                              f"not {self.duration_s!r}")
        self.settings()

    def settings(self) -> tuple[AvoidanceParams, Geofence | None, LimitOverrides]:
        """The avoidance parameters, the operational volume and the limit overrides this
        node flies, validated.

        Raises:
            LaunchError: a field that does not hold (the message names it)."""
        try:
            params = avoidance_params(dict(self.avoidance_params))
            fence = None if self.geofence is None else Geofence.from_dict(dict(self.geofence))
            limits = LimitOverrides.from_dict(dict(self.limits))
        except (ConfigError, ValueError, TypeError) as exc:
            raise LaunchError(f"{self.KIND} launch: {exc}") from None
        return params, fence, limits

    def to_json(self) -> str:
        return _to_json(self)


def node_settings(scenario: Scenario) -> dict[str, Any]:
    """The :class:`NodeLaunch` fields that carry ``scenario``'s safety settings to a node
    process (its avoidance parameters, geofence and limits), exactly as the world flies them.

    Raises:
        ConfigError: the scenario asks for what a node process cannot honour, named: a
            ``[landing]`` on a ``[ground_vehicle]`` (the world's car), or a ``[link]`` other
            than the real network a node flies over (loss, range, bursts, or a latency or
            jitter other than the defaults the world simulates for a real link)."""
    what = [k for k, v in (("[landing]", scenario.landing),
                           ("[ground_vehicle]", scenario.ground_vehicle)) if v]
    default = LinkSettings()
    what += [f"[link].{name}" for name in ("latency_s", "jitter_s", "loss", "range_m",
                                           "burst_len")
             if getattr(scenario.link, name) != getattr(default, name)]
    if what:
        raise ConfigError(f"{scenario.name}: {', '.join(what)} need the simulated world; node "
                          "processes fly the real network and no car (fly it with: uavmpc run "
                          f"{scenario.name})")
    return {"avoidance_params": changed_fields(scenario.avoidance),
            "geofence": None if scenario.geofence is None else scenario.geofence.to_table(),
            "limits": scenario.limits.as_dict()}


@dataclass(frozen=True)
class SitlLaunch:
    """A stand-in PX4 process (the flags of ``uavmpc sitl``)."""

    connect: str = "udpout://127.0.0.1:14540"
    airframe: str = "f550"
    position_m: Vec3 = (0.0, 0.0, 0.0)
    heading_rad: float = 0.0
    system_id: int = 1
    odometry_rate_hz: float = 30.0
    clock_rate: float = 0.986
    seed: int = 0
    estimator_error: bool = True
    #: The world's ENU origin on the globe; None: no global position at all.
    geo_origin: Vec3 | None = PX4_SITL_HOME
    #: Send the plant's ground truth to UDP 127.0.0.1:truth_port as PX4's SIH SITL does.
    truth_port: int | None = None
    duration_s: float | None = None
    report_file: str | None = None

    KIND: typing.ClassVar[str] = "sitl"

    def __post_init__(self) -> None:
        _validate(self, "sitl launch")
        if self.duration_s is not None and not self.duration_s > 0:
            raise LaunchError(f"{self.KIND} launch.duration_s: must be > 0, "
                              f"not {self.duration_s!r}")

    def to_json(self) -> str:
        return _to_json(self)


@dataclass(frozen=True)
class SitlReport:
    """What a stand-in PX4 reports when it stops."""

    events: list[str] = field(default_factory=list)
    final_position_m: list[float] = field(default_factory=list)
    cpu_s: float = 0.0
    wall_s: float = 0.0

    def __post_init__(self) -> None:
        _validate(self, "sitl report")


#: The launch specifications and the reports, by the ``kind`` their JSON carries.
_KINDS: dict[str, type[NodeLaunch] | type[SitlLaunch]] = {"node": NodeLaunch,
                                                          "sitl": SitlLaunch}
_REPORT_KINDS: dict[type[DataclassInstance], str] = {NodeStats: "node", SitlReport: "sitl"}

T = TypeVar("T", bound="DataclassInstance")  # a dataclass type


# --- checking a dataclass field by field against its annotations -------------------------

def _validate(obj: DataclassInstance, what: str) -> None:
    check_fields(obj, what, LaunchError)


def _from_fields(cls: type[T], data: object, what: str) -> T:
    """An instance of the dataclass ``cls`` from a JSON object, every field checked."""
    if not isinstance(data, dict):
        raise LaunchError(f"{what}: must be a JSON object, not {describe(data)}")
    return cast(T, decode_dataclass(cls, data, what, LaunchError))


def _to_json(obj: NodeLaunch | SitlLaunch) -> str:
    return json.dumps({"kind": obj.KIND, **dataclasses.asdict(obj)}, allow_nan=False)


def load_launch(source: str | Path) -> NodeLaunch | SitlLaunch:
    """The launch specification in the JSON file ``source``, every field checked.

    Raises:
        LaunchError: not JSON, an unknown ``kind``, an unknown or missing field, or a field
            of the wrong type or value (the message names it).
        OSError: the file cannot be read."""
    text = Path(source).read_text()
    try:
        data = json.loads(text)
    except ValueError as exc:
        raise LaunchError(f"launch spec {source}: not JSON ({exc})") from None
    if not isinstance(data, dict):
        raise LaunchError(f"launch spec {source}: must be a JSON object")
    kind = data.pop("kind", None)
    if kind not in _KINDS:
        raise LaunchError(f"launch spec {source}: kind: must be one of "
                          f"{', '.join(map(repr, _KINDS))}, not {describe(kind)}")
    return _from_fields(_KINDS[kind], data, f"{kind} launch")


def write_report(path: str | Path, report: NodeStats | SitlReport) -> None:
    """``report`` (:class:`NodeStats` or :class:`SitlReport`) to ``path`` as one typed JSON
    object, whole or not at all (written aside, then renamed)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".part")
    tmp.write_text(json.dumps({"kind": _REPORT_KINDS[type(report)],
                               "report": dataclasses.asdict(report)}))
    os.replace(tmp, path)


def read_report(path: str | Path, cls: type[T]) -> T:
    """The report of kind ``cls`` (:class:`NodeStats` or :class:`SitlReport`) a process wrote
    to ``path``, every field checked.

    Raises:
        FileNotFoundError: the process wrote none (it was killed, or failed before its end).
        LaunchError: not a report of that kind, or a field that does not hold."""
    kind = _REPORT_KINDS[cls]
    try:
        data = json.loads(Path(path).read_text())
    except ValueError as exc:
        raise LaunchError(f"{kind} report: not JSON ({exc})") from None
    if not isinstance(data, dict) or data.get("kind") != kind or set(data) != {"kind",
                                                                               "report"}:
        raise LaunchError(f'{kind} report: must be {{"kind": "{kind}", "report": {{...}}}}')
    return _from_fields(cls, data["report"], f"{kind} report")


def launch_command(spec_file: str | Path) -> list[str]:
    """The command line of the process that runs the specification in ``spec_file``."""
    return [sys.executable, "-m", MODULE, str(spec_file)]


# --- the construction, written once -------------------------------------------------------

def load_credentials(prog: str, *, key_file: str | None, identity_file: str | None,
                     roster_file: str | None, need_roster: bool) -> Credentials | None:
    """(key, identity, roster) from a shared key file, an identity file, a roster file, or
    None after printing what is wrong (as ``prog``)."""
    key = identity = roster = None
    if key_file and identity_file:
        print(f"{prog}: --key-file or --identity-file, not both", file=sys.stderr)
        return None
    try:
        from uavmpc.comms import auth

        if key_file:
            key = auth.load_key(key_file)
        if identity_file:
            identity = auth.load_identity(identity_file)
        if need_roster:
            if (identity is None) != (roster_file is None):
                print(f"{prog}: --identity-file and --roster go together", file=sys.stderr)
                return None
            if roster_file:
                roster = auth.load_roster(roster_file)
    except ImportError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return None
    except ValueError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return None
    return key, identity, roster


def _say_compiling(airframe: Airframe) -> None:
    """One line before the kernels load: cold, they compile for about a minute."""
    print(f"uavmpc node: loading the compiled kernels for {airframe.name} before the link "
          "opens (the first run after install compiles them: about a minute)",
          file=sys.stderr, flush=True)


class _Refused(Exception):
    """A bad setting of a node's launch (said in one line; exit code 2)."""


def run_node(spec: NodeLaunch) -> int:
    """Build the node ``spec`` describes and fly it until its duration or SIGINT/SIGTERM;
    its report goes to ``spec.report_file`` (or stdout). Returns the exit code: 0, 1 if the
    autopilot never answered, 2 for a bad setting (said in one line on stderr)."""
    from uavmpc.comms.zenoh_link import ZenohTransport
    from uavmpc.drivers.node import Node
    from uavmpc.drivers.node import run_node as fly
    from uavmpc.plant import Airframe

    airframe = Airframe.named(spec.airframe)
    params, fence, limits = spec.settings()
    creds = load_credentials("uavmpc node", key_file=spec.key_file,
                             identity_file=spec.identity_file, roster_file=spec.roster_file,
                             need_roster=True)
    if creds is None:
        return 2
    key, identity, roster = creds
    try:
        if identity is not None and identity.member_id != spec.uav_id:
            raise _Refused(f"--identity-file is {identity.member_id!r}'s, not "
                           f"{spec.uav_id!r}'s")
        mission = _node_mission(spec)
        formation_mission, pair_radius = _node_formation(spec, mission)
        vehicle, lost = _node_vehicle(spec, airframe)
        # With a key, ROS 2 commands would be a way around it (ROS 2 has no signatures
        # here): they are taken only when asked for.
        graph, topics = _node_ros2(spec, (key is None and roster is None) or spec.ros2_commands)
    except _Refused as exc:
        print(f"uavmpc node: {exc}", file=sys.stderr)
        return 2
    with ZenohTransport(spec.uav_id, swarm=spec.swarm, listen=list(spec.listen),
                        connect=list(spec.connect)) as transport:
        node = Node(spec.uav_id, spec.priority, airframe, transport, start_m=spec.start_m,
                    heading_rad=spec.heading_rad, avoidance=spec.avoidance, params=params,
                    geofence=fence, tracker_config=limits.over(None), key=key,
                    identity=identity, roster=roster, vehicle=vehicle, ros2=topics,
                    mission=formation_mission, pair_radius_m=pair_radius)
        if mission is not None:
            node.set_mission(mission)
        try:
            stats = fly(node, spec.duration_s)
        except lost as exc:  # the autopilot never answered
            print(f"uavmpc node: {exc}", file=sys.stderr)
            return 1
        finally:
            if graph is not None:
                graph.close()
    _report(spec.report_file, stats)
    return 0


def _node_mission(spec: NodeLaunch) -> Reference | None:
    """The node's mission (a Reference) from ``--mission-file`` or ``--goto``, or None."""
    from uavmpc.missions.format import mission_from_table, read_mission
    from uavmpc.reference import InvalidReferenceError

    try:
        if sum(x is not None for x in (spec.mission_file, spec.mission, spec.goto)) > 1:
            raise _Refused("one initial mission: --goto, --mission-file or the scenario's")
        if spec.mission_file:
            return read_mission(spec.mission_file, time.time())[1]
        if spec.mission is not None:
            return mission_from_table(spec.mission, "mission", time.time())
        if spec.goto:
            return mission_from_table({"goto": spec.goto}, "--goto", time.time())
    except InvalidReferenceError as exc:
        raise _Refused(f"bad mission: {exc}") from None
    return None


def _node_formation(spec: NodeLaunch, mission: Reference | None
                    ) -> tuple[FormationFollower | None, dict[str, float]]:
    """With ``--formation``: a follower's mission (its slot) and the members' pair radii."""
    if not spec.formation_file:
        return None, {}
    from uavmpc.missions.formation import FormationFollower, load_formation

    formation = load_formation(spec.formation_file)
    if spec.uav_id not in formation.members:
        raise _Refused(f"--formation: {spec.uav_id!r} is not a member of the formation "
                       f"({', '.join(formation.members)})")
    pair_radius = formation.pair_radii(spec.uav_id)
    if spec.uav_id not in formation.followers:
        return None, pair_radius
    if mission is not None:
        raise _Refused("a follower flies its slot: no --goto or --mission-file")
    return FormationFollower(formation, spec.uav_id), pair_radius


def _node_vehicle(spec: NodeLaunch, airframe: Airframe
                  ) -> tuple[Px4Vehicle | None, tuple[type[Exception], ...]]:
    """With ``--mavlink``: the PX4 vehicle (kernels loaded first) and the error it raises
    when the autopilot never answers; else (None, ())."""
    if spec.geo_origin is not None and not spec.mavlink:
        raise _Refused("--geo-origin places a PX4's frame: it needs --mavlink")
    if not spec.mavlink:
        return None, ()
    from uavmpc.drivers.node import warm_up
    from uavmpc.drivers.px4.vehicle import Px4Vehicle, VehicleLost

    # Compile before the link exists: a first run compiles for a minute, and neither
    # the autopilot's clock map nor its stream should start before the flight can.
    _say_compiling(airframe)
    warm_up(airframe)
    try:
        vehicle = Px4Vehicle(spec.mavlink, airframe, setpoints=spec.setpoints,
                             system_id=spec.system_id, hover_thrust=spec.hover_thrust,
                             origin_m=spec.origin_m, geo_origin=spec.geo_origin)
    except (ValueError, OSError) as exc:
        raise _Refused(f"--mavlink: {exc}") from None
    return vehicle, (VehicleLost,)


def _node_ros2(spec: NodeLaunch, commands: bool
               ) -> tuple[RosGraph | None, UavTopics | None]:
    """With ``--ros2``: the graph and the UAV's topics (taking commands if ``commands``);
    else (None, None)."""
    if not spec.ros2:
        return None, None
    from uavmpc.comms.ros2 import UavTopics
    from uavmpc.drivers.ros2 import open_graph

    try:
        graph = open_graph(spec.ros2, f"uavmpc_{spec.uav_id.replace('-', '_')}")
    except (ValueError, OSError) as exc:
        raise _Refused(f"--ros2: {exc}") from None
    return graph, UavTopics(graph, spec.uav_id, commands=commands)


def run_sitl(spec: SitlLaunch) -> int:
    """Build the stand-in PX4 ``spec`` describes and run it until its duration or
    SIGINT/SIGTERM; its report goes to ``spec.report_file`` (or stdout). Returns the exit
    code: 0, or 2 for a bad setting (said in one line on stderr)."""
    from uavmpc.drivers.px4.sitl import StandInPx4
    from uavmpc.drivers.px4.sitl import run_sitl as serve
    from uavmpc.plant import Airframe

    airframe = Airframe.named(spec.airframe)
    try:
        sitl = StandInPx4(airframe, spec.connect, position_m=spec.position_m,
                          heading_rad=spec.heading_rad, system_id=spec.system_id,
                          odometry_rate_hz=spec.odometry_rate_hz, clock_rate=spec.clock_rate,
                          seed=spec.seed, estimator_error=spec.estimator_error,
                          geo_origin_deg=spec.geo_origin, truth_port=spec.truth_port)
    except (ValueError, OSError) as exc:
        print(f"uavmpc sitl: {exc}", file=sys.stderr)
        return 2
    print(f"uavmpc sitl: PX4 stand-in (system {spec.system_id}) on UDP port "
          f"{sitl.link.local_port}, talking to {sitl.link.address}", file=sys.stderr, flush=True)
    cpu0, wall0 = time.process_time(), time.perf_counter()
    serve(sitl, spec.duration_s)
    _report(spec.report_file, SitlReport(
        events=list(sitl.events), final_position_m=sitl.plant.state().position_m.tolist(),
        cpu_s=time.process_time() - cpu0, wall_s=time.perf_counter() - wall0))
    return 0


def _report(report_file: str | None, report: NodeStats | SitlReport) -> None:
    if report_file is not None:
        write_report(report_file, report)
    else:
        print(json.dumps(dataclasses.asdict(report)), flush=True)


def main(argv: list[str] | None = None) -> int:
    """``python -m uavmpc.drivers.launch SPEC.json``: run the specification's process."""
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print(f"usage: python -m {MODULE} SPEC.json", file=sys.stderr)
        return 2
    try:
        spec = load_launch(args[0])
    except (OSError, LaunchError) as exc:
        print(f"{MODULE}: {exc}", file=sys.stderr)
        return 2
    from uavmpc.config import exit_code_of

    return exit_code_of(lambda: run_node(spec) if isinstance(spec, NodeLaunch)
                        else run_sitl(spec))


if __name__ == "__main__":
    sys.exit(main())
