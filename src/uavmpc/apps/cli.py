"""Command line: ``uavmpc --help`` lists the commands."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Callable

    from matplotlib.figure import Figure

    from uavmpc.apps.falsify import Outcome
    from uavmpc.comms.auth import Identity, Roster
    from uavmpc.drivers.px4.firmware import Px4SitlBuild
    from uavmpc.drivers.summary import Formation, Landing, RunSummary
    from uavmpc.drivers.world import World
    from uavmpc.drivers.world_report import WorldResult
    from uavmpc.jit import CompileWatch
    from uavmpc.scenarios import Scenario
    from uavmpc.scenarios.faults import FaultSpec
    from uavmpc.scenarios.run import RunSpec

    #: What the sub-commands' parsers are added to.
    Subparsers = argparse._SubParsersAction[argparse.ArgumentParser]

#: ``uavmpc run`` writes a flight log for worlds of at most this many UAVs.
MAX_LOGGED_UAVS = 50


def _load_run_scenario(scenario: str, *, seed: int, duration: float | None,
                       uavs: int | None,
                       cruise_heights: tuple[float, ...] | None) -> Scenario:
    """The scenario to fly: a :class:`~uavmpc.scenarios.traffic.TrafficScenario` for the
    generated traffic."""
    from uavmpc import scenarios

    if scenario == "traffic":  # generated, not a file: built from --uavs and --seed
        from uavmpc.scenarios import traffic as traffic_mod

        return traffic_mod.traffic(traffic_mod.DEFAULT_UAVS if uavs is None else uavs, seed,
                                   duration_s=duration,
                                   cruise_heights_m=cruise_heights or
                                   traffic_mod.DEFAULT_CRUISE_HEIGHTS_M)
    return scenarios.load(scenario)


def _run_spec(sc: Scenario, *, avoidance: bool, seed: int, duration: float | None,
              loss: float | None, latency: float | None, wind: float,
              faults: FaultSpec | None, launch_check: float | None) -> RunSpec:
    """The flight ``uavmpc run`` asks for: ``sc`` with the flags' link, faults and the rest."""
    import dataclasses

    from uavmpc.scenarios.faults import FaultSpec
    from uavmpc.scenarios.run import RunSpec

    link = sc.link
    if loss is not None:
        link = dataclasses.replace(link, loss=loss)
    if latency is not None:
        link = dataclasses.replace(link, latency_s=latency)
    return RunSpec(sc, avoidance=avoidance, seed=seed, link=link,
                   faults=FaultSpec() if faults is None else faults, wind_mps=wind,
                   launch_check_s=launch_check, duration_s=duration)


def _fly_world(world: World, sc: Scenario, *, duration: float | None, ros2: str | None,
               realtime: float | None, live_port: int | None) -> WorldResult:
    """Fly ``world``, mirrored on ROS 2 and served to a live view if asked; its result."""
    import contextlib

    with contextlib.ExitStack() as around:
        mirror = live = None
        if ros2 is not None:
            from uavmpc.drivers.ros2 import WorldOnRos2, open_graph

            graph = around.enter_context(open_graph(ros2, "uavmpc_world"))
            mirror = WorldOnRos2(graph, [u.uav_id for u in sc.uavs])
        if live_port is not None:
            from uavmpc.view.live import LiveView

            live = around.enter_context(LiveView(port=live_port))
            print(f"live view on {live.url} (Foxglove: Open connection)", flush=True)
        if (mirror is not None or live is not None) and realtime is None:
            realtime = 1.0  # watched: at the pace of the wall clock
        return world.run(duration, realtime=realtime, on_log=mirror,
                         on_scene=live.publish if live is not None else None)


#: Every file a run may write into its folder (its figures, whichever it draws, among them).
RUN_OUTPUTS = ("summary.json", "flight.mcap", "top_view.png", "altitude.png", "traffic.png",
               "min_distance.png", "side_view.png", "view_3d.png", "landing.png",
               "formation.png")


def _save_run_figures(result: WorldResult, sc: Scenario, summary: RunSummary, out: Path, *,
                      avoidance: bool) -> list[str]:
    """Draw a run's figures into ``out``; their file names."""
    from uavmpc.apps.plots import close_figure, plot_side_and_3d, plot_world
    from uavmpc.drivers.world import COLLISION_DISTANCE_M
    from uavmpc.scenarios.traffic import TrafficScenario

    title = f"{sc.name} ({'with' if avoidance else 'without'} avoidance)"
    figs: tuple[Figure, ...]
    if isinstance(sc, TrafficScenario):  # hundreds of paths: no per-UAV legend, decimated
        from uavmpc.apps.plots import plot_min_distance_trace, plot_traffic

        figs = (*plot_traffic(result, sc, title),
                plot_min_distance_trace(result.t_s, result.min_distance_m, COLLISION_DISTANCE_M,
                                        "time [s]", f"{title}: minimum distance between any "
                                                    "two UAVs"))
        names = ["top_view.png", "altitude.png", "traffic.png", "min_distance.png"]
    else:
        figs = (*plot_world(result.t_s, result.positions_m, result.min_distance_m,
                            result.uav_ids, title, COLLISION_DISTANCE_M),
                *plot_side_and_3d(result.t_s, result.positions_m, result.uav_ids, title))
        names = ["top_view.png", "altitude.png", "min_distance.png", "side_view.png",
                 "view_3d.png"]
    if summary.landing is not None:
        from uavmpc.apps.plots import plot_landing

        figs = (*figs, plot_landing(result))
        names.append("landing.png")
    if summary.formation is not None and summary.formation.error is not None:
        from uavmpc.apps.plots import plot_formation

        figs = (*figs, plot_formation(result))
        names.append("formation.png")
    for fig, name in zip(figs, names, strict=True):
        fig.savefig(out / name, dpi=110)
        close_figure(fig)  # hundreds of UAVs' lines: free them now, not at exit
    return names


def _run_scenario(scenario: str, out: Path, *, avoidance: bool, seed: int,
                  duration: float | None, loss: float | None, latency: float | None,
                  wind: float = 0.0, ros2: str | None = None,
                  realtime: float | None = None, uavs: int | None = None,
                  cruise_heights: tuple[float, ...] | None = None,
                  faults: FaultSpec | None = None, launch_check: float | None = None,
                  live_port: int | None = None, liveness: bool = True) -> RunSummary:
    """Fly a scenario; write its summary, flight log and figures to ``out``; the summary."""
    import contextlib
    import dataclasses

    # matplotlib (Agg) before the flight, not after it: a missing one fails before the flight
    import uavmpc.apps.plots  # noqa: F401
    from uavmpc.drivers.world import GROUND_VEHICLE_ID, World
    from uavmpc.log import FlightRecorder
    from uavmpc.scenarios.traffic import TrafficScenario, traffic_outcome

    sc = _load_run_scenario(scenario, seed=seed, duration=duration, uavs=uavs,
                            cruise_heights=cruise_heights)
    spec = _run_spec(sc, avoidance=avoidance, seed=seed, duration=duration, loss=loss,
                     latency=latency, wind=wind, faults=faults, launch_check=launch_check)
    sc, link = spec.flown.scenario, spec.flown.link
    out.mkdir(parents=True, exist_ok=True)
    for name in RUN_OUTPUTS:  # none of an earlier run's outputs is left beside this one's
        (out / name).unlink(missing_ok=True)
    meta = {"scenario": sc.name, "seed": seed, "avoidance": avoidance, "loss": link.loss,
            "latency_s": link.latency_s}
    objects = (GROUND_VEHICLE_ID,) if sc.ground_vehicle is not None else ()
    # A flight log of hundreds of UAVs is gigabytes (poses at 20 Hz, every prediction) and
    # costs more than the flight: above MAX_LOGGED_UAVS only the summary and figures.
    logged = len(sc.uavs) <= MAX_LOGGED_UAVS
    if not logged:
        print(f"{len(sc.uavs)} UAVs: no flight.mcap (logs are written up to {MAX_LOGGED_UAVS} "
              "UAVs)")
    with (FlightRecorder(out / "flight.mcap", [u.uav_id for u in sc.uavs], meta, objects)
          if logged else contextlib.nullcontext()) as rec:
        world = World(spec, recorder=rec)
        result = _fly_world(world, sc, duration=duration, ros2=ros2, realtime=realtime,
                            live_port=live_port)
    summary = result.summary().with_sections(
        link=dataclasses.asdict(link), flight_log="flight.mcap" if logged else None)
    if spec.faults.active():
        summary = summary.with_sections(faults=spec.flown.faults.summary())
    if isinstance(sc, TrafficScenario):
        summary = summary.with_sections(traffic=traffic_outcome(result, sc))
    elif liveness and avoidance:
        from uavmpc.apps.liveness import liveness as liveness_of

        summary = summary.with_sections(liveness=liveness_of(spec, result))
    summary.write(out / "summary.json")
    return summary.with_sections(figures=_save_run_figures(result, sc, summary, out,
                                                           avoidance=avoidance))


