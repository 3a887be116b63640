"""A scenario flown by one node process per UAV on loopback, watched by a monitor (issue 6).

``uavmpc swarm SCENARIO_OR_FILE`` starts a node for every UAV of the scenario (each its own
process, peer-to-peer over Zenoh on 127.0.0.1, no broker), and a monitor in this process
that subscribes to every state and prediction, records them in the same MCAP format as the
simulated world, detects collisions and writes the same ``summary.json`` as ``uavmpc run``.

Each process is launched from this tier, never through the application's command line: the
swarm writes its launch specification (:class:`~uavmpc.drivers.launch.NodeLaunch`, the same
node ``uavmpc node`` builds) and starts ``python -m uavmpc.drivers.launch SPEC``; the node's
statistics come back as a checked report (:class:`~uavmpc.drivers.node.NodeStats`) in a file
of its own, not on its standard output.

Topology: the monitor listens first, node 0 next; every node connects to the monitor and every
other node to node 0 as well (Zenoh's gossip completes the mesh). The monitor is listening before
any node starts, so it hears each from its first message: connecting to a node not up yet, it
would wait out Zenoh's retry back-off and miss the first seconds of a loaded machine's flight.
All missions start at a common epoch a few seconds after launch, once the peers have found each
other.

With ``mavlink=True`` every UAV is a pair of processes: a stand-in PX4 (a
:class:`~uavmpc.drivers.launch.SitlLaunch`, as ``uavmpc sitl``) booted
on the ground below the UAV's start, and its node, connected over MAVLink/UDP on 127.0.0.1. The
node takes off to its start before the epoch, flies the mission, then lands and disarms; the
monitor keeps watching until every node has landed.

With ``px4_sitl`` (``uavmpc swarm SCENARIO --px4-sitl DIR``) every UAV is the real PX4 firmware
instead of the stand-in: the i-th UAV is PX4 SITL instance ``px4_first_instance + i`` with its
built-in SIH simulator, working in ``out/px4/<id>/`` (its console in ``px4.log``, its flight
log in ``log/<date>/*.ulg``), booted at the geodetic point below the UAV's start
(``enu_to_geodetic((x, y, 0), geo_origin)``); its node listens on ``udp://:14540+i`` and places
PX4's frame in the swarm's world from PX4's own GPS_GLOBAL_ORIGIN (``--geo-origin``). Every
instance is ready for take-off before the mission's epoch is set; all are stopped, with their
process groups, after their nodes.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import os
import random
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, TypeVar, cast

import numpy as np

from uavmpc.avoidance import AvoidanceParams
from uavmpc.comms.auth import load_key, verify
from uavmpc.comms.message import InvalidMessageError, decode
from uavmpc.comms.state import InvalidStateError, NodeState
from uavmpc.config import ConfigError
from uavmpc.drivers.launch import (
    PX4_SITL_HOME,
    LaunchError,
    NodeLaunch,
    SitlLaunch,
    SitlReport,
    launch_command,
    node_settings,
    read_report,
)
from uavmpc.drivers.node import NodeStats, warm_up
from uavmpc.drivers.px4.firmware import (
    DEFAULT_GEO_ORIGIN,
    MAX_INSTANCE,
    Px4Instance,
    Px4SitlBuild,
)
from uavmpc.drivers.px4.frames import enu_to_geodetic
from uavmpc.drivers.px4.truth import (
    TRUTH_PORT_BASE,
    TRUTH_RATE_HZ,
    Track,
    TruthListener,
    closest_by_pair,
)
from uavmpc.drivers.summary import (
    Contact,
    Formation,
    LinkCounts,
    RunStatus,
    RunSummary,
    UavSummary,
    run_status,
)
from uavmpc.drivers.world_report import (
    FORMATION_SETTLE_S,
    GOAL_TOLERANCE_M,
    Contacts,
)
from uavmpc.drivers.world_tick import pair_distances
from uavmpc.drivers.world_view import SCENE_PERIOD_S
from uavmpc.log import FlightRecorder
from uavmpc.missions.format import mission_table
from uavmpc.missions.formation import formation_error, formation_table
from uavmpc.plant import Airframe
from uavmpc.reference import Reference
from uavmpc.scenarios import Scenario
from uavmpc.scenarios.run import RunSpec
from uavmpc.view.scene import (
    UavView,
    detail_of,
    ground_around,
    metrics_update,
    scene_update,
    state_of,
)

if TYPE_CHECKING:  # Zenoh loads only when a swarm flies
    from uavmpc.comms.zenoh_link import ZenohTransport

#: Seconds from launch to the common mission start (discovery takes ≈ 1 s; numba loads ≈ 1 s).
STARTUP_S = 4.0
#: Extra seconds with MAVLink: stream > 1 s, offboard, arm, and climb to the start.
TAKEOFF_S = 8.0
#: Extra seconds with the real PX4: its HEARTBEAT is 1 Hz (so are its mode and arming
#: reports), EKF2 must have its origin, and position-mode take-off spools up for 1 s and ramps
#: for 3 s (lift-off ≈ 3.4 s after arming) before the climb to the start.
PX4_TAKEOFF_S = 14.0
#: Longest wait for the nodes to land after the mission.
LANDING_WAIT_S = 40.0
#: Longest wait for a PX4 SITL instance to print that it is ready for take-off (≈ 4–6 s alone).
PX4_READY_TIMEOUT_S = 60.0

R = TypeVar("R", NodeStats, SitlReport)


#: Where :func:`free_ports` looks: below Linux's ephemeral range (32768–60999), which the
#: system hands out to every socket bound to port 0. A port picked from that range can be
#: given to another process between our pick and its owner's bind (a CI run failed on it:
#: "Address already in use").
_PICK_PORTS = (20000, 32767)


def free_ports(n: int) -> list[int]:
    """``n`` distinct ports free on 127.0.0.1 right now for both TCP and UDP (the nodes listen
    on TCP for Zenoh and on UDP for MAVLink), outside the system's ephemeral range."""
    rng = random.Random()
    ports: list[int] = []
    while len(ports) < n:
        port = rng.randint(*_PICK_PORTS)
        if port in ports:
            continue
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as t, \
                    socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
                t.bind(("127.0.0.1", port))
                u.bind(("127.0.0.1", port))
        except OSError:
            continue
        ports.append(port)
    return ports


