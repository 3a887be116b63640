"""Figures (matplotlib, headless)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")

import itertools

import matplotlib.pyplot as plt
import numpy as np
import numpy.typing as npt
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    from uavmpc.drivers.world_report import WorldResult
    from uavmpc.scenarios.traffic import TrafficScenario


def plot_axis_response(
    t_s: np.ndarray,
    position_m: np.ndarray,
    velocity_mps: np.ndarray,
    accel_mps2: np.ndarray,
    *,
    target: float,
    v_max: float,
    a_max: float,
    title: str,
) -> Figure:
    """Position, velocity and acceleration of one axis vs time, with the limits drawn."""
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(8, 7))
    axes[0].plot(t_s, position_m, label="virtual UAV")
    axes[0].axhline(target, color="k", ls="--", lw=0.8, label="reference")
    axes[0].set_ylabel("position [m]")
    axes[0].legend(loc="lower right")
    axes[1].plot(t_s, velocity_mps)
    axes[2].plot(t_s, accel_mps2)
    for ax, lim, name in ((axes[1], v_max, "velocity [m/s]"), (axes[2], a_max, "accel. [m/s²]")):
        ax.axhline(lim, color="r", ls=":", lw=1.0, label="limit")
        ax.axhline(-lim, color="r", ls=":", lw=1.0)
        ax.set_ylabel(name)
        ax.legend(loc="upper right")
    axes[-1].set_xlabel("time [s]")
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def plot_tracking(
    t_s: np.ndarray, reference: np.ndarray, command: np.ndarray, actual: np.ndarray, title: str
) -> Figure:
    """Per axis (x, y, z, heading): the user's reference, the tracker's output, the UAV."""
    fig, axes = plt.subplots(4, 1, sharex=True, figsize=(9, 9))
    names = ("x [m]", "y [m]", "z [m]", "heading [rad]")
    for i, ax in enumerate(axes):
        ref, cmd, act = reference[:, i], command[:, i], actual[:, i]
        if i == 3:  # show headings continuous, not wrapped
            ref, cmd, act = np.unwrap(ref), np.unwrap(cmd), np.unwrap(act)
        ax.plot(t_s, ref, "k--", lw=0.9, label="reference (mission)")
        ax.plot(t_s, cmd, lw=1.4, label="tracker output (virtual UAV)")
        ax.plot(t_s, act, lw=1.0, label="UAV (actual)")
        ax.set_ylabel(names[i])
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def plot_world(t_s: np.ndarray, positions_m: np.ndarray, min_distance_m: np.ndarray,
               uav_ids: list[str], title: str,
               collision_m: float = 1.0) -> tuple[Figure, Figure, Figure]:
    """Top view of the paths, altitude vs time, minimum pairwise distance vs time."""
    top, ax = plt.subplots(figsize=(7, 6))
    for i, uav in enumerate(uav_ids):
        line = ax.plot(positions_m[:, i, 0], positions_m[:, i, 1], label=uav)[0]
        ax.plot(*positions_m[0, i, :2], "o", color=line.get_color())
        ax.plot(*positions_m[-1, i, :2], "s", color=line.get_color())
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{title}: top view (o start, ■ end)")
    ax.grid(alpha=0.3)
    ax.legend()
    top.tight_layout()

    alt, ax = plt.subplots(figsize=(8, 4))
    for i, uav in enumerate(uav_ids):
        ax.plot(t_s, positions_m[:, i, 2], label=uav)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("altitude z [m]")
    ax.set_title(f"{title}: altitude")
    ax.grid(alpha=0.3)
    ax.legend()
    alt.tight_layout()

    dist = plot_min_distance_trace(t_s, min_distance_m, collision_m, "time [s]",
                                   f"{title}: minimum distance between any two UAVs")
    return top, alt, dist


def main_axis(xy_m: np.ndarray) -> np.ndarray:
    """The unit horizontal direction along which points ``xy_m`` (n, 2) spread most (their
    principal axis; +x when they do not spread), pointed to have a positive x component when
    it can."""
    pts = np.asarray(xy_m, dtype=float).reshape(-1, 2)
    centred = pts - pts.mean(axis=0)
    if not np.any(centred):
        return np.array([1.0, 0.0])
    axis: npt.NDArray[np.float64] = np.linalg.svd(centred, full_matrices=False)[2][0]
    return -axis if axis[0] < 0 or (axis[0] == 0 and axis[1] < 0) else axis


def _time_marks(t_s: np.ndarray, every_s: float | None) -> np.ndarray:
    """Indices of ``t_s`` at about six evenly spaced times (or every ``every_s``)."""
    span = float(t_s[-1] - t_s[0]) if len(t_s) else 0.0
    step = every_s or max(1.0, round(span / 6.0))
    marks = np.arange(t_s[0], t_s[-1] + 1e-9, step)
    return np.unique(np.searchsorted(t_s, marks).clip(0, len(t_s) - 1))


def plot_side_and_3d(t_s: np.ndarray, positions_m: np.ndarray, uav_ids: list[str], title: str,
                     every_s: float | None = None) -> tuple[Figure, Figure]:
    """A side view (distance along the main horizontal direction of the paths vs altitude)
    and a 3-D view of the paths, with the UAVs' places at common times marked and labelled:
    the avoidance of the height-offset strategy happens in the vertical plane a top view does
    not show."""
    from mpl_toolkits.mplot3d import Axes3D  # noqa: F401  (registers the 3-D projection)

    t = np.asarray(t_s, dtype=float)
    pos = np.asarray(positions_m, dtype=float)
    axis = main_axis(pos[:, :, :2].reshape(-1, 2))
    along = pos[:, :, :2] @ axis
    marks = _time_marks(t, every_s)

    side, ax = plt.subplots(figsize=(10, 4.5))
    for i, uav in enumerate(uav_ids):
        line = ax.plot(along[:, i], pos[:, i, 2], label=uav)[0]
        ax.plot(along[marks, i], pos[marks, i, 2], "o", ms=4, color=line.get_color())
    for k in marks:  # one label per mark, above the highest UAV there
        top = int(np.argmax(pos[k, :, 2]))
        ax.annotate(f"{t[k]:.0f} s", (along[k, top], pos[k, top, 2]),
                    textcoords="offset points", xytext=(0, 6), ha="center", fontsize=7,
                    color="0.35")
    ax.set_xlabel(f"along ({axis[0]:+.2f}, {axis[1]:+.2f}) [m]")
    ax.set_ylabel("altitude z [m]")
    ax.set_title(f"{title}: side view (● the UAVs at common times)")
    ax.grid(alpha=0.3)
    ax.legend()
    side.tight_layout()

    fig3 = plt.figure(figsize=(9, 7))
    ax3 = fig3.add_subplot(projection="3d")
    for i, uav in enumerate(uav_ids):
        line = ax3.plot(pos[:, i, 0], pos[:, i, 1], pos[:, i, 2], label=uav)[0]
        ax3.scatter(pos[marks, i, 0], pos[marks, i, 1], pos[marks, i, 2], s=12,
                    color=line.get_color(), depthshade=False)
        for k in marks[1:-1]:
            ax3.text(pos[k, i, 0], pos[k, i, 1], pos[k, i, 2] + 0.4, f"{t[k]:.0f}",
                     fontsize=6, color=line.get_color())
    # metres alike on x and y (a straight swap must not look like a zigzag of 1e-16 m)
    lo, hi = pos[:, :, :2].reshape(-1, 2).min(axis=0), pos[:, :, :2].reshape(-1, 2).max(axis=0)
    half = 0.5 * max(float((hi - lo).max()), 1.0)
    mid = 0.5 * (lo + hi)
    ax3.set_xlim(mid[0] - half, mid[0] + half)
    ax3.set_ylim(mid[1] - half, mid[1] + half)
    ax3.set_zlim(0.0, float(pos[:, :, 2].max()) + 1.0)
    ax3.set_box_aspect((1.0, 1.0, 0.6))
    ax3.set_xlabel("x [m]")
    ax3.set_ylabel("y [m]")
    ax3.set_zlabel("z [m]")
    ax3.set_title(f"{title}: 3-D paths (labels: time [s])")
    ax3.legend(loc="upper left")
    fig3.tight_layout()
    return side, fig3


def close_figure(fig: Figure) -> None:
    """Free a figure once saved (pyplot keeps every figure it made until closed)."""
    plt.close(fig)


def plot_min_distance_trace(t_s: ArrayLike, d_m: ArrayLike, collision_m: float,
                            xlabel: str = "time since mission start [s]",
                            title: str | None = None) -> Figure:
    """The closest pairwise distance over time, with the collision threshold (a world's
    third figure, and the swarm's only one)."""
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.plot(t_s, d_m, label="closest pair")
    ax.axhline(collision_m, color="r", ls="--", label=f"collision ({collision_m:g} m)")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("min pairwise distance [m]")
    ax.set_ylim(bottom=0.0)
    if title is not None:
        ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    return fig


def plot_landing(result: WorldResult) -> Figure:
    """The landing on the moving deck: top view of the car and the UAV, the UAV's height above
    the deck and its horizontal speed relative to the car over time, the phases shaded."""
    la = result.landing
    car = result.ground_vehicle_m
    if la is None or car is None:
        raise ValueError(f"plot_landing: {result.scenario!r} had no landing on a ground vehicle")
    i = result.uav_ids.index(la.uav)
    t = result.t_s
    uav = result.positions_m[:, i]
    dt = np.gradient(t)
    rel_v = np.hypot(*(np.gradient(uav[:, :2] - car[:, :2], axis=0) / dt[:, None]).T)
    t_end = la.touchdown.t_s + 2.0 if la.touchdown is not None else t[-1]
    show = t <= t_end
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.5), gridspec_kw={"width_ratios": [1.1, 1]})
    ax = axes[0]
    ax.plot(car[:, 0], car[:, 1], color="0.75", lw=1, label="car's track")
    ax.plot(car[show, 0], car[show, 1], color="k", lw=1.5, label="car")
    ax.plot(uav[show, 0], uav[show, 1], color="C0", lw=1.5, label=result.uav_ids[i])
    ax.plot(*uav[0, :2], "o", color="C0")
    if la.touchdown is not None:
        k = int(np.searchsorted(t, la.touchdown.t_s))
        ax.plot(*uav[min(k, len(t) - 1), :2], "*", ms=14, color="C3", label="touchdown")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    ax.set_title("top view")
    ax1 = axes[1]
    ax1.plot(t[show], uav[show, 2] - car[show, 2], color="C0", label="height above the deck")
    ax1.set_ylabel("height above the deck [m]")
    ax1.set_xlabel("time [s]")
    ax1.grid(alpha=0.3)
    ax2 = ax1.twinx()
    ax2.plot(t[show], rel_v[show], color="C1", lw=1, label="horizontal speed relative to the car")
    ax2.set_ylabel("relative horizontal speed [m/s]", color="C1")
    ax2.set_ylim(0.0, max(2.0, float(np.percentile(rel_v[show], 99))))
    colours = {"approach": "0.92", "descend": "#dcefdc", "abort": "#f6d5d5"}
    marks = [*la.transitions, (t_end, "end")]
    for (t0, phase), (t1, _) in itertools.pairwise(marks):
        if phase in colours:
            ax1.axvspan(t0, min(t1, t_end), color=colours[phase], zorder=0, lw=0)
    handles = [plt.Rectangle((0, 0), 1, 1, color=c) for c in colours.values()]
    lines = ax1.get_legend_handles_labels()[0] + ax2.get_legend_handles_labels()[0]
    ax1.legend(lines + handles, ["height above the deck", "relative speed", *colours],
               fontsize=8, loc="upper right")
    verdict = (f"landed {la.time_to_land_s or 0.0:.1f} s after the approach began"
               if la.landed else "not landed")
    ax1.set_title(f"{verdict}; the phases shaded")
    fig.suptitle(f"{result.scenario}, seed {result.seed}")
    fig.tight_layout()
    return fig