def _goal_words(reached: bool | None) -> str:
    return "flew its mission" if reached is None else (
        "reached its goal" if reached else "MISSED its goal")


def _times(factor: float | None) -> str:
    # Hundreds of UAVs fly slower than real time: "0×" would hide how much slower.
    return "–" if factor is None else f"{factor:.0f}×" if factor >= 10 else f"{factor:.2g}×"


def _verdict(s: RunSummary) -> str:
    """The verdict of a run: its status and its collisions."""
    hits = f"{len(s.collisions)} collision(s)" if s.collisions else "no collision"
    return f"status: {s.status.value}, {hits}"


def _print_world_summary(s: RunSummary, out: Path) -> None:
    closest = ("one UAV" if s.min_distance_m is None
               else f"closest approach {s.min_distance_m:.2f} m (collision < 1 m)")
    print(f"{s.scenario}, {'with' if s.avoidance else 'without'} avoidance, seed "
          f"{s.seed}: {_verdict(s)}; {closest}; {_times(s.realtime_factor)} real time")
    for c in s.collisions[:5]:
        print(f"  collision at t = {c.t_s:.2f} s: {c.a} and {c.b}, "
              f"{c.distance_m:.2f} m apart")
    traffic = s.sections.get("traffic")
    # A line per UAV is unreadable for a traffic of hundreds: the traffic block says it all.
    per_uav = s.uavs.items() if traffic is None or len(s.uavs) <= 10 else ()
    for uav, u in per_uav:
        climbed = (f"climbed up to {u.max_z_offset_m:.1f} m to avoid"
                   if u.max_z_offset_m >= 0.05 else "never climbed")
        print(f"  {uav}: {climbed}, avoiding for {u.avoidance_active_s or 0.0:.1f} s, "
              f"{_goal_words(u.reached_goal)}, tracking RMSE "
              f"{u.tracking_rmse_m or float('nan'):.3f} m")
    live = s.sections.get("liveness")
    if live is not None:
        print(_liveness_line(live))
    m = s.messages
    print(f"  link: {m.sent} predictions sent, {m.delivered} delivered, {m.dropped} dropped")
    if traffic is not None:
        from uavmpc.scenarios.traffic import outcome_lines

        print("\n".join(outcome_lines(traffic)))
    if s.landing is not None:
        _print_landing(s.landing)
    if s.formation is not None:
        _print_formation(s.formation)
    log = ", flight.mcap" if s.sections.get("flight_log") else ""
    print(f"wrote {out}/summary.json{log}, {', '.join(s.sections.get('figures', []))}")


def _liveness_line(live: dict[str, Any]) -> str:
    timed = live["per_uav"]
    arrived = sum(e["goal_s"] is not None for e in timed.values())
    line = f"  liveness: {arrived} of {len(timed)} at their goals"
    if live["delay_max_s"] is not None:
        worst = max((e["delay_s"], u) for u, e in timed.items() if e["delay_s"] is not None)
        line += (f"; the avoidance cost a median {live['delay_median_s']:.1f} s, at most "
                 f"{worst[0]:.1f} s ({worst[1]}), against the same flight without it")
    for uav in live["late"]:
        line += f"\n  {uav} LATE: {timed[uav]['why']}"
    return line


def _print_landing(la: Landing) -> None:
    td = la.touchdown
    if la.landed and td is not None:
        print(f"  landed: {la.uav} on the deck {la.time_to_land_s or 0.0:.1f} s after "
              f"the approach began; touchdown at {td.vertical_speed_mps:.2f} m/s down "
              f"(limit {la.max_touchdown_speed_mps:g}), {td.horizontal_speed_mps:.2f} "
              f"m/s across, {td.offset_from_centre_m:.2f} m from the deck's centre")
    else:
        why = ("no touchdown" if td is None else "hard touchdown" if td.hard
               else f"{la.edge_strikes} edge strike(s)" if la.edge_strikes
               else "not on the deck at the end")
        print(f"  NOT landed: {why}")
    print(f"  time: {', '.join(f'{k} {v:.1f} s' for k, v in la.phases_s.items())}; "
          f"aborts {dict(la.aborts) or 'none'}")


def _print_formation(f: Formation) -> None:
    if f.error is None:
        print("  formation error: not measured (a member was not heard)")
        return
    per = ", ".join(f"{k} {v.rms_m:.2f}/{v.max_m:.2f}" for k, v in f.per_follower.items())
    print(f"  formation error (from {f.measured_from_s:g} s): rms "
          f"{f.error.rms_m:.2f} m, max {f.error.max_m:.2f} m (rms/max: {per})")
    calm = f.while_no_member_avoids
    if calm is not None:
        print(f"    while no member avoids: rms {calm.rms_m:.2f} m, max {calm.max_m:.2f} m")


@contextlib.contextmanager
def _compiling() -> Iterator[CompileWatch]:
    """A watch that tells the user, on stderr, what a cold cache compiles (a first run), and
    the kernels around the tick compiled beside it on a second core
    (:func:`uavmpc.apps.prewarm.beside`)."""
    from uavmpc.apps.prewarm import beside
    from uavmpc.jit import CompileWatch

    with beside() as helped:
        announced: list[str] = []

        def show(line: str) -> None:
            print(line, file=sys.stderr, flush=True)
            if helped and not announced:
                announced.append(line)
                print("  (a second process compiles the kernels around the tick beside it, "
                      "on another core)", file=sys.stderr, flush=True)

        with CompileWatch(show=show) as watch:
            yield watch


def _print_compiled(watch: CompileWatch) -> None:
    if watch.kernels:
        print(f"compiled {watch.kernels} kernels in {watch.seconds:.0f} s (once: the next run "
              "loads them; the real-time factor above leaves it out)", file=sys.stderr)


def _demo(args: argparse.Namespace) -> int:
    out = Path(args.out)
    with _compiling() as watch:
        s = _run_scenario("swap_through_static", out, avoidance=True, seed=args.seed,
                          duration=None, loss=None, latency=None)
    _print_world_summary(s, out)
    _print_compiled(watch)
    return 0 if not s.collisions else 1