def node_launch(spec: Any, settings: dict[str, Any], *, swarm: str, listen: str,
                connect: list[str],
                mission_file: Path | None, avoidance: bool, duration_s: float,
                key_file: str | None = None, mavlink: str | None = None,
                setpoints: str = "attitude", ros2: str | None = None,
                formation_file: Path | None = None,
                geo_origin: tuple[float, float, float] | None = None,
                system_id: int | None = None,
                report_file: Path | None = None) -> NodeLaunch:
    """The node process of one UAV of a scenario. ``geo_origin`` (lat [deg], lon [deg], alt
    [m AMSL] of the world's ENU origin): the autopilot's frame is placed from its
    GPS_GLOBAL_ORIGIN instead of the ground below the start (``origin_m``). ``settings``:
    the scenario's safety settings (:func:`~uavmpc.drivers.launch.node_settings`)."""
    origin = (0.0, 0.0, 0.0)
    if mavlink and geo_origin is None:
        origin = (float(spec.start_m[0]), float(spec.start_m[1]), 0.0)
    return NodeLaunch(
        uav_id=spec.uav_id, priority=spec.priority, airframe=spec.airframe, swarm=swarm,
        listen=(listen,), connect=tuple(connect),
        start_m=cast("tuple[float, float, float]", tuple(float(v) for v in spec.start_m)),
        heading_rad=float(spec.heading_rad),
        duration_s=float(duration_s),
        mission_file=None if mission_file is None else str(mission_file),
        formation_file=None if formation_file is None else str(formation_file),
        avoidance=avoidance, **settings, key_file=key_file or None, ros2=ros2 or None,
        mavlink=mavlink or None, setpoints=setpoints, origin_m=origin,
        geo_origin=(None if not mavlink or geo_origin is None
                    else cast("tuple[float, float, float]",
                              tuple(float(v) for v in geo_origin))),
        system_id=system_id if mavlink else None,
        report_file=None if report_file is None else str(report_file))


def px4_instances(scenario: Scenario, build: Px4SitlBuild, out: Path, *,
                  geo_origin: tuple[float, float, float] = DEFAULT_GEO_ORIGIN,
                  first_instance: int = 0) -> dict[str, Px4Instance]:
    """One PX4 SITL instance per UAV (not started): instance ``first_instance + i`` for the
    i-th, working in ``out/px4/<id>/``, home on the ground below its start.

    Raises:
        ConfigError: more UAVs than PX4 SITL has onboard ports for (instances 0–9)."""
    last = first_instance + len(scenario.uavs) - 1
    if first_instance < 0 or last > MAX_INSTANCE:
        raise ConfigError(
            f"--px4-sitl: {len(scenario.uavs)} UAVs from instance {first_instance} need "
            f"instances {first_instance}..{last}, but PX4 SITL gives an onboard port of its own "
            f"only to instances 0..{MAX_INSTANCE} (above, all share UDP 14549)")
    return {spec.uav_id: Px4Instance(
        build, first_instance + i, out / "px4" / spec.uav_id,
        # one point: three floats
        home=cast("tuple[float, float, float]", enu_to_geodetic(
            np.array([spec.start_m[0], spec.start_m[1], 0.0]), geo_origin)))
        for i, spec in enumerate(scenario.uavs)}


def sitl_launch(spec: Any, address: str, report_file: Path | None = None,
                truth_port: int | None = None) -> SitlLaunch:
    """The stand-in autopilot process of one UAV: on the ground below its start, sending its
    ground truth to ``truth_port`` (as PX4's SIH SITL does)."""
    return SitlLaunch(connect=address, airframe=spec.airframe,
                      position_m=(float(spec.start_m[0]), float(spec.start_m[1]), 0.0),
                      heading_rad=float(spec.heading_rad), truth_port=truth_port,
                      report_file=None if report_file is None else str(report_file))


def start_process(spec: NodeLaunch | SitlLaunch, spec_file: Path, *,
                  stderr: Any = subprocess.DEVNULL) -> subprocess.Popen[bytes]:
    """Write ``spec`` to ``spec_file`` and launch its process (:mod:`uavmpc.drivers.launch`)."""
    spec_file.write_text(spec.to_json())
    return subprocess.Popen(launch_command(spec_file), stdout=subprocess.DEVNULL,
                            stderr=stderr)


def _formation_summary(spec: Any, tracks: dict[str, list[tuple[float, np.ndarray]]],
                       epoch: float, duration_s: float, ids: list[str]) -> Formation:
    """The formation error from the states the monitor received: every member's track
    resampled at 20 Hz from FORMATION_SETTLE_S after the epoch to the end of the mission
    (no error when a member was heard less than twice)."""
    outsiders = [u for u in ids if u not in spec.members]
    grid = epoch + np.arange(FORMATION_SETTLE_S, duration_s, 0.05)
    positions = {}
    for m in spec.members:
        if len(tracks[m]) < 2:
            return Formation.of(spec, FORMATION_SETTLE_S, None, outsiders)
        t = np.array([x[0] for x in tracks[m]])
        p = np.array([x[1] for x in tracks[m]])
        order = np.argsort(t)
        positions[m] = np.column_stack([np.interp(grid, t[order], p[order, k])
                                        for k in range(3)])
    err = formation_error(dataclasses.replace(spec, changes=tuple(
        (t + epoch, shape) for t, shape in spec.changes)), grid, positions)
    err.pop("series_m")
    return Formation.of(spec, FORMATION_SETTLE_S, err, outsiders)