def plot_formation(result: WorldResult) -> Figure:
    """The formation: every UAV's path (top view), and each follower's distance from its slot
    over time, with the times a member was avoiding shaded."""
    f = result.formation
    t, err = result.formation_t_s, result.formation_error_m
    if f is None or f.error is None or t is None or err is None:
        raise ValueError(f"plot_formation: {result.scenario!r} had no formation")
    fig, axes = plt.subplots(2, 1, figsize=(11, 9), gridspec_kw={"height_ratios": [1.3, 1]})
    ax = axes[0]
    for i, uav in enumerate(result.uav_ids):
        p = result.positions_m[:, i]
        line = ax.plot(p[:, 0], p[:, 1], lw=1.2, label=uav)[0]
        ax.plot(*p[0, :2], "o", color=line.get_color(), ms=4)
    step = max(1, len(result.t_s) // 12)
    members = [result.uav_ids.index(m) for m in (f.leader, *f.followers)]
    for k in range(0, len(result.t_s), step):  # the formation's shape every few seconds
        pts = result.positions_m[k, members, :2]
        ax.plot(pts[:, 0], pts[:, 1], ".", color="0.4", ms=3)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("paths (grey dots: the members every few seconds)")
    ax = axes[1]
    for j, follower in enumerate(f.followers):
        ax.plot(t, err[:, j], lw=1, label=follower)
    avoiding = result.members_avoiding
    if avoiding is not None:
        keep = result.t_s >= t[0]
        ax.fill_between(t, 0, 1, where=avoiding[keep], color="#f6d5d5",
                        transform=ax.get_xaxis_transform(), label="a member avoiding")
    ax.set_yscale("symlog", linthresh=0.1)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("distance from its slot [m]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"formation error: rms {f.error.rms_m:.2f} m, max {f.error.max_m:.2f} m")
    fig.suptitle(f"{result.scenario}, seed {result.seed}")
    fig.tight_layout()
    return fig


def plot_traffic(result: WorldResult, scenario: TrafficScenario,
                 title: str) -> tuple[Figure, Figure, Figure]:
    """A traffic run (:mod:`uavmpc.scenarios.traffic`): top view (paths by cruise layer, pads),
    altitudes, and the numbers airborne and arrived
    over time: figures that stay readable, and quick, with hundreds of UAVs (no per-UAV
    legend; traces decimated to ~2000 points)."""
    from uavmpc.scenarios.traffic import airborne_counts, arrival_times

    stride = max(1, len(result.t_s) // 2000)  # ≤ ~2000 points per path is plenty to draw
    index = {uid: k for k, uid in enumerate(result.uav_ids)}
    heights = sorted(set(scenario.cruise_m))
    colour = {h: f"C{k % 10}" for k, h in enumerate(heights)}
    thin = 0.6 if len(scenario.uavs) > 50 else 1.0
    top, ax = plt.subplots(figsize=(8, 7.5))
    for u, h in zip(scenario.uavs, scenario.cruise_m, strict=True):
        p = result.positions_m[::stride, index[u.uav_id]]
        ax.plot(p[:, 0], p[:, 1], color=colour[h], lw=thin, alpha=0.7)
    starts = np.array([u.start_m[:2] for u in scenario.uavs])
    goals = np.array([u.goal_m[:2] for u in scenario.uavs])
    mark = 4 if len(scenario.uavs) > 50 else 6
    ax.plot(starts[:, 0], starts[:, 1], "o", ms=mark, mfc="none", color="k", label="origin pads")
    ax.plot(goals[:, 0], goals[:, 1], "s", ms=mark, mfc="none", color="0.4",
            label="destination pads")
    for h in heights:
        ax.plot([], [], color=colour[h], label=f"cruise {h:g} m")
    for c in result.collisions:
        k = int(np.searchsorted(result.t_s, c.t))
        k = min(k, len(result.t_s) - 1)
        p = result.positions_m[k, index[c.a], :2]
        ax.plot(p[0], p[1], "x", color="r", ms=8, mew=2)
    if result.collisions:
        ax.plot([], [], "x", color="r", label="collision")
    half = 0.5 * scenario.area_side_m
    ax.plot([-half, half, half, -half, -half], [-half, -half, half, half, -half], "k:", lw=0.8)
    ax.set_aspect("equal", adjustable="datalim")
    _label(top, ax, "x (east) [m]", "y (north) [m]", f"{title}: top view")

    alt, ax = plt.subplots(figsize=(8, 4))
    t = result.t_s[::stride]
    for u, h in zip(scenario.uavs, scenario.cruise_m, strict=True):
        ax.plot(t, result.positions_m[::stride, index[u.uav_id], 2], color=colour[h], lw=thin,
                alpha=0.7)
    for h in heights:
        ax.axhline(h, color=colour[h], ls="--", lw=0.8, label=f"cruise {h:g} m")
    _label(alt, ax, "time [s]", "altitude z [m]", f"{title}: altitude")

    air, ax = plt.subplots(figsize=(8, 4))
    counts = airborne_counts(result, scenario)
    ax.plot(result.t_s[::stride], counts[::stride], label="airborne")
    arrive = [t for t in arrival_times(result, scenario).values() if t is not None]
    ax.plot(np.sort(arrive), np.arange(1, len(arrive) + 1), label="arrived (cumulative)")
    _label(air, ax, "time [s]", "UAVs", f"{title}: traffic")
    return top, alt, air


def _label(fig: Figure, ax: Axes, xlabel: str, ylabel: str, title: str) -> None:
    """Axis labels, title, grid, legend and layout of one traffic figure."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