def _run(args: argparse.Namespace) -> int:
    from uavmpc.apps.campaign import fault_spec

    out = Path(args.out) if args.out is not None else Path("out/run") / Path(args.scenario).stem
    if args.realtime is not None and not args.realtime > 0:
        print("uavmpc run: --realtime must be > 0", file=sys.stderr)
        return 2
    if args.launch_check is not None and not (math.isfinite(args.launch_check)
                                              and args.launch_check >= 0.0):
        print(f"uavmpc run: --launch-check must be a time ≥ 0 [s], got {args.launch_check}",
              file=sys.stderr)
        return 2
    if args.uavs is not None and args.scenario != "traffic":
        print(f"uavmpc run: --uavs is for the generated scenario 'traffic', not "
              f"{args.scenario!r} (its UAVs are in its file)", file=sys.stderr)
        return 2
    if args.uavs is not None and not 1 <= args.uavs <= 1000:
        print(f"uavmpc run: --uavs must be in [1, 1000], got {args.uavs}", file=sys.stderr)
        return 2
    heights = None
    if args.cruise_heights is not None:
        if args.scenario != "traffic":
            print("uavmpc run: --cruise-heights is for the generated scenario 'traffic'",
                  file=sys.stderr)
            return 2
        try:
            heights = tuple(float(h) for h in args.cruise_heights.split(","))
        except ValueError:
            print(f"uavmpc run: --cruise-heights: comma-separated metres, e.g. 30,40; got "
                  f"{args.cruise_heights!r}", file=sys.stderr)
            return 2
    note = getattr(args, "threads_note", None)
    if note is not None:
        print(note, file=sys.stderr)
    try:
        with _compiling() as watch:
            s = _run_scenario(args.scenario, out, avoidance=not args.no_avoidance,
                              seed=args.seed, duration=args.duration, loss=args.loss,
                              latency=args.latency, wind=args.wind, ros2=args.ros2,
                              realtime=args.realtime, uavs=args.uavs, cruise_heights=heights,
                              faults=fault_spec(args), launch_check=args.launch_check,
                              live_port=args.live, liveness=not args.no_liveness)
    except (OSError, ValueError) as exc:
        if args.ros2 is None and args.live is None:
            raise
        print(f"uavmpc run: {'--ros2' if args.live is None else '--ros2/--live'}: {exc}",
              file=sys.stderr)
        return 2
    _print_world_summary(s, out)
    _print_compiled(watch)
    return 0


def _node(args: argparse.Namespace) -> int:
    from uavmpc.drivers.launch import LaunchError, NodeLaunch, run_node

    try:
        own = _node_from_scenario(args) if args.scenario else _node_from_flags(args)
        spec = NodeLaunch(
            **own, swarm=args.swarm, listen=tuple(args.listen or ()),
            connect=tuple(args.connect or ()), duration_s=args.duration,
            formation_file=args.formation, key_file=args.key_file,
            identity_file=args.identity_file, roster_file=args.roster, mavlink=args.mavlink,
            setpoints=args.setpoints, origin_m=tuple(args.origin),
            geo_origin=None if args.geo_origin is None else tuple(args.geo_origin),
            hover_thrust=args.hover_thrust, system_id=args.system_id, ros2=args.ros2,
            ros2_commands=args.ros2_commands)
    except LaunchError as exc:
        print(f"uavmpc node: {exc}", file=sys.stderr)
        return 2
    return run_node(spec)


#: The flags of ``uavmpc node`` that ``--scenario`` gives from the UAV's own entry.
_SCENARIO_GIVES = ("priority", "airframe", "start", "heading", "goto", "mission_file")


def _node_from_flags(args: argparse.Namespace) -> dict[str, Any]:
    """The UAV's own NodeLaunch fields from the flags (no scenario)."""
    from uavmpc.drivers.launch import LaunchError

    if args.priority is None:
        raise LaunchError("--priority is required (or --scenario FILE gives it)")
    return dict(uav_id=args.id, priority=args.priority, airframe=args.airframe or "f550",
                start_m=tuple(args.start or (0.0, 0.0, 5.0)), heading_rad=args.heading or 0.0,
                goto=None if args.goto is None else tuple(args.goto),
                mission_file=args.mission_file, avoidance=not args.no_avoidance)


def _node_from_scenario(args: argparse.Namespace) -> dict[str, Any]:
    """The UAV's own NodeLaunch fields from its entry in ``--scenario`` and the scenario's
    safety settings (avoidance parameters, geofence, limits), as the world flies them; its
    mission starts at ``--epoch`` (default: now). ConfigError for what a node cannot
    honour, LaunchError for a flag the scenario gives too."""
    from uavmpc.drivers.launch import LaunchError, node_settings
    from uavmpc.missions.format import mission_table
    from uavmpc.reference import Reference
    from uavmpc.scenarios import load

    given = [f"--{name.replace('_', '-')}" for name in _SCENARIO_GIVES
             if getattr(args, name) is not None]
    if given:
        raise LaunchError(f"--scenario gives the UAV's {', '.join(given)}: drop them")
    scenario = load(args.scenario)
    uav = next((u for u in scenario.uavs if u.uav_id == args.id), None)
    if uav is None:
        raise LaunchError(f"--id {args.id!r} is not a UAV of {scenario.name} "
                          f"({', '.join(u.uav_id for u in scenario.uavs)})")
    epoch = time.time() if args.epoch is None else float(args.epoch)
    on_clock = Reference(uav.mission.times_s + epoch, uav.mission.points, uav.mission.loop)
    return dict(uav_id=uav.uav_id, priority=uav.priority, airframe=uav.airframe,
                start_m=uav.start_m, heading_rad=uav.heading_rad,
                mission=mission_table(on_clock),
                avoidance=uav.avoidance and not args.no_avoidance, **node_settings(scenario))


def _sitl(args: argparse.Namespace) -> int:
    from uavmpc.drivers.launch import SitlLaunch, run_sitl

    return run_sitl(SitlLaunch(
        connect=args.connect, airframe=args.airframe, position_m=tuple(args.position),
        heading_rad=args.heading, system_id=args.system_id,
        odometry_rate_hz=args.odometry_rate, clock_rate=args.clock_rate, seed=args.seed,
        estimator_error=not args.no_estimator_error,
        geo_origin=None if args.no_geo else tuple(args.geo_origin), duration_s=args.duration))


def _swarm_preflight(args: argparse.Namespace
                     ) -> tuple[Px4SitlBuild | None, tuple[float, float, float] | None] | None:
    """The PX4 SITL build and its geo origin (or None, None); None after printing an error."""
    if args.px4_sitl is not None and args.mavlink:
        print("uavmpc swarm: --px4-sitl and --mavlink are exclusive: --px4-sitl flies real PX4 "
              "instances, --mavlink the stand-ins", file=sys.stderr)
        return None
    if args.geo_origin is not None and args.px4_sitl is None:
        print("uavmpc swarm: --geo-origin needs --px4-sitl (it places the real PX4s' homes)",
              file=sys.stderr)
        return None
    build = geo_origin = None
    if args.px4_sitl is not None:
        from uavmpc.drivers.px4.firmware import DEFAULT_GEO_ORIGIN, Px4SitlBuild
        from uavmpc.drivers.px4.frames import enu_to_geodetic

        geo_origin = tuple(args.geo_origin or DEFAULT_GEO_ORIGIN)
        try:
            enu_to_geodetic(np.asarray([0.0, 0.0, 0.0]), geo_origin)
        except ValueError as exc:
            print(f"uavmpc swarm: --geo-origin: {exc}", file=sys.stderr)
            return None
        build = Px4SitlBuild.locate(args.px4_sitl)  # a ConfigError names what is missing
    if args.mavlink or build is not None:
        import uavmpc.drivers.px4.dialect  # noqa: F401  (fail early if pymavlink is missing)
    if args.ros2:
        from uavmpc.drivers.ros2 import require_graph

        require_graph(args.ros2)  # fail early, in one line, if the ros2 extra is missing
    return build, geo_origin