class LiveSink(Protocol):
    """Where a swarm's scene goes while it flies (:class:`uavmpc.view.live.LiveView`)."""

    def publish(self, t_s: float, scene: dict[str, Any], metrics: dict[str, Any]) -> None: ...


def _scene(t_s: float, states: dict[str, NodeState],
           plans: dict[str, tuple[float, np.ndarray]], now: float, prm: AvoidanceParams,
           ground: dict[str, Any], min_distance_m: float | None
           ) -> tuple[dict[str, Any], dict[str, Any]]:
    """The scene and the metrics as the monitor hears the nodes: each UAV at its last state,
    its last plan heard (the desired path drawn as that plan without the offset: nodes do not
    send it), silent when no plan came within ``prm.timeout_s``."""
    views = []
    for uav, s in states.items():
        heard, plan = plans.get(uav, (-math.inf, np.zeros((0, 3))))
        z_off = s.z_offset_m
        views.append(UavView(
            uav, np.array(s.position_m), s.heading_rad, plan,
            plan - np.array([0.0, 0.0, z_off]), z_off,
            state_of(silent=now - heard > prm.timeout_s, waiting_for=list(s.waiting_for),
                     yielding_to=list(s.yielding_to), z_offset_m=z_off, avoiding=s.avoiding),
            prm.radius_m, prm.height_m,
            detail_of(yielding_to=list(s.yielding_to), waiting_for=list(s.waiting_for))))
    rows = {v.uav_id: {"z_offset_m": v.z_offset_m, "avoiding": states[v.uav_id].avoiding}
            for v in views}
    return (scene_update(t_s, views, ground=ground),
            metrics_update(t_s, min_distance_m, views, rows))


def _end(p: subprocess.Popen[bytes]) -> None:
    """Wait for a child asked to stop (asked twice, then killed if it does not within 15 s)."""
    try:
        p.wait(timeout=5)
    except subprocess.TimeoutExpired:  # still landing: a second request ends it at once
        p.send_signal(signal.SIGINT)
        try:
            p.wait(timeout=15)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def _report_of(p: subprocess.Popen[bytes], report_file: Path, cls: type[R],
               log: Path | None = None) -> tuple[R | None, dict[str, Any]]:
    """The report a child process wrote when it ended (a :class:`NodeStats` or a
    :class:`SitlReport`, checked field by field) and it as a dictionary; if it wrote none,
    or one that does not hold, (None, its exit code and the end of its error output
    (``log``), which say why)."""
    _end(p)
    why: dict[str, Any] = {"exit_code": p.returncode}
    try:
        report = read_report(report_file, cls)
        return report, dataclasses.asdict(report)
    except FileNotFoundError:
        pass
    except LaunchError as exc:
        why["bad_report"] = str(exc)
    if log is not None and log.exists():
        why["stderr_tail"] = log.read_text(errors="replace").splitlines()[-20:]
    return None, why


def _truth_ports(scenario: Scenario, first_instance: int, real_px4: bool,
                 mavlink: bool) -> dict[str, int]:
    """Per UAV, the UDP port its vehicle's ground truth arrives on: PX4 SIH SITL's own
    (19410 + instance), a free one for each stand-in; none for simulated-plant nodes."""
    ids = [u.uav_id for u in scenario.uavs]
    if real_px4:
        return {u: TRUTH_PORT_BASE + first_instance + i for i, u in enumerate(ids)}
    if mavlink:
        return dict(zip(ids, free_ports(len(ids)), strict=True))
    return {}


def swarm_flyable(spec: RunSpec, mavlink: bool, px4_sitl: Px4SitlBuild | None) -> None:
    """Refuse what node processes cannot fly (a :class:`ConfigError` naming it), and the two
    kinds of vehicle at once."""
    scenario = spec.scenario
    simulated = [name for name, asked in (
        ("a link's latency and loss", spec.link is not None),
        ("faults", bool(spec.faults.active())), ("wind", bool(spec.wind_mps)),
        ("a launch check", spec.launch_check_s is not None)) if asked]
    if simulated:
        raise ConfigError(f"{scenario.name}: {', '.join(simulated)} are the simulated world's; "
                          "node processes fly over the real network (fly it with: uavmpc run "
                          f"{scenario.name})")
    node_settings(scenario)  # what a node process cannot honour is refused by name
    if mavlink and px4_sitl is not None:
        raise ConfigError("--px4-sitl and --mavlink are exclusive: --px4-sitl flies real PX4 "
                          "instances, --mavlink the stand-ins")


def _stop_px4s(px4s: dict[str, Px4Instance]) -> None:
    """Stop every real PX4 instance, each with its process group (harmless if not started)."""
    for inst in px4s.values():
        inst.stop()


def _start_px4s(scenario: Scenario, build: Px4SitlBuild, out: Path,
                geo_origin: tuple[float, float, float],
                first_instance: int) -> dict[str, Px4Instance]:
    """Start one real PX4 SITL instance per UAV; if one fails, none is left running."""
    px4s = px4_instances(scenario, build, out, geo_origin=geo_origin,
                         first_instance=first_instance)
    try:
        for inst in px4s.values():
            inst.start()
    except BaseException:
        _stop_px4s(px4s)
        raise
    return px4s


def _warm_up(scenario: Scenario, px4s: dict[str, Px4Instance]) -> None:
    """Load every airframe's kernels and wait for every PX4 to be ready for take-off."""
    # Compile the kernels once here, into the cache every node loads them from, before the
    # clock of the mission starts.
    for name in sorted({u.airframe for u in scenario.uavs}):
        warm_up(Airframe.named(name))
    for inst in px4s.values():
        inst.wait_ready(PX4_READY_TIMEOUT_S)


