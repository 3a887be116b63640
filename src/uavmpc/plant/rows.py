"""The simulated vehicles' state as typed row records: one row per vehicle, owned by whoever
drives them.

A :class:`PlantRows` holds N multirotors in plain arrays (row i = vehicle i). The compiled
kernels (:func:`uavmpc.plant.kernels.plant_step`) take the record and a row index, so one call
site serves both a single :class:`~uavmpc.plant.multirotor.Multirotor` (a view on its row) and a
batched driver looping over every row of a shared record inside one compiled function. Nothing
else keeps plant state: an object that is a view on a row reads and writes the row.

:func:`copy_row` copies one row between records of any such type (also
:class:`uavmpc.control.se3.ControlRows`), e.g. to gather objects' rows into a driver's record.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from uavmpc.plant.airframe import G_MPS2, Airframe
from uavmpc.plant.attitude import mixer_matrices, pack_attitude_gains
from uavmpc.plant.kernels import N_RIGID, work_floats

__all__ = ["PlantRows", "copy_row"]


class PlantRows(NamedTuple):
    """N simulated multirotors, row i = one vehicle (numba takes the record as an argument).

    R is the most rotors of any row; a row with n < R rotors uses the first n rotor columns,
    the others stay 0 and are never read. Units SI; frames as in :mod:`uavmpc.plant.interface`.

    State (changes every step):
        x: (N, 13 + R) p (3) [m] and v (3) [m/s] in the world frame ENU, attitude q (4)
            (w, x, y, z) body → world, body rates Ω (3) FLU [rad/s], rotor speeds (R) [rad/s].
        ctrl: (N, 7) attitude-loop state: [0:3] rate integrator [rad/s²], [3:6] last measured
            body rate [rad/s], [6] 1.0 once [3:6] holds a measurement.
        landed: (N,) 1.0 while resting on the ground, else 0.0.
        t_s: (N,) simulated time [s].
        wind_mps: (N, 3) wind velocity (world frame) held over the next step [m/s].
        armed: (N,) 1.0 while the motors run, 0.0 once cut (the rotors spin down).
        deck: (N, 9) the moving landing deck the row's contact knows, as it is at ``t_s``
            (columns ``DECK_*`` of :mod:`uavmpc.plant.kernels`): active flag, centre (3) [m],
            heading [rad], velocity (2) [m/s], yaw rate [rad/s], half side [m]; inactive = none.
        touch: (N, 12) what the row did on the deck (columns ``TOUCH_*``): touchdowns, the first
            one's time [s], relative velocity (3) [m/s] and offset from the centre along and
            across the deck [m], edge strikes, the contact now, and where it rests on the deck.

    Airframe constants (written once per row, :meth:`configure`):
        n_rotors: (N,) int64 rotor count n of the row.
        phys: (N, 8) [mass kg, g m/s², motor_tau s, omega_max rad/s, drag x, y, z N/(m/s),
            rotor-disc radius m (the farthest rotor hub: the footprint that can hit a deck's edge)].
        inertia: (N, 3, 3) [kg m²]; inertia_inv: (N, 3, 3) its inverse.
        alloc: (N, 4, R) allocation matrix, [T, τx, τy, τz] = alloc @ ω² [N, N m].
        att_gains: (N, 7, 3) attitude-loop gains
            (:func:`uavmpc.plant.attitude.pack_attitude_gains`).
        mix_inv: (N, R, 4) mixer (pseudo-inverse of alloc) [(rad/s)² per N, N m].
        lo, hi: (N,) range of ω² the mixer commands while flying [(rad/s)²].
        substep_s: (N,) integration and attitude-loop step [s].

    Work area (no state: every step overwrites it before reading it):
        work: (N, :func:`~uavmpc.plant.kernels.work_floats` (R)) a row's RK4 stages, attitude
            loop and rotor commands during its step; a row's own, so that rows step on any
            thread without allocating.
    """

    x: np.ndarray
    ctrl: np.ndarray
    landed: np.ndarray
    t_s: np.ndarray
    wind_mps: np.ndarray
    armed: np.ndarray
    deck: np.ndarray
    touch: np.ndarray
    n_rotors: np.ndarray
    phys: np.ndarray
    inertia: np.ndarray
    inertia_inv: np.ndarray
    alloc: np.ndarray
    att_gains: np.ndarray
    mix_inv: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    substep_s: np.ndarray
    work: np.ndarray

    @classmethod
    def empty(cls, n: int, max_rotors: int) -> PlantRows:
        """A record of ``n`` rows for vehicles of up to ``max_rotors`` rotors, all zero (a row
        is flyable once :meth:`configure`'d, e.g. by a :class:`Multirotor` viewing it)."""
        if n < 1 or max_rotors < 1:
            raise ValueError(f"need n ≥ 1 rows and max_rotors ≥ 1, got {n}, {max_rotors}")
        r = int(max_rotors)
        return cls(
            x=np.zeros((n, N_RIGID + r)), ctrl=np.zeros((n, 7)), landed=np.zeros(n),
            t_s=np.zeros(n), wind_mps=np.zeros((n, 3)), armed=np.ones(n), deck=np.zeros((n, 9)),
            touch=np.zeros((n, 12)), n_rotors=np.zeros(n, dtype=np.int64),
            phys=np.zeros((n, 8)), inertia=np.zeros((n, 3, 3)), inertia_inv=np.zeros((n, 3, 3)),
            alloc=np.zeros((n, 4, r)), att_gains=np.zeros((n, 7, 3)), mix_inv=np.zeros((n, r, 4)),
            lo=np.zeros(n), hi=np.zeros(n), substep_s=np.zeros(n),
            work=np.zeros((n, work_floats(r))),
        )

    @property
    def max_rotors(self) -> int:
        """R: the most rotors a row can have."""
        return int(self.alloc.shape[2])

    def configure(self, i: int, airframe: Airframe, substep_s: float) -> None:
        """Write ``airframe``'s constants and the substep into row ``i`` and clear its state
        (all zero: at the origin, attitude and rotor speeds still to be written)."""
        n = airframe.n_rotors
        if n > self.max_rotors:
            raise ValueError(f"airframe {airframe.name!r} has {n} rotors, the record only "
                             f"{self.max_rotors}")
        for field in ("x", "ctrl", "wind_mps", "alloc", "mix_inv", "deck", "touch"):
            getattr(self, field)[i] = 0.0
        self.landed[i] = 0.0
        self.armed[i] = 1.0
        self.t_s[i] = 0.0
        self.n_rotors[i] = n
        self.phys[i] = [airframe.mass_kg, G_MPS2, airframe.motor_tau_s, airframe.omega_max_radps,
                        *airframe.drag_n_per_mps,
                        float(np.max(np.linalg.norm(airframe.rotor_xy_m, axis=1)))]
        self.inertia[i] = airframe.inertia_kgm2
        self.inertia_inv[i] = np.linalg.inv(np.ascontiguousarray(airframe.inertia_kgm2,
                                                                 dtype=float))
        self.alloc[i, :, :n] = airframe.allocation()
        self.att_gains[i] = pack_attitude_gains(airframe.attitude)
        mix_inv, lo, hi = mixer_matrices(airframe)
        self.mix_inv[i, :n] = mix_inv
        self.lo[i] = lo
        self.hi[i] = hi
        self.substep_s[i] = substep_s


def copy_row(src: Any, i: int, dst: Any, j: int) -> None:
    """Copy row ``i`` of record ``src`` into row ``j`` of ``dst`` (both of the same record type,
    e.g. :class:`PlantRows`; their widths may differ as long as the row's data fits: what does
    not exist in ``src`` is zero in ``dst``)."""
    if type(src) is not type(dst):
        raise TypeError(f"cannot copy a {type(src).__name__} row into a {type(dst).__name__}")
    for a, b in zip(src, dst, strict=True):
        row, out = a[i], b[j]
        if np.ndim(out) == 0:
            b[j] = row
            continue
        for d in range(row.ndim):  # a narrower destination: what is cut off must be unused
            if row.shape[d] > out.shape[d]:
                cut = np.take(row, range(out.shape[d], row.shape[d]), axis=d)
                if np.any(cut != 0):
                    raise ValueError("the row does not fit into the destination record")
        common = tuple(slice(0, min(p, q)) for p, q in zip(row.shape, out.shape, strict=True))
        out[...] = 0
        out[common] = row[common]