def _print_swarm_summary(s: RunSummary, out: Path, *, build: Px4SitlBuild | None,
                         mavlink: bool) -> None:
    """Print a swarm run's verdict, a line per node and the formation error."""
    closest = s.min_distance_m
    via = (" each flying a real PX4 SITL (SIH) over MAVLink" if build is not None
           else " each flying a PX4 stand-in over MAVLink" if mavlink else "")
    est = s.sections.get("estimate")
    by = ""
    if est is not None:  # judged by a simulator's truth: the estimates' figure beside it
        by = f" by the truth ({est['min_distance_m']} m by the estimates)"
    print(f"{s.scenario} as {len(s.uavs)} node processes over Zenoh{via}: {_verdict(s)}; "
          f"closest approach {closest if closest is None else round(closest, 2)} m{by}")
    for uav, u in s.uavs.items():
        node = u.details.get("node", {})
        line = (f"  {uav}: climbed {u.max_z_offset_m:.0f} m, "
                f"{_goal_words(u.reached_goal)}, tracking RMSE "
                f"{u.tracking_rmse_m or float('nan'):.3f} m; tick period p50 "
                f"{node.get('period_p50_ms', float('nan')):.2f} ms, "
                f"p99 {node.get('period_p99_ms', float('nan')):.2f} ms")
        px4 = node.get("vehicle") or {}
        if px4:
            line += (f"; MAVLink {px4.get('phase')}"
                     + (f" ({px4['stop_reason']})" if px4.get("stop_reason") else "")
                     + f", setpoints p99 {px4.get('setpoint_period_p99_ms', 0.0):.2f} ms")
        if u.details.get("px4"):
            line += f"; PX4 log {u.details['px4'].get('ulog') or u.details['px4'].get('log')}"
        watch = node.get("assumptions") or {}
        if watch.get("breaks") or watch.get("dead_peers"):
            line += (f"; assumptions broken {watch.get('breaks')}, peers taken for dead "
                     f"{sorted(watch.get('dead_peers', {}))}")
        if "node_killed_at_s" in u.details:
            line += f"; its node was killed {u.details['node_killed_at_s']:.1f} s in"
        print(line)
    if s.formation is not None:
        _print_formation(s.formation)
    print(f"wrote {out}/summary.json, flight.mcap, min_distance.png, <id>.node.log")


def _kills(given: list[list[str]] | None, spec: RunSpec) -> dict[str, float] | None:
    """``--kill-node ID S`` pairs as {id: seconds}, checked; None after saying what is
    wrong."""
    kills: dict[str, float] = {}
    ids = {u.uav_id for u in spec.scenario.uavs}
    for uav, when in given or []:
        try:
            t = float(when)
        except ValueError:
            t = math.nan
        if uav not in ids or not (math.isfinite(t) and t >= 0.0):
            print(f"uavmpc swarm: --kill-node {uav} {when}: needs a UAV of the scenario "
                  f"({', '.join(sorted(ids))}) and a time ≥ 0 [s]", file=sys.stderr)
            return None
        kills[uav] = t
    return kills


def _swarm(args: argparse.Namespace) -> int:
    """``uavmpc swarm``: fly a scenario as one node process per UAV and print the outcome."""
    import contextlib

    from uavmpc import scenarios
    from uavmpc.drivers.swarm import run_swarm
    from uavmpc.drivers.world import COLLISION_DISTANCE_M
    from uavmpc.scenarios.run import RunSpec

    out = Path(args.out)

    def draw(t_s: list[float], d_m: list[float]) -> None:
        from uavmpc.apps.plots import plot_min_distance_trace

        plot_min_distance_trace(t_s, d_m, COLLISION_DISTANCE_M).savefig(
            out / "min_distance.png", dpi=110)

    checked = _swarm_preflight(args)
    if checked is None:
        return 2
    build, geo_origin = checked
    with contextlib.ExitStack() as around:
        live = None
        if args.live is not None:
            from uavmpc.view.live import LiveView

            try:
                live = around.enter_context(LiveView(port=args.live))
            except (OSError, ValueError) as exc:
                print(f"uavmpc swarm: --live: {exc}", file=sys.stderr)
                return 2
            print(f"live view on {live.url} (Foxglove: Open connection)", flush=True)
        spec = RunSpec(scenarios.load(args.scenario), avoidance=not args.no_avoidance,
                       duration_s=args.duration)
        kills = _kills(args.kill_node, spec)
        if kills is None:
            return 2
        s = run_swarm(spec, out, key_file=args.key_file, on_trace=draw, kill_at_s=kills,
                      mavlink=args.mavlink, setpoints=args.setpoints, ros2=args.ros2,
                      live=live, px4_sitl=build, px4_first_instance=args.px4_first_instance,
                      **({"geo_origin": geo_origin} if geo_origin is not None else {}))
    _print_swarm_summary(s, out, build=build, mavlink=args.mavlink)
    return 0


def _file_reference(args: argparse.Namespace) -> int:
    from uavmpc.apps.fileref import reference_markdown

    text = reference_markdown()
    if args.out:
        Path(args.out).write_text(text)
    else:
        print(text, end="")
    return 0


def _formation_shape(args: argparse.Namespace) -> int:
    from uavmpc.comms.zenoh_link import ZenohTransport
    from uavmpc.drivers.node import FORMATION_CHANNEL
    from uavmpc.missions.formation import SHAPES

    if args.shape not in SHAPES:
        print(f"uavmpc formation-shape: shape must be one of {', '.join(SHAPES)}",
              file=sys.stderr)
        return 2
    if not (args.in_s >= 0.0 and args.in_s < 3600.0):
        print("uavmpc formation-shape: --in must be in [0, 3600) s", file=sys.stderr)
        return 2
    seal_for = _command_sealer(args, "uavmpc formation-shape")
    if seal_for is None:
        return 2
    payload = json.dumps({"shape": args.shape, "at_s": time.time() + args.in_s}).encode()
    with ZenohTransport(args.id, swarm=args.swarm, connect=args.connect or []) as transport:
        # Peers need a moment to find each other; the same command again is ignored (sealed
        # anew each time: a sealed command sent twice would be refused as a replay).
        for _ in range(3):
            time.sleep(0.5)
            transport.put("formation", seal_for(payload, FORMATION_CHANNEL))
    print(f"sent: {args.shape} in {args.in_s:g} s to swarm {args.swarm!r}")
    return 0


def _credentials(args: argparse.Namespace, prog: str, *, need_roster: bool
                 ) -> tuple[bytes | None, Identity | None, Roster | None] | None:
    """(key, identity, roster) from ``--key-file``, ``--identity-file``, ``--roster``, or
    None after printing what is wrong."""
    from uavmpc.drivers.launch import load_credentials

    # (load_credentials is not annotated yet: this is what it returns)
    creds: tuple[bytes | None, Identity | None, Roster | None] | None = load_credentials(
        prog, key_file=args.key_file, identity_file=getattr(args, "identity_file", None),
        roster_file=getattr(args, "roster", None) if need_roster else None,
        need_roster=need_roster)
    return creds


def _command_sealer(args: argparse.Namespace, prog: str
                    ) -> Callable[[bytes, str], bytes] | None:
    """``seal(payload, channel)`` for a command sender: sealed with its key or identity (a
    node with keys refuses anything else), or the payload as it is."""
    creds = _credentials(args, prog, need_roster=False)
    if creds is None:
        return None
    key, identity, _ = creds
    if key is None and identity is None:
        return lambda payload, channel: payload
    from uavmpc.comms.auth import CommandSigner, SharedKey

    if identity is not None:
        return CommandSigner(identity).seal
    assert key is not None  # (not both None: returned above)
    return CommandSigner(SharedKey(key, args.id)).seal


def _mission(args: argparse.Namespace) -> int:
    from uavmpc.comms.zenoh_link import ZenohTransport
    from uavmpc.missions.format import mission_from_table, read_mission

    try:  # checked as the node will check it: what it would refuse is not sent
        if args.file is None:
            table: dict[str, Any] = {"goto": args.goto}
            mission_from_table(table, "--goto", time.time())
        else:
            table, _ = read_mission(args.file, time.time())
    except ValueError as exc:
        print(f"uavmpc mission: {exc}", file=sys.stderr)
        return 2
    payload = json.dumps(table).encode()
    seal_for = _command_sealer(args, "uavmpc mission")
    if seal_for is None:
        return 2
    with ZenohTransport(args.id, swarm=args.swarm, connect=args.connect or []) as transport:
        time.sleep(0.5)  # discovery; once only: a sealed mission sent again is a replay
        transport.send(args.to, "mission", seal_for(payload, f"{args.to}/mission"))
        time.sleep(0.2)
    what = f"goto {args.goto}" if args.file is None else f"the mission of {args.file}"
    print(f"sent: {what} to {args.to!r} in swarm {args.swarm!r}")
    return 0