@dataclasses.dataclass(frozen=True)
class _Options:
    """The options of one :func:`run_swarm`, resolved, as its processes and summary need them."""

    avoidance: bool
    duration: float
    epoch: float
    key_file: str | None
    mavlink: bool
    real_px4: bool
    setpoints: str
    ros2: str | None
    geo_origin: tuple[float, float, float]


@dataclasses.dataclass
class _Ended:
    """What the swarm's processes reported when they ended."""

    nodes: dict[str, tuple[NodeStats | None, dict[str, Any]]]
    sitls: dict[str, dict[str, Any]]


@dataclasses.dataclass
class _Fleet:
    """The swarm's child processes (nodes, stand-in PX4s, real PX4s) and where they write."""

    work: Path  # each process's launch specification and report
    logs: dict[str, Path]  # each node's error output
    px4s: dict[str, Px4Instance]
    nodes: dict[str, subprocess.Popen[bytes]] = dataclasses.field(default_factory=dict)
    sitls: dict[str, subprocess.Popen[bytes]] = dataclasses.field(default_factory=dict)

    def start_standin(self, spec: Any, port: int, truth_port: int | None) -> str:
        """Start the stand-in PX4 of ``spec`` on UDP ``port`` (its truth to ``truth_port``);
        its address for the node."""
        self.sitls[spec.uav_id] = start_process(
            sitl_launch(spec, f"udpout://127.0.0.1:{port}",
                        self.work / f"{spec.uav_id}.sitl.report.json", truth_port),
            self.work / f"{spec.uav_id}.sitl.json")
        return f"udp://127.0.0.1:{port}"

    def start_node(self, launch: NodeLaunch) -> None:
        """Start the node process of ``launch``, its error output in its log."""
        with open(self.logs[launch.uav_id], "w") as err:  # the child keeps its own copy
            self.nodes[launch.uav_id] = start_process(
                launch, self.work / f"{launch.uav_id}.node.json", stderr=err)

    def stop(self) -> _Ended:
        """Stop every process (the nodes, then the stand-ins, then the real PX4s) and gather
        their reports; whatever interrupts this, nothing is left running."""
        try:
            for p in self.nodes.values():
                if p.poll() is None:
                    p.send_signal(signal.SIGINT)
            ended = {uav: _report_of(p, self.work / f"{uav}.node.report.json", NodeStats,
                                     self.logs[uav])
                     for uav, p in self.nodes.items()}
            for p in self.sitls.values():  # the stand-ins end after their nodes
                if p.poll() is None:
                    p.send_signal(signal.SIGINT)
            sitl_reports = {uav: _report_of(p, self.work / f"{uav}.sitl.report.json",
                                            SitlReport)[1]
                            for uav, p in self.sitls.items()}
        finally:
            for p in [*self.nodes.values(), *self.sitls.values()]:
                if p.poll() is None:  # only when interrupted while waiting for them
                    p.kill()
                    p.wait()
            _stop_px4s(self.px4s)  # the real PX4s too, each with its process group
        return _Ended(ended, sitl_reports)


def _mission_file(spec: Any, work: Path, epoch: float, follower: bool) -> Path | None:
    """Write the mission of ``spec`` on the wall clock of ``epoch``; None for a follower."""
    if follower:  # a follower's trajectory comes from its slot only
        return None
    mission = work / f"{spec.uav_id}.json"
    on_wall_clock = Reference(spec.mission.times_s + epoch, spec.mission.points,
                              spec.mission.loop)
    mission.write_text(json.dumps(mission_table(on_wall_clock)))
    return mission


def _formation_file(scenario: Scenario, work: Path, epoch: float) -> Path | None:
    """Write the formation's table (its shape changes on the wall clock of the epoch)."""
    if scenario.formation is None:
        return None
    path = work / "formation.json"
    path.write_text(json.dumps(formation_table(scenario.formation, epoch)))
    return path


def _start_fleet(fleet: _Fleet, scenario: Scenario, opts: _Options, *, swarm: str,
                 endpoints: list[str], mav_ports: list[int],
                 truth_ports: dict[str, int]) -> None:
    """Start every UAV's node, each after its stand-in PX4 when it flies one."""
    formation = scenario.formation
    formation_file = _formation_file(scenario, fleet.work, opts.epoch)
    settings = node_settings(scenario)
    for i, spec in enumerate(scenario.uavs):
        follower = formation is not None and spec.uav_id in formation.followers
        mission = _mission_file(spec, fleet.work, opts.epoch, follower)
        address = None
        if opts.real_px4:
            address = fleet.px4s[spec.uav_id].mavlink_address
        elif opts.mavlink:
            address = fleet.start_standin(spec, mav_ports[i], truth_ports.get(spec.uav_id))
        member = formation is not None and spec.uav_id in formation.members
        fleet.start_node(node_launch(
            spec, settings, swarm=swarm, listen=endpoints[i],
            connect=[endpoints[-1]] + ([endpoints[0]] if i else []), mission_file=mission,
            avoidance=opts.avoidance and spec.avoidance,
            duration_s=opts.duration + (opts.epoch - time.time()) + 1.0,
            key_file=opts.key_file, mavlink=address, setpoints=opts.setpoints,
            ros2=opts.ros2, formation_file=formation_file if member else None,
            geo_origin=opts.geo_origin if opts.real_px4 else None,
            system_id=(fleet.px4s[spec.uav_id].system_id if opts.real_px4 else None),
            report_file=fleet.work / f"{spec.uav_id}.node.report.json"))


