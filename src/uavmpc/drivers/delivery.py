"""The simulated world's link stage: each UAV's broadcasts onto the
:class:`~uavmpc.comms.link.SimulatedLink` (unless its radio is dead), and the link's due copies
into the receivers' inbox rows, a tick's deliveries at once (each broadcast decoded once for
all its receivers, docs/scale.md) or UAV by UAV; both written to the flight log."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np

from uavmpc.comms.inbox import InboxTable, accept_copies, accept_copies_threads
from uavmpc.comms.link import SimulatedLink
from uavmpc.comms.message import InvalidMessageError
from uavmpc.jit import bound, thread_count
from uavmpc.log import FlightRecorder
from uavmpc.onboard import OnboardStack, store_sent

#: A tick's copies are taken into the inbox rows on every thread from this many on (fewer
#: are not worth waking the threads; the rows come out the same either way).
_THREADED_COPIES = 256


class WorldLink:
    """The link between the world's stacks (``stacks[i]``: row i of ``inboxes``).

    Args:
        link: the simulated link.
        inboxes: every UAV's inbox, one row each.
        stacks: the UAVs' programs, by row.
        offsets_s: (N,) each UAV's clock minus the world's [s].
        silent_from_s: UAV id → world time from which its radio sends nothing [s].
        recorder: the flight log, if any.
    """

    def __init__(self, link: SimulatedLink, inboxes: InboxTable, stacks: Sequence[OnboardStack],
                 offsets_s: np.ndarray, silent_from_s: dict[str, float],
                 recorder: FlightRecorder | None) -> None:
        self.link = link
        self.inboxes = inboxes
        self.stacks = stacks
        self.offsets_s = offsets_s
        self.silent_from_s = silent_from_s
        self.recorder = recorder
        if inboxes.rows.own_col.shape[0] != len(stacks):
            raise ValueError(f"WorldLink: {len(stacks)} stacks but {inboxes.rows.own_col.shape[0]} "
                             "inbox rows (one row per stack)")
        #: Broadcasts swallowed by dead radios.
        self.silenced = 0
        #: The store slot of each broadcast in flight whose message the table holds for its
        #: receivers (by the link's payload id; :meth:`publish`).
        self._held: dict[int, int] = {}

    def publish(self, stacks: Sequence[OnboardStack], data: Sequence[bytes],
                now: float) -> None:
        """The broadcasts ``data[j]`` of ``stacks[j]`` at world time ``now``, in that order
        (a tick's, onto the link in one pass)."""
        silent = self.silent_from_s
        if silent and any(now >= silent.get(s.uav_id, math.inf) for s in stacks):
            on = [j for j, s in enumerate(stacks) if now < silent.get(s.uav_id, math.inf)]
            self.silenced += len(stacks) - len(on)  # dead radios: the UAVs do not know it
            stacks = [stacks[j] for j in on]
            data = [data[j] for j in on]
        pids = self.link.publish_many(data, [s.uav_id for s in stacks], now).tolist()
        self._store_sent(stacks, data, pids)
        if self.recorder is not None:
            for stack in stacks:
                pred = stack.last_broadcast
                assert pred is not None  # it has just broadcast
                self.recorder.prediction(stack.uav_id, now, pred.position_m, pred.heading_rad)
                self.recorder.link(now, "sent", stack.uav_id, stamp_s=now)

    def _store_sent(self, stacks: Sequence[OnboardStack], data: Sequence[bytes],
                    pids: list[int]) -> None:
        """The message of each broadcast in flight sent as it was written (no key, no
        identity) into a store slot of the receivers' table, from the rows the broadcast was
        written from (:func:`~uavmpc.onboard.store_sent`: field for field what its bytes
        decode to), held while its copies are in flight: the receivers take it without
        decoding the bytes. Other bytes are decoded on arrival, as a node's are."""
        plain = [j for j, s in enumerate(stacks)
                 if pids[j] >= 0 and s.key is None and s.identity is None]
        if not plain:
            return
        table = self.inboxes
        sent = stacks[plain[0]].batch.sent
        m = sent.times_s.shape[1]
        rows = np.array([stacks[j].row for j in plain], dtype=np.int64)
        slots = np.array([table.reserve(m) for _ in plain], dtype=np.int64)
        cols = table.rows.own_col[[stacks[j].inbox.row for j in plain]]  # who sent it
        bound(store_sent)(table.store, slots, cols, sent, rows)
        table.hold(slots, [data[j] for j in plain])
        held = self._held
        for j, slot in zip(plain, slots.tolist(), strict=True):
            held[pids[j]] = slot

    def _let_go(self, gone: Iterable[int] | None = None) -> None:
        """Let go of the slots of the broadcasts whose copies are all delivered: ``gone``
        (the link's ids of those just delivered in full), or, without it, every one the
        link no longer holds."""
        if gone is None:
            gone = [pid for pid in self._held if not self.link.holds(pid)]
        for pid in gone:
            slot = self._held.pop(pid, None)
            if slot is not None:
                self.inboxes.let_go(slot)

    def receive_one(self, i: int, now: float) -> None:
        """Row ``i``'s due datagrams into its stack's inbox (the per-object path)."""
        stack = self.stacks[i]
        rec = self.recorder
        data = self.link.receive(stack.uav_id, now)
        rejected = stack.inbox.rejected_total
        kept = stack.receive(now + float(self.offsets_s[i]), data)
        if self._held:
            self._let_go()
        if rec is not None:
            for msg in kept:
                if msg is not None:
                    rec.link(now, "delivered", msg.uav_id, stack.uav_id, msg.stamp_s)
            for _ in range(stack.inbox.rejected_total - rejected):
                rec.link(now, "rejected", "?", stack.uav_id)

    def deliver(self, now: float) -> None:
        """Every copy due at ``now`` through its receiver's rule into its inbox row."""
        due = self.link.take_due(now)
        if due is None:
            return
        receivers = due.receivers
        table = self.inboxes
        n = len(self.stacks)
        # A tick's copies come from a few broadcasts: each is found (the slot its sender's
        # side wrote, held while its copies fly) or decoded once.
        pids = due.payloads.tolist()
        held = self._held
        found = [held.get(pid, -1) for pid in pids]
        errors: dict[int, str] = {}
        if -1 in found:
            for j, pid in enumerate(pids):
                if found[j] < 0:
                    try:
                        found[j] = table.slot_for(self.link.payload(pid))
                    except InvalidMessageError as exc:
                        errors[j] = str(exc)
        slots = np.array(found, dtype=np.int64)
        gone = self.link.release(due.payloads, due.copies)
        if held:
            self._let_go(gone)
        copy_slots = slots[due.which]
        if errors:
            for k in np.flatnonzero((receivers < n) & (copy_slots < 0)).tolist():
                self.stacks[receivers[k]].inbox.count_rejected(errors[int(due.which[k])])
        rec = self.recorder
        if rec is not None:
            before = table.rows.accepted.copy()
        # The rule passes over copies of unread bytes (slot −1) and to receivers past the
        # rows (copies injected for strangers: the table has a row per stack).
        try:
            threads = thread_count()
            if threads > 1 and receivers.shape[0] >= _THREADED_COPIES:
                bound(accept_copies_threads)(table.rows, table.store, receivers, copy_slots,
                                             now + self.offsets_s, threads)
            else:
                bound(accept_copies)(table.rows, table.store, receivers, copy_slots,
                                     now + self.offsets_s)
        finally:
            table.unpin()
        if rec is not None:
            good = (receivers < n) & (copy_slots >= 0)
            self._log_deliveries(now, receivers, copy_slots, good, before)

    def _log_deliveries(self, now: float, receivers: np.ndarray, slots: np.ndarray,
                        good: np.ndarray, before: np.ndarray) -> None:
        """Delivered (kept) and rejected copies into the flight log: a receiver's kept copies
        are the newest of each sender it now holds that it did not hold before."""
        rec = self.recorder
        assert rec is not None
        table = self.inboxes
        st = table.store
        for k in range(receivers.shape[0]):
            r = int(receivers[k])
            if r >= len(self.stacks):
                continue
            if not good[k]:
                rec.link(now, "rejected", "?", self.stacks[r].uav_id)
                continue
            slot = int(slots[k])
            col = int(st.col[slot])
            if table.rows.held_slot[r, col] == slot and table.rows.accepted[r] > before[r]:
                rec.link(now, "delivered", table.ids[col], self.stacks[r].uav_id,
                         float(st.stamp_s[slot]))