def _keygen(args: argparse.Namespace) -> int:
    from uavmpc.comms import auth

    try:
        auth.check_member_id(args.member_id, "ID")
        ident = auth.Identity.generate(args.member_id)
    except (ImportError, ValueError) as exc:
        print(f"uavmpc keygen: {exc}", file=sys.stderr)
        return 2
    out = Path(args.dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{args.member_id}.id"
    roster_path = Path(args.roster) if args.roster else out / "roster.toml"
    members: dict[str, auth.RosterEntry] = {}
    try:
        if roster_path.exists():
            members = dict(auth.load_roster(roster_path))
        if args.member_id in members:
            raise ValueError(f"{roster_path}: already has a member {args.member_id!r}")
        auth.write_identity(ident, path)
    except FileExistsError:
        print(f"uavmpc keygen: {path} exists (keys are never overwritten)", file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f"uavmpc keygen: {exc}", file=sys.stderr)
        return 2
    members[args.member_id] = auth.RosterEntry(args.role, ident.public_key)
    roster_path.write_text(auth.Roster(members).to_toml())
    print(f"wrote {path} (private, mode 600) and {args.role} {args.member_id!r} into "
          f"{roster_path}")
    return 0


def _export_bag(args: argparse.Namespace) -> int:
    from uavmpc.apps.bag import BagExportError, export_bag

    try:
        s = export_bag(args.run_dir, args.out, overwrite=args.overwrite)
    except BagExportError as exc:
        print(f"uavmpc export-bag: {exc}", file=sys.stderr)
        return 2
    total = sum(s["messages"].values())
    span = (s["end_ns"] - s["start_ns"]) * 1e-9 if total else 0.0
    print(f"wrote {s['bag']}: {total} messages on {len(s['messages'])} topics over {span:.1f} s "
          "(rosbag2, MCAP storage, CDR; ros2 bag play / Foxglove)")
    return 0


def _tracker_demo(args: argparse.Namespace) -> int:
    from uavmpc.apps.plots import plot_axis_response
    from uavmpc.reference import Reference
    from uavmpc.tracker import MpcTracker

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tracker = MpcTracker(position_m=(0.0, 0.0, 10.0))
    tracker.set_reference(Reference.goto(50.0, 0.0, 10.0))
    n = round(args.duration / tracker.config.first_step_s)
    log = np.empty((n, 4))
    for i in range(n):
        cmd = tracker.step().command
        log[i] = cmd.t_s, cmd.position_m[0], cmd.velocity_mps[0], cmd.acceleration_mps2[0]
    t, p, v, a = log.T
    lim = tracker.limits
    outside = np.flatnonzero(np.abs(p - 50.0) >= 0.01)
    settle = float(t[outside[-1] + 1]) if outside.size and outside[-1] + 1 < n else None
    overshoot_m = float(max(p.max() - 50.0, 0.0))
    summary = {
        "step_m": 50.0,
        "overshoot_m": overshoot_m,
        "settle_1cm_s": settle,
        "max_speed_mps": float(np.abs(v).max()),
        "max_accel_mps2": float(np.abs(a).max()),
        "speed_limit_mps": lim.horizontal_speed_mps,
        "accel_limit_mps2": lim.horizontal_accel_mps2,
        "fallbacks": tracker.fallback_count,
    }
    fig = plot_axis_response(t, p, v, a, target=50.0, v_max=lim.horizontal_speed_mps,
                             a_max=lim.horizontal_accel_mps2,
                             title="MPC tracker: 50 m step on x (virtual UAV)")
    fig.savefig(out / "step_50m.png", dpi=120)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(f"50 m step flown by the virtual UAV: max speed {summary['max_speed_mps']:.2f} m/s "
          f"(limit {lim.horizontal_speed_mps}), max accel {summary['max_accel_mps2']:.2f} m/s² "
          f"(limit {lim.horizontal_accel_mps2}),")
    print(f"overshoot {100 * overshoot_m:.1f} cm, within 1 cm after "
          f"{settle if settle is not None else float('nan'):.2f} s, "
          f"{tracker.fallback_count} solver fallbacks.")
    print(f"wrote {out / 'step_50m.png'} and {out / 'summary.json'}")
    return 0


def _track(args: argparse.Namespace) -> int:
    from uavmpc.apps.plots import plot_tracking
    from uavmpc.drivers.flight import demanding_reference, fly, summarize
    from uavmpc.plant import Airframe, Wind

    airframe = Airframe.named(args.airframe)
    wind = None
    if args.wind:
        wind = Wind(mean_mps=np.array([args.wind, 0.0, 0.0]), gust_sigma_mps=0.2 * args.wind,
                    seed=args.seed)
    log = fly(airframe, demanding_reference(), args.duration, wind=wind)
    summary = summarize(log, airframe)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fig = plot_tracking(log.t_s, log.reference, log.command, log.actual,
                        f"{airframe.name}: mission reference, tracker output and UAV")
    fig.savefig(out / "tracking.png", dpi=110)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(f"{airframe.name}: {summary['status']}, "
          f"tracking RMSE {summary['tracking_rmse_m']:.3f} m "
          f"(max {summary['max_tracking_error_m']:.3f} m), "
          f"max tilt {summary['max_tilt_deg']:.1f}°, "
          f"motors saturated {summary['motor_saturation_s']:.2f} s, "
          f"{summary['realtime_factor']:.0f}× real time")
    print(f"wrote {out / 'tracking.png'} and {out / 'summary.json'}")
    return 0 if log.status.value == "complete" else 1


def _bench(args: argparse.Namespace) -> int:
    from uavmpc.apps.bench import main_loop, main_px4, main_ros2, main_tracker, main_world

    if args.what == "tracker":
        return main_tracker(args.ticks, args.seed)
    if args.what == "loop":
        return main_loop(args.duration, 3 if args.repeats is None else args.repeats,
                         args.airframe)
    if args.what == "world":
        return main_world(args.duration if args.duration != 60.0 else 20.0, args.sizes,
                          args.duration_large, args.threads, args.profile,
                          1 if args.repeats is None else args.repeats)
    if args.what == "px4":
        return main_px4(args.duration if args.duration != 60.0 else 20.0)
    if args.what == "ros2":
        return main_ros2(args.duration if args.duration != 60.0 else 20.0)
    raise AssertionError(args.what)


def _add_demo_parser(sub: Subparsers) -> None:
    """Add ``uavmpc demo``: the swap-through scenario with its defaults."""
    demo = sub.add_parser(
        "demo", help="three UAVs swap through a hovering one, with collision avoidance")
    demo.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    demo.add_argument("--seed", type=int, default=0)
    # One thread by default, on the quick-start tick: its three UAVs fly in under a second
    # either way, while a first run would spend ~16 s more compiling the threaded tick.
    _add_threads_argument(demo, "1, or $UAVMPC_THREADS")
    demo.set_defaults(func=_demo)


def _add_threads_argument(parser: argparse.ArgumentParser,
                          default: str = "every core, or $UAVMPC_THREADS") -> None:
    parser.add_argument("--threads", type=int, default=None, metavar="N",
                        help=f"threads the world's tick runs its UAVs on (default: {default}; "
                             "the flight is the same for any N)")


def _add_run_parser(sub: Subparsers) -> None:
    """Add ``uavmpc run``: a scenario's overrides, ROS 2 and live view, and the faults."""
    run = sub.add_parser("run", help="fly a scenario (built-in name or TOML file)")
    run.add_argument("scenario", help="swap_through_static, converge_center, traffic (generated: "
                                      "--uavs, --seed), or a .toml file")
    run.add_argument("--uavs", type=int, default=None,
                     help="traffic: number of UAVs (default 300; the area grows with it)")
    run.add_argument("--cruise-heights", default=None, metavar="Z1,Z2,...",
                     help="traffic: cruise heights by direction of travel (default one: 30)")
    run.add_argument("--no-avoidance", action="store_true", help="fly without avoidance")
    run.add_argument("--no-liveness", action="store_true",
                     help="skip the flight without avoidance that times each UAV's delay")
    run.add_argument("--seed", type=int, default=0)
    run.add_argument("--duration", type=float, default=None, help="simulated seconds")
    _add_threads_argument(run, "the cores idle now: every core less the 1-minute load "
                               "average, at least 1; or $UAVMPC_THREADS")
    run.add_argument("--out", default=None,
                     help="output folder (default out/run/SCENARIO, the scenario's name or its "
                          "file's stem); the outputs of an earlier run there are replaced")
    run.add_argument("--loss", type=float, default=None, help="message loss probability")
    run.add_argument("--latency", type=float, default=None, help="link latency [s]")
    run.add_argument("--wind", type=float, default=0.0, help="mean wind along x [m/s]")
    run.add_argument("--ros2", metavar="ROUTER",
                     help="fly in real time and show every UAV on a ROS 2 graph through this "
                          "Zenoh router (rmw_zenohd, e.g. tcp/localhost:7447); goals and "
                          "trajectories from ROS 2 are flown")
    run.add_argument("--ros2-dds", type=int, nargs="?", const=-1, default=None,
                     metavar="DOMAIN",
                     help="like --ros2, on ROS 2's default middleware (DDS) in this domain "
                          "(default: ROS_DOMAIN_ID, else 0)")
    run.add_argument("--realtime", type=float, default=None, metavar="FACTOR",
                     help="pace the simulation at FACTOR × real time (--ros2, --live: "
                          "default 1)")
    run.add_argument("--live", type=int, nargs="?", const=8765, default=None, metavar="PORT",
                     help="serve the 3-D scene and metrics to Foxglove on ws://127.0.0.1:PORT "
                          "while it flies (default port 8765; pip install 'uavmpc[viz]')")
    from uavmpc.apps.campaign import add_fault_arguments

    add_fault_arguments(run)
    run.set_defaults(func=_run)


def _add_falsify_parser(sub: Subparsers) -> None:
    """Add ``uavmpc falsify``: the search for the smallest separation (its space, budget,
    link and faults)."""
    from uavmpc.apps.campaign import add_fault_arguments

    f = sub.add_parser("falsify", help="search scenarios for the smallest separation the "
                                       "avoidance allows; keep the worst as scenario files")
    f.add_argument("--budget", type=int, default=200, help="flights (default 200)")
    f.add_argument("--generation", type=int, default=None,
                   help="cases per generation (default: a tenth of the budget, at least 4)")
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--family", default="straight",
                   help="the scenarios searched: straight (one straight path each, anywhere), "
                        "vertical (columns climbing and descending through each other), "
                        "grid (a grid's points shuffled), walk (waypoints in one height band) "
                        "(default straight; docs/falsify.md)")
    f.add_argument("--uavs", type=int, default=6, help="UAVs per case (default 6)")
    f.add_argument("--area", type=float, default=60.0,
                   help="side of the square starts and goals lie in [m] (default 60)")
    f.add_argument("--min-height", type=float, default=5.0, help="[m] (default 5)")
    f.add_argument("--max-height", type=float, default=20.0, help="[m] (default 20)")
    f.add_argument("--ceiling", type=float, default=None,
                   help="the geofence's ceiling [m] (default 30; the grid family's 25)")
    f.add_argument("--speed", type=float, default=5.0, help="cruise speed [m/s] (default 5)")
    f.add_argument("--duration", type=float, default=60.0,
                   help="simulated seconds per flight (default 60)")
    f.add_argument("--loss", type=float, default=0.0, help="message loss probability")
    f.add_argument("--latency", type=float, default=0.05, help="link latency [s]")
    f.add_argument("--no-avoidance", action="store_true", help="search without avoidance")
    f.add_argument("--workers", type=int, default=1,
                   help="processes a generation's flights are shared among (default 1; the "
                        "results do not depend on it)")
    f.add_argument("--out", default="out/falsify", help="output folder (default out/falsify)")
    add_fault_arguments(f)
    f.set_defaults(func=_falsify)