class _Monitor:
    """What the monitor hears from the nodes and measures: every state and plan recorded,
    collisions and each pair's closest approach, the scene for the live view.

    Separation is judged by the truth where a simulator gives it (``truth``: a listener per
    UAV for its vehicle's ground truth, :mod:`uavmpc.drivers.px4.truth`); the same figures
    from the nodes' estimates are kept beside it. A simulated-plant node's state is its
    plant's truth. A vehicle whose node was killed is still followed by its truth."""

    def __init__(self, transport: ZenohTransport, scenario: Scenario, epoch: float,
                 auth_key: bytes | None, kill_at_s: dict[str, float] | None,
                 live: LiveSink | None, truth: dict[str, TruthListener] | None = None) -> None:
        """Subscribe to every state and prediction on ``transport``."""
        self.states = transport.subscribe("*/state", maxlen=100_000)
        self.predictions = transport.subscribe("*/prediction", maxlen=10_000)
        self.ids = [u.uav_id for u in scenario.uavs]
        self.epoch = epoch
        self.auth_key = auth_key
        self.kills = dict(kill_at_s or {})
        self.killed: dict[str, float] = {}  # id → when its node was killed [s, Unix]
        self.live = live
        self.truth_in = dict(truth or {})
        self.latest: dict[str, np.ndarray] = {}  # each node's estimate, as it said last
        self.truth: dict[str, np.ndarray] = {}  # each vehicle's truth, last sample
        self.last_state: dict[str, NodeState] = {}
        self.first_heard: dict[str, float] = {}  # each node's first state [s, Unix]
        self.states_refused = 0  # malformed state messages (not drawn, not judged)
        self.at_end: dict[str, np.ndarray] = {}
        self.truth_at_end: dict[str, np.ndarray] = {}
        self.offsets: dict[str, float] = dict.fromkeys(self.ids, 0.0)
        #: Each UAV's highest altitude from the epoch on [m]: by its truth where a simulator
        #: gives it, else its state.
        self.top: dict[str, float] = {}
        #: The contacts judged (by the truth where a simulator gives it) and by the
        #: estimates, watched as the world watches its own (times from the epoch).
        self.contacts = Contacts(self.ids)
        self.contacts_est = Contacts(self.ids)
        self.closest: dict[tuple[str, str], float] = {}  # each pair's closest approach [m]
        self.closest_est: dict[tuple[str, str], float] = {}  # ... by the estimates [m]
        self._pair_ids = list(itertools.combinations(self.ids, 2))  # triu_indices' order
        self._pair_d = np.empty(len(self._pair_ids))
        self.min_d = math.inf
        self.min_d_est = math.inf
        self.window: list[float] = []  # first and last time judged [s, Unix]
        self.trace_t: list[float] = []
        self.trace_d: list[float] = []
        self.tracks: dict[str, list[tuple[float, np.ndarray]]] = {u: [] for u in self.ids}
        self.truth_tracks: dict[str, list[tuple[float, np.ndarray]]] = {
            u: [] for u in self.truth_in}
        self.plans: dict[str, tuple[float, np.ndarray]] = {}  # id → (wall time heard, plan)
        self.prm = scenario.avoidance
        self.ground = ground_around(scenario.points_m())
        self.next_scene = -math.inf

    @property
    def by_truth(self) -> bool:
        """Separation is judged by a simulator's truth of every vehicle (else: the nodes'
        states, which are their plants' truth)."""
        return bool(self.truth_in)

    def watch(self, rec: FlightRecorder, nodes: dict[str, subprocess.Popen[bytes]],
              end: float, landing_end: float) -> None:
        """Watch until ``end``, then while a node still runs (landing) until ``landing_end``."""
        while time.time() < end or (
                time.time() < landing_end and any(p.poll() is None for p in nodes.values())):
            if time.time() >= end and not self.at_end:
                self.at_end.update({u: p.copy() for u, p in self.latest.items()})
                self.truth_at_end.update({u: p.copy() for u, p in self.truth.items()})
            self.hear_states(rec)
            self.hear_truth(rec)
            self.hear_predictions(rec)
            now = time.time()
            self.kill_due(nodes, now)
            self.measure(nodes, now)
            if now >= self.next_scene:
                self.show(rec, now)
            time.sleep(0.005)

    def hear_states(self, rec: FlightRecorder) -> None:
        """Record every state received since the last call (malformed ones are counted and
        skipped)."""
        for topic, payload in self.states.drain():
            uav = topic.split("/")[-2]
            try:
                s = NodeState.decode(payload)
            except InvalidStateError:
                self.states_refused += 1
                continue
            if uav not in self.offsets:
                self.states_refused += 1
                continue
            p = np.array(s.position_m)
            self.latest[uav] = p
            self.last_state[uav] = s
            self.first_heard.setdefault(uav, s.t_s)
            self.tracks[uav].append((s.t_s, p))
            self.offsets[uav] = max(self.offsets[uav], s.z_offset_m)
            if not self.by_truth and s.t_s >= self.epoch:
                self.top[uav] = max(self.top.get(uav, -math.inf), float(p[2]))
            rec.pose(uav, "state", s.t_s, p, s.heading_rad)
            rec.pose(uav, "command", s.t_s, np.array(s.command_m), 0.0)
            rec.status(uav, s.t_s, z_offset_m=s.z_offset_m, avoiding=s.avoiding,
                       conflicts=list(s.conflicts), yielding_to=list(s.yielding_to),
                       broken=list(s.broken))

    def hear_truth(self, rec: FlightRecorder) -> None:
        """Record every ground-truth sample received since the last call."""
        for uav, listener in self.truth_in.items():
            for sample in listener.poll():
                self.truth[uav] = sample.position_m
                self.truth_tracks[uav].append((sample.t_s, sample.position_m))
                if sample.t_s >= self.epoch:
                    self.top[uav] = max(self.top.get(uav, -math.inf),
                                        float(sample.position_m[2]))
                rec.pose(uav, "truth", sample.t_s, sample.position_m, 0.0)

    def hear_predictions(self, rec: FlightRecorder) -> None:
        """Record every plan received since the last call (unverifiable ones are skipped)."""
        for _key, payload in self.predictions.drain():
            try:
                msg = decode(verify(payload, self.auth_key) if self.auth_key is not None
                             else payload)
            except InvalidMessageError:
                continue
            rec.prediction(msg.uav_id, msg.stamp_s, msg.positions_m,
                           np.zeros(msg.positions_m.shape[0]))
            self.plans[msg.uav_id] = (time.time(), msg.positions_m)

    def kill_due(self, nodes: dict[str, subprocess.Popen[bytes]], now: float) -> None:
        """SIGKILL every node whose time in ``kill_at_s`` has come. A simulated plant dies
        with its node (no longer watched); a vehicle with an autopilot flies on, followed by
        its truth."""
        for uav, t_kill in list(self.kills.items()):
            if now >= self.epoch + t_kill:
                nodes[uav].kill()
                self.killed[uav] = now
                self.latest.pop(uav, None)
                del self.kills[uav]

    def _pairs(self, where: dict[str, np.ndarray], closest: dict[tuple[str, str], float],
               contacts: Contacts, now: float) -> float:
        """Every pair's distance at ``where`` (a vehicle not there: no distance): closest
        approaches and contacts; returns the smallest."""
        nowhere = np.full(3, np.nan)
        pos = np.array([where.get(u, nowhere) for u in self.ids], dtype=float)
        pair_d = self._pair_d
        pair_distances(pos, pair_d)
        for pair, d in zip(self._pair_ids, pair_d.tolist(), strict=True):
            if not math.isnan(d):
                closest[pair] = min(closest.get(pair, math.inf), d)
        contacts.update_pairs(now - self.epoch, pair_d)
        seen = pair_d[~np.isnan(pair_d)]
        return float(seen.min()) if seen.size else math.inf

    def measure(self, nodes: dict[str, subprocess.Popen[bytes]], now: float) -> None:
        """Pairwise distances once every vehicle has been heard: collisions and closest
        approaches by the truth (where a simulator gives it), and by the estimates beside."""
        if now < self.epoch:
            return
        if self.by_truth:  # every vehicle, its node alive or not, once its truth came
            if not all(u in self.truth for u in self.ids):
                return
        else:  # a simulated plant dies with its node
            alive = [u for u in self.ids if nodes[u].poll() is None or u in self.latest]
            if not (all(u in self.latest for u in alive) and len(alive) > 1):
                return
        self._pairs(self.latest, self.closest_est, self.contacts_est, now)
        self.min_d_est = min(self.min_d_est, min(
            (self.closest_est[p] for p in self.closest_est), default=math.inf))
        judged = self.truth if self.by_truth else self.latest
        d_now = self._pairs(judged, self.closest, self.contacts, now)
        self.min_d = min(self.min_d, d_now)
        self.window = [self.window[0] if self.window else now, now]
        self.trace_t.append(now - self.epoch)
        self.trace_d.append(d_now)

    def closest_by_truth(self) -> dict[tuple[str, str], float]:
        """Each pair's closest approach by the truth tracks, resampled on one 20 ms grid over
        the window judged (:func:`~uavmpc.drivers.px4.truth.closest_by_pair`, the law the
        flight logs are read by): between two 25 Hz samples of two vehicles closing fast the
        last samples heard miss the closest point by up to a couple of decimetres."""
        if not self.window:
            return {}
        tracks = {}
        for uav in self.ids:
            t = np.array([x[0] for x in self.truth_tracks[uav]])
            keep = np.r_[True, np.diff(t) > 0.0] if t.size else np.zeros(0, bool)
            if keep.sum() < 2:
                return {}
            tracks[uav] = Track(t[keep], np.array([x[1] for x in self.truth_tracks[uav]])[keep])
        return closest_by_pair(tracks, self.window[0], self.window[1])

    def estimator_errors(self, until_s: float) -> dict[str, dict[str, float]]:
        """Per UAV with a truth, its estimate against it from the epoch to ``until_s`` [s,
        Unix] (before the landing: after touchdown SIH's ground lets a vehicle sink):
        horizontal RMS, mean and largest vertical error (estimate − truth) [m]."""
        out: dict[str, dict[str, float]] = {}
        for uav, track in self.truth_tracks.items():
            est = [(t, p) for t, p in self.tracks[uav] if self.epoch <= t <= until_s]
            if len(track) < 2 or not est:
                continue
            tt = np.array([t for t, _ in track])
            tp = np.array([p for _, p in track])
            te = np.array([t for t, _ in est])
            pe = np.array([p for _, p in est])
            inside = (te >= tt[0]) & (te <= tt[-1])
            if not inside.any():
                continue
            te, pe = te[inside], pe[inside]
            truth = np.column_stack([np.interp(te, tt, tp[:, k]) for k in range(3)])
            err = pe - truth
            out[uav] = {"horizontal_rms_m": round(float(np.sqrt(np.mean(
                            np.sum(err[:, :2] ** 2, axis=1)))), 3),
                        "vertical_mean_m": round(float(np.mean(err[:, 2])), 3),
                        "vertical_max_m": round(float(np.max(np.abs(err[:, 2]))), 3),
                        "samples": int(te.size)}
        return out

    def show(self, rec: FlightRecorder, now: float) -> None:
        """Record the scene and the metrics, and send them to the live view."""
        self.next_scene = now + SCENE_PERIOD_S
        t_rel = max(0.0, now - self.epoch)
        d_last = (self.trace_d[-1] if self.trace_d and self.trace_t[-1] == now - self.epoch
                  else None)
        scene, metrics = _scene(t_rel, self.last_state, self.plans, now, self.prm,
                                self.ground, d_last)
        rec.scene(t_rel, scene)
        rec.metrics(t_rel, metrics)
        if self.live is not None:
            self.live.publish(t_rel, scene, metrics)


