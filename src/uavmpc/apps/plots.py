"""Figures (matplotlib, headless)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure


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


def plot_min_distance_trace(t_s: object, d_m: object, collision_m: float,
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