def _falsify(args: argparse.Namespace) -> int:
    from uavmpc.apps.falsify import falsify, space_from_args, summary_lines, write_results

    space = space_from_args(args)
    closest = [math.inf]
    so_far: list[Outcome] = []

    def said(o: Outcome) -> None:
        new = o.min_distance_m < closest[0]
        closest[0] = min(closest[0], o.min_distance_m)
        so_far.append(o)
        if new or (o.index + 1) % 10 == 0:
            print(f"flight {o.index + 1}/{args.budget}: {o.min_distance_m:.2f} m"
                  + (" (closest so far)" if new else f"; closest {closest[0]:.2f} m"),
                  flush=True)
            # A long search stopped early keeps what it found.
            write_results(space, so_far, Path(args.out), avoidance=not args.no_avoidance)

    outcomes = falsify(space, args.budget, seed=args.seed, generation=args.generation,
                       avoidance=not args.no_avoidance, workers=args.workers, on_flight=said)
    paths = write_results(space, outcomes, Path(args.out), avoidance=not args.no_avoidance)
    for line in summary_lines(space, outcomes, paths):
        print(line)
    return 0


def _add_node_parser(sub: Subparsers) -> None:
    """Add ``uavmpc node``: one UAV's identity, peers, mission, keys and autopilot link."""
    node = sub.add_parser("node", help="one UAV's onboard stack in real time over Zenoh")
    node.add_argument("--id", required=True, help="UAV id ([A-Za-z0-9_-], ≤ 32)")
    node.add_argument("--scenario", metavar="NAME_OR_FILE",
                      help="fly the UAV --id of this scenario: its priority, airframe, start, "
                           "mission, and the scenario's avoidance parameters, geofence and "
                           "limits, as `uavmpc run` flies them (a part a node cannot fly is "
                           "refused by name)")
    node.add_argument("--epoch", type=float, default=None,
                      help="--scenario: Unix time of the scenario's t = 0 (default: now); "
                           "give every node of a swarm the same")
    node.add_argument("--priority", type=int, default=None,
                      help="lower = higher priority (required without --scenario)")
    node.add_argument("--airframe", default=None, help="f550 (default), x500 or a TOML file")
    node.add_argument("--connect", action="append", help="peer endpoint, e.g. tcp/10.0.0.2:7447")
    node.add_argument("--listen", action="append", help="own endpoint, e.g. tcp/0.0.0.0:7447")
    node.add_argument("--swarm", default="default", help="swarm name (key prefix)")
    node.add_argument("--start", type=float, nargs=3, default=None,
                      metavar=("X", "Y", "Z"),
                      help="start position [m] (simulated plant; default 0 0 5)")
    node.add_argument("--heading", type=float, default=None, help="start heading [rad]")
    node.add_argument("--goto", type=float, nargs=4, metavar=("X", "Y", "Z", "HEADING"),
                      help="initial mission: fly to this point")
    node.add_argument("--mission-file", help="initial mission: a TOML or JSON file with one of "
                                             "goto, trajectory or path (times on Unix time)")
    node.add_argument("--formation", metavar="FILE",
                      help="fly as a member of this formation (a [formation] table, TOML or "
                           "JSON): a follower flies its slot along the leader's plans")
    node.add_argument("--no-avoidance", action="store_true")
    node.add_argument("--key-file", help="shared key: sign predictions, drop unsigned ones; "
                                         "missions must be sealed with it")
    node.add_argument("--identity-file", help="this UAV's own identity (uavmpc keygen): sign "
                                              "its predictions as itself (with --roster)")
    node.add_argument("--roster", help="the swarm's roster: accept predictions only from the "
                                       "UAV they claim, commands only from operators")
    node.add_argument("--duration", type=float, default=None,
                      help="stop after S seconds (with --mavlink: then land)")
    node.add_argument("--mavlink", metavar="URL",
                      help="fly a PX4 autopilot instead of the simulated plant: udp://:14540 "
                           "listens (PX4 SITL's offboard port), udpout://HOST:PORT sends; "
                           "--start is then where to take off to")
    node.add_argument("--setpoints", choices=["attitude", "position"], default="attitude",
                      help="--mavlink: SET_ATTITUDE_TARGET from our SE(3) controller (default) "
                           "or SET_POSITION_TARGET_LOCAL_NED for PX4's position controller")
    node.add_argument("--origin", type=float, nargs=3, default=[0.0, 0.0, 0.0],
                      metavar=("X", "Y", "Z"),
                      help="--mavlink: the autopilot's local-frame origin in the world (ENU)")
    node.add_argument("--geo-origin", type=float, nargs=3, default=None,
                      metavar=("LAT", "LON", "ALT"),
                      help="--mavlink: the world's ENU origin on the globe (degrees, metres "
                           "AMSL); the autopilot's frame is then placed from its own "
                           "GPS_GLOBAL_ORIGIN (no --origin needed)")
    node.add_argument("--hover-thrust", type=float, default=None,
                      help="--mavlink: normalised hover thrust (default: MPC_THR_HOVER)")
    node.add_argument("--system-id", type=int, default=None,
                      help="--mavlink: the autopilot's system id (default: the first heard)")
    node.add_argument("--ros2", metavar="ROUTER",
                      help="also appear on a ROS 2 graph (rmw_zenoh) through this Zenoh router, "
                           "e.g. tcp/localhost:7447: /ID/pose, odom, prediction, avoidance out; "
                           "/ID/goal, /ID/trajectory in (pip install 'uavmpc[ros2]')")
    node.add_argument("--ros2-dds", type=int, nargs="?", const=-1, default=None,
                      metavar="DOMAIN",
                      help="like --ros2, on ROS 2's default middleware (DDS) in this domain "
                           "(default: ROS_DOMAIN_ID, else 0)")
    node.add_argument("--ros2-commands", action="store_true",
                      help="--ros2 with --key-file: take goals and trajectories from ROS 2 anyway "
                           "(they are not signed)")
    node.set_defaults(func=_node)