def _uav_summary(uav: str, goal: np.ndarray, follower: bool, monitor: _Monitor,
                 ended: _Ended, px4_reports: dict[str, dict[str, Any]],
                 opts: _Options, errors: dict[str, dict[str, float]]) -> UavSummary:
    """One UAV's entry of the summary, from its node's report and what the monitor heard."""
    st = ended.nodes[uav][0] if uav in ended.nodes else None
    final = np.array((st.final_position_m if st is not None else None)
                     or monitor.latest.get(uav, [np.nan] * 3))
    estimated = monitor.at_end.get(uav, final) if opts.mavlink else final
    # The goal is judged where the vehicle truly was when the mission ended, where known.
    judged = monitor.truth_at_end.get(uav, estimated) if monitor.by_truth else estimated
    details: dict[str, Any] = {
        "mission_end_position_m": (np.asarray(judged).tolist()
                                   if np.isfinite(judged).all() else None),
        "last_state": (dataclasses.asdict(monitor.last_state[uav])
                       if uav in monitor.last_state else {}),
        "node": ended.nodes[uav][1] if uav in ended.nodes else {},
        # from the mission's start (positive: the node's first seconds went unwatched)
        "first_heard_s": (round(monitor.first_heard[uav] - monitor.epoch, 3)
                          if uav in monitor.first_heard else None),
    }
    if monitor.by_truth:
        details["mission_end_estimate_m"] = (np.asarray(estimated).tolist()
                                             if np.isfinite(estimated).all() else None)
        details["estimator_error"] = errors.get(uav)
        if uav in monitor.truth:
            details["last_truth_m"] = monitor.truth[uav].round(3).tolist()
    if uav in monitor.top:
        details["max_altitude_m"] = round(monitor.top[uav], 3)
    if uav in monitor.killed:
        details["node_killed_at_s"] = round(monitor.killed[uav] - monitor.epoch, 3)
    if opts.real_px4:
        details["px4"] = px4_reports.get(uav, {})
    elif opts.mavlink:
        details["sitl"] = ended.sitls.get(uav, {})
    return UavSummary(
        # the node's own report covers its whole flight, the monitor only what it heard
        max_z_offset_m=max(monitor.offsets[uav], st.max_z_offset_m if st is not None else 0.0),
        avoidance_active_s=st.avoidance_active_s if st is not None else None,
        tracking_rmse_m=st.tracking_rmse_m if st is not None else None,
        reached_goal=(None if follower
                      else bool(np.linalg.norm(judged - goal) < GOAL_TOLERANCE_M)),
        final_position_m=((float(final[0]), float(final[1]), float(final[2]))
                          if np.isfinite(final).all() else None),
        details=details)