def _add_sitl_parser(sub: Subparsers) -> None:
    """Add ``uavmpc sitl``: the stand-in PX4's link, boot state, rates and estimator."""
    sitl = sub.add_parser("sitl", help="a stand-in PX4 autopilot (our plant) on MAVLink/UDP")
    sitl.add_argument("--connect", default="udpout://127.0.0.1:14540",
                      help="where its MAVLink goes (default udpout://127.0.0.1:14540, as PX4 "
                           "SITL; udp://:PORT listens instead)")
    sitl.add_argument("--airframe", default="f550", help="f550, x500 or a TOML file")
    sitl.add_argument("--position", type=float, nargs=3, default=[0.0, 0.0, 0.0],
                      metavar=("X", "Y", "Z"), help="boot position (ENU) [m], on the ground")
    sitl.add_argument("--heading", type=float, default=0.0, help="boot heading [rad]")
    sitl.add_argument("--system-id", type=int, default=1, help="MAVLink system id (default 1)")
    sitl.add_argument("--odometry-rate", type=float, default=30.0,
                      help="ODOMETRY [Hz] (default 30, PX4's onboard rate)")
    sitl.add_argument("--clock-rate", type=float, default=0.986,
                      help="its clock against the wall clock (default 0.986, lockstep SITL)")
    sitl.add_argument("--seed", type=int, default=0, help="the estimator error's seed")
    sitl.add_argument("--no-estimator-error", action="store_true",
                      help="report (and control on) the true state")
    sitl.add_argument("--geo-origin", type=float, nargs=3, default=[47.397742, 8.545594, 488.0],
                      metavar=("LAT", "LON", "ALT"),
                      help="the world's ENU origin on the globe (deg, deg, m AMSL; default "
                           "PX4 SITL's home)")
    sitl.add_argument("--no-geo", action="store_true",
                      help="no global position (no GPS_GLOBAL_ORIGIN, GLOBAL_POSITION_INT)")
    sitl.add_argument("--duration", type=float, default=None, help="stop after S seconds")
    sitl.set_defaults(func=_sitl)


def _add_swarm_parser(sub: Subparsers) -> None:
    """Add ``uavmpc swarm``: one node process per UAV, simulated or on (stand-in) PX4s."""
    swarm = sub.add_parser("swarm", help="a scenario as one node process per UAV on loopback")
    swarm.add_argument("scenario", help="swap_through_static, converge_center or a TOML file")
    swarm.add_argument("--out", default="out/swarm", help="output folder (default out/swarm)")
    swarm.add_argument("--no-avoidance", action="store_true")
    swarm.add_argument("--kill-node", nargs=2, action="append", metavar=("ID", "S"),
                       help="SIGKILL the node of UAV ID S seconds after the mission starts "
                            "(its vehicle, with an autopilot, flies on under its failsafe)")
    swarm.add_argument("--duration", type=float, default=None, help="seconds after the start")
    swarm.add_argument("--key-file", help="shared key file given to every node")
    swarm.add_argument("--mavlink", action="store_true",
                       help="each node flies its own stand-in PX4 (uavmpc sitl) over "
                            "MAVLink/UDP on 127.0.0.1: take-off from the ground, mission, "
                            "landing")
    swarm.add_argument("--px4-sitl", metavar="DIR",
                       help="each node flies a real PX4 SITL instance with SIH from this build "
                            "(bin/px4, etc/; or its .tar.gz): the i-th UAV is instance i, "
                            "working in OUT/px4/<id>/")
    swarm.add_argument("--geo-origin", type=float, nargs=3, default=None,
                       metavar=("LAT", "LON", "ALT"),
                       help="--px4-sitl: the world's ENU origin on the globe (degrees, metres "
                            "AMSL; default PX4's SITL home 47.397742 8.545594 488)")
    swarm.add_argument("--px4-first-instance", type=int, default=0, metavar="N",
                       help="--px4-sitl: instance number of the first UAV (ports 14540+N...)")
    swarm.add_argument("--setpoints", choices=["attitude", "position"], default="attitude",
                       help="--mavlink, --px4-sitl: the setpoint message the nodes send")
    swarm.add_argument("--ros2", metavar="ROUTER",
                       help="every node also appears on a ROS 2 graph through this Zenoh router "
                            "(rmw_zenohd, e.g. tcp/localhost:7447)")
    swarm.add_argument("--ros2-dds", type=int, nargs="?", const=-1, default=None,
                       metavar="DOMAIN",
                       help="like --ros2, on ROS 2's default middleware (DDS) in this domain "
                            "(default: ROS_DOMAIN_ID, else 0)")
    swarm.add_argument("--live", type=int, nargs="?", const=8765, default=None, metavar="PORT",
                       help="serve the 3-D scene and metrics to Foxglove on "
                            "ws://127.0.0.1:PORT while it flies (default port 8765; pip "
                            "install 'uavmpc[viz]')")
    swarm.set_defaults(func=_swarm)


def _add_file_reference_parser(sub: Subparsers) -> None:
    """Add ``uavmpc file-reference``: where the Markdown reference goes."""
    ref = sub.add_parser("file-reference",
                         help="the reference of the scenario and airframe files, from their "
                              "loaders (Markdown)")
    ref.add_argument("--out", default=None, help="write it here (default: print it)")
    ref.set_defaults(func=_file_reference)


def _add_formation_shape_parser(sub: Subparsers) -> None:
    """Add ``uavmpc formation-shape``: the shape, when, and how it is sealed."""
    shape = sub.add_parser("formation-shape",
                           help="tell a formation's followers (node processes) to change shape")
    shape.add_argument("shape", help="line or square")
    shape.add_argument("--swarm", default="default", help="swarm name (key prefix)")
    shape.add_argument("--connect", action="append", help="a node's endpoint, e.g. "
                                                          "tcp/10.0.0.2:7447")
    shape.add_argument("--in", dest="in_s", type=float, default=0.0,
                       help="start the change this many seconds from now (default 0)")
    shape.add_argument("--id", default="ground", help="this sender's id (default ground)")
    shape.add_argument("--key-file", help="seal the command with the swarm's shared key")
    shape.add_argument("--identity-file", help="seal the command as this operator")
    shape.set_defaults(func=_formation_shape)


def _add_mission_parser(sub: Subparsers) -> None:
    """Add ``uavmpc mission``: the goal, its recipient, and how it is sealed."""
    mission = sub.add_parser("mission", help="send one UAV node a mission over Zenoh (sealed "
                                             "with a key or an operator's identity)")
    mission.add_argument("--to", required=True, help="the UAV's id")
    what = mission.add_mutually_exclusive_group(required=True)
    what.add_argument("--goto", type=float, nargs=4, metavar=("X", "Y", "Z", "HEADING"),
                      help="fly to this point (ENU, rad)")
    what.add_argument("--file", metavar="MISSION",
                      help="fly the mission of this TOML or JSON file: one of goto, trajectory "
                           "or path (the mission format of docs/reference/files.md)")
    mission.add_argument("--swarm", default="default", help="swarm name (key prefix)")
    mission.add_argument("--connect", action="append", help="a node's endpoint")
    mission.add_argument("--id", default="ground", help="this sender's id (default ground)")
    mission.add_argument("--key-file", help="seal with the swarm's shared key")
    mission.add_argument("--identity-file", help="seal as this operator (uavmpc keygen)")
    mission.set_defaults(func=_mission)


def _add_keygen_parser(sub: Subparsers) -> None:
    """Add ``uavmpc keygen``: the member's id, role and where its files go."""
    keygen = sub.add_parser("keygen", help="a new Ed25519 identity and its roster entry "
                                           "(pip install 'uavmpc[auth]')")
    keygen.add_argument("member_id", metavar="ID", help="a UAV's or an operator's id")
    keygen.add_argument("--role", choices=["uav", "operator"], required=True)
    keygen.add_argument("--dir", default="keys", help="where ID.id goes (default keys/)")
    keygen.add_argument("--roster", default=None,
                        help="the roster to add it to (default DIR/roster.toml)")
    keygen.set_defaults(func=_keygen)


def _add_export_bag_parser(sub: Subparsers) -> None:
    """Add ``uavmpc export-bag``: the run folder and the bag folder."""
    bag = sub.add_parser("export-bag", help="a run's flight.mcap as a rosbag2 (ROS 2 types, "
                                            "CDR, MCAP storage)")
    bag.add_argument("run_dir", help="a folder written by uavmpc run, demo or swarm")
    bag.add_argument("--out", default=None, help="bag folder (default RUN_DIR/rosbag2)")
    bag.add_argument("--overwrite", action="store_true", help="replace an existing bag folder")
    bag.set_defaults(func=_export_bag)


def _add_tracker_demo_parser(sub: Subparsers) -> None:
    """Add ``uavmpc tracker-demo``: output folder and simulated time."""
    tdemo = sub.add_parser("tracker-demo", help="the virtual UAV flies a 50 m step; plot it")
    tdemo.add_argument("--out", default="out/tracker-demo", help="output folder")
    tdemo.add_argument("--duration", type=float, default=20.0, help="simulated seconds")
    tdemo.set_defaults(func=_tracker_demo)


def _add_track_parser(sub: Subparsers) -> None:
    """Add ``uavmpc track``: airframe, wind and output folder."""
    track = sub.add_parser(
        "track", help="one UAV flies a demanding reference in closed loop; figure + summary")
    track.add_argument("--airframe", default="f550",
                       help="packaged airframe (f550, x500) or a TOML file (default f550)")
    track.add_argument("--duration", type=float, default=60.0, help="simulated seconds")
    track.add_argument("--wind", type=float, default=0.0, help="mean wind along x [m/s]")
    track.add_argument("--seed", type=int, default=0, help="seed of the wind gusts")
    track.add_argument("--out", default="out/track", help="output folder (default out/track)")
    track.set_defaults(func=_track)


def _add_bench_parser(sub: Subparsers) -> None:
    """Add ``uavmpc bench``: which benchmark and its sizes."""
    bench = sub.add_parser("bench", help="benchmarks; the last line printed is JSON")
    bench.add_argument("what", choices=["tracker", "loop", "world", "px4", "ros2"],
                       help="tracker: one MpcTracker vs Clarabel; loop: the full one-UAV loop; "
                            "world: random_walk worlds of 5 to 1000 UAVs, one process each; "
                            "px4: three nodes flying stand-in PX4s over MAVLink vs their built-in "
                            "plants; ros2: three nodes on a ROS 2 graph vs without")
    bench.add_argument("--ticks", type=int, default=3000, help="tracker ticks (≥ 2000 advised)")
    bench.add_argument("--seed", type=int, default=1)
    bench.add_argument("--duration", type=float, default=60.0,
                       help="loop, world, px4: seconds (world and px4 default 20)")
    bench.add_argument("--sizes", default=None,
                       help="world: UAVs per world, comma-separated (default 5,20,100,300,1000)")
    bench.add_argument("--duration-large", type=float, default=None,
                       help="world: seconds for worlds of ≥ 300 UAVs (default 10, at most "
                            "--duration)")
    bench.add_argument("--threads", default=None, metavar="T1,T2,...",
                       help="world: thread counts to fly each size with, side by side "
                            "(default: 1 and every core)")
    bench.add_argument("--profile", action="store_true",
                       help="world: each flight's compiled tick stage by stage (prepare, QP, "
                            "advance, control, plant, traces) and the Python phases per tick")
    bench.add_argument("--repeats", type=int, default=None,
                       help="loop: timed runs (default 3); world: flights per size and thread "
                            "count, taking turns, the fastest reported (default 1)")
    bench.add_argument("--airframe", default="f550", help="loop: airframe")
    bench.set_defaults(func=_bench)


def build_parser() -> argparse.ArgumentParser:
    """The ``uavmpc`` parser with every sub-command."""
    parser = argparse.ArgumentParser(
        prog="uavmpc",
        description="Multi-UAV MPC tracking, control and collision avoidance.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    _add_demo_parser(sub)
    _add_run_parser(sub)
    _add_falsify_parser(sub)
    _add_node_parser(sub)
    _add_sitl_parser(sub)
    _add_swarm_parser(sub)
    _add_file_reference_parser(sub)
    _add_formation_shape_parser(sub)
    _add_mission_parser(sub)
    _add_keygen_parser(sub)
    _add_export_bag_parser(sub)
    _add_tracker_demo_parser(sub)
    _add_track_parser(sub)
    _add_bench_parser(sub)
    from uavmpc.apps.campaign import build_parser_campaign

    build_parser_campaign(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    from uavmpc.config import exit_code_of

    args = build_parser().parse_args(argv)
    duration = getattr(args, "duration", 1.0)
    if duration is not None and not duration > 0:
        print("uavmpc: --duration must be > 0", file=sys.stderr)
        return 2
    if getattr(args, "ticks", 1) < 1:
        print("uavmpc: --ticks must be ≥ 1", file=sys.stderr)
        return 2
    if args.command == "demo" and args.threads is None:
        from uavmpc.jit import THREADS_ENV

        args.threads = None if os.environ.get(THREADS_ENV) else 1
    if args.command == "run" and args.threads is None:
        from uavmpc.jit import THREADS_ENV, available_threads, idle_threads

        args.threads = idle_threads()
        why = (f"${THREADS_ENV}" if os.environ.get(THREADS_ENV, "").strip()
               else f"the cores idle now of {available_threads()}")
        # Said when the run sets off (_run), not before a bad flag's one-line error.
        args.threads_note = (f"uavmpc run: ticking on {args.threads} thread(s), {why} "
                             "(--threads N to choose)")
    if args.command in ("demo", "run") and args.threads is not None:
        from uavmpc.jit import set_threads

        try:
            set_threads(args.threads)
        except ValueError as exc:
            print(f"uavmpc: --threads: {exc}", file=sys.stderr)
            return 2
    if getattr(args, "ros2_dds", None) is not None:  # run, swarm, node: one graph, named once
        from uavmpc.drivers.ros2 import dds_where

        if args.ros2 is not None:
            print("uavmpc: --ros2 and --ros2-dds are exclusive (one ROS 2 middleware)",
                  file=sys.stderr)
            return 2
        try:
            args.ros2 = dds_where(None if args.ros2_dds < 0 else args.ros2_dds)
        except ValueError as exc:
            print(f"uavmpc: {exc}", file=sys.stderr)
            return 2
    return exit_code_of(lambda: args.func(args))


if __name__ == "__main__":
    sys.exit(main())