def _stopped(ended: _Ended) -> list[str]:
    """The UAVs whose node ended without a report (killed, or failed) or whose vehicle
    stopped being its to fly before the landing."""
    return [uav for uav, (st, _) in ended.nodes.items()
            if st is None or st.run_status is RunStatus.VEHICLE_STOPPED]


def _summary(scenario: Scenario, opts: _Options, monitor: _Monitor, ended: _Ended,
             px4_sitl: Px4SitlBuild | None,
             px4_reports: dict[str, dict[str, Any]]) -> RunSummary:
    """The run's summary (``summary.json``), the same schema as ``uavmpc run`` writes."""
    stats = [st for st, _ in ended.nodes.values() if st is not None]
    sent = sum(st.predictions_sent for st in stats) * (len(scenario.uavs) - 1)
    delivered = sum(st.accepted for st in stats)
    formation = scenario.formation
    errors = monitor.estimator_errors(opts.epoch + opts.duration)
    resampled = monitor.closest_by_truth() if monitor.by_truth else {}
    if resampled:  # the truth tracks on one grid, not the last samples as they came
        monitor.closest = resampled
        monitor.min_d = min(resampled.values())
    uavs = {u.uav_id: _uav_summary(
        u.uav_id, np.array(u.goal_m),
        formation is not None and u.uav_id in formation.followers,
        monitor, ended, px4_reports, opts, errors) for u in scenario.uavs}
    contacts = tuple(Contact(c.t, c.a, c.b, c.distance_m)
                     for c in monitor.contacts.collisions)
    sections: dict[str, Any] = {
        "transport": "zenoh (peer to peer, 127.0.0.1)",
        "vehicles": (f"real PX4 SITL firmware with SIH over MAVLink/UDP, {opts.setpoints} "
                     "setpoints" if opts.real_px4 else
                     f"PX4 stand-ins over MAVLink/UDP, {opts.setpoints} setpoints"
                     if opts.mavlink else "simulated plants in the nodes"),
        "judged_by": (f"the simulator's ground truth (HIL_STATE_QUATERNION, "
                      f"{TRUTH_RATE_HZ:g} Hz)" if monitor.by_truth
                      else "the nodes' states (each its own plant's truth)"),
        "closest_by_pair_m": {f"{a}-{b}": round(d, 3)
                              for (a, b), d in sorted(monitor.closest.items())},
    }
    if monitor.by_truth:  # the same figures as the autopilots' estimates tell them
        sections["estimate"] = {
            "min_distance_m": (round(monitor.min_d_est, 3) if math.isfinite(monitor.min_d_est)
                               else None),
            "collisions": len(monitor.contacts_est.collisions),
            "closest_by_pair_m": {f"{a}-{b}": round(d, 3)
                                  for (a, b), d in sorted(monitor.closest_est.items())}}
        sections["truth"] = {"window_unix_s": [round(t, 3) for t in monitor.window]}
    if monitor.killed:
        sections["killed"] = {u: round(t - monitor.epoch, 3) for u, t in monitor.killed.items()}
    if px4_sitl is not None:
        sections["px4_sitl"] = {"build": str(px4_sitl.root),
                                "geo_origin": list(opts.geo_origin)}
    return RunSummary(
        driver="swarm",
        # A node the swarm stopped at the end says "interrupted": that is the swarm's way of
        # ending it, not the run's; only a stopped vehicle counts.
        status=run_status(collisions=len(contacts),
                          reached_goal=[u.reached_goal for u in uavs.values()],
                          stopped=_stopped(ended)),
        scenario=scenario.name, seed=None, avoidance=opts.avoidance,
        duration_s=opts.duration, collisions=contacts,
        min_distance_m=monitor.min_d if math.isfinite(monitor.min_d) else None,
        uavs=uavs, messages=LinkCounts(sent, delivered, max(sent - delivered, 0)),
        formation=(None if formation is None else _formation_summary(
            formation, monitor.tracks, opts.epoch, opts.duration, monitor.ids)),
        sections=sections)


def _vehicle_kind(real_px4: bool, mavlink: bool) -> str:
    """What the nodes fly, as the flight log's metadata says it."""
    if real_px4:
        return "PX4 SITL (SIH) over MAVLink"
    return "PX4 stand-in over MAVLink" if mavlink else "simulated plant"


def run_swarm(spec: RunSpec, out: Path, *, key_file: str | None = None,
              kill_at_s: dict[str, float] | None = None,
              on_trace: Callable[[list[float], list[float]], None] | None = None,
              mavlink: bool = False, setpoints: str = "attitude",
              ros2: str | None = None, live: LiveSink | None = None,
              px4_sitl: Px4SitlBuild | None = None,
              geo_origin: tuple[float, float, float] = DEFAULT_GEO_ORIGIN,
              px4_first_instance: int = 0) -> RunSummary:
    """Fly ``spec`` (its scenario, with or without avoidance, for its duration) as separate
    node processes; returns its summary (also written to ``out/summary.json``). The nodes talk
    over the real network: a spec that asks for the simulated world's link, faults, wind or
    launch check is refused (:func:`swarm_flyable`).

    ``kill_at_s``: UAV id → seconds after the mission start at which its node is SIGKILLed
    (a UAV that drops out of the sky, as far as the link can tell). ``on_trace(t_s, d_m)``
    gets the closest pairwise distance over time at the end (the CLI draws it). ``mavlink``:
    every node flies its own stand-in PX4 over MAVLink/UDP (``setpoints``: the message it
    sends); goals are judged where the UAVs are when the mission ends, before they land.
    ``ros2``: a Zenoh router; every node also appears on the ROS 2 graph through it. Each
    node's error output goes to ``out/<id>.node.log``. ``live``: gets the 3-D scene and the
    metrics every :data:`~uavmpc.drivers.world.SCENE_PERIOD_S` of the wall clock (e.g.
    :class:`uavmpc.view.live.LiveView`). ``px4_sitl``: every node flies a real PX4 SITL
    instance of that build instead of a stand-in (the module's docstring; ``geo_origin``: the
    ENU origin on the globe, ``px4_first_instance``: the first instance number)."""
    from uavmpc.comms.zenoh_link import ZenohTransport

    swarm_flyable(spec, mavlink, px4_sitl)
    scenario, avoidance, duration = spec.scenario, spec.avoidance, spec.flight_s
    real_px4 = px4_sitl is not None
    mavlink = mavlink or real_px4  # the nodes fly over MAVLink either way
    auth_key = load_key(key_file) if key_file else None
    out.mkdir(parents=True, exist_ok=True)
    swarm = f"s{os.getpid()}"
    n = len(scenario.uavs)
    ports = free_ports(n + 1)
    mav_ports = free_ports(n) if mavlink and not real_px4 else []
    endpoints = [f"tcp/127.0.0.1:{p}" for p in ports]
    ids = [u.uav_id for u in scenario.uavs]
    truth_ports = _truth_ports(scenario, px4_first_instance, real_px4, mavlink)
    truth: dict[str, TruthListener] = {}
    with tempfile.TemporaryDirectory(prefix="uavmpc-swarm-") as tmp:
        fleet = _Fleet(Path(tmp), {u: out / f"{u}.node.log" for u in ids}, {})
        transport: ZenohTransport | None = None
        try:
            if px4_sitl is not None:  # they boot while the kernels load
                fleet.px4s = _start_px4s(scenario, px4_sitl, out, geo_origin,
                                         px4_first_instance)
            # After the instances are checked and started: their truth starts with them.
            truth = {u: TruthListener(port, geo_origin if real_px4 else PX4_SITL_HOME)
                     for u, port in truth_ports.items()}
            _warm_up(scenario, fleet.px4s)
            takeoff = PX4_TAKEOFF_S if real_px4 else TAKEOFF_S if mavlink else 0.0
            opts = _Options(avoidance=avoidance, duration=duration,
                            epoch=time.time() + STARTUP_S + takeoff, key_file=key_file,
                            mavlink=mavlink, real_px4=real_px4, setpoints=setpoints,
                            ros2=ros2, geo_origin=geo_origin)
            transport = ZenohTransport("monitor", swarm=swarm, listen=[endpoints[n]],
                                       max_pending=4096)
            monitor = _Monitor(transport, scenario, opts.epoch, auth_key, kill_at_s, live,
                               truth)
            _start_fleet(fleet, scenario, opts, swarm=swarm, endpoints=endpoints,
                         mav_ports=mav_ports, truth_ports=truth_ports)
            meta = {"scenario": scenario.name, "avoidance": avoidance, "transport": "zenoh",
                    "vehicle": _vehicle_kind(real_px4, mavlink)}
            with FlightRecorder(out / "flight.mcap", ids, meta) as rec:
                end = opts.epoch + opts.duration
                monitor.watch(rec, fleet.nodes, end,
                              end + (LANDING_WAIT_S if mavlink else 0.0))
        finally:
            ended = fleet.stop()
            if transport is not None:
                transport.close()
            for listener in truth.values():
                listener.close()
    px4_reports = {uav: inst.report() for uav, inst in fleet.px4s.items()}
    summary = _summary(scenario, opts, monitor, ended, px4_sitl, px4_reports)
    summary.write(out / "summary.json")
    if monitor.trace_t and on_trace is not None:
        on_trace(monitor.trace_t, monitor.trace_d)
    return summary
