"""The one campaign engine under the random-walk, landing and traffic campaigns.

A campaign is a frozen specification (a :class:`CampaignSpec`: what every trial flies) and a
folder ``DIR``:

- ``campaign.json``: ``{"format": FORMAT, "kind": ..., "version": ..., "spec": {...}}``, the
  specification as its ``to_json``; reloaded with its ``from_json`` it is the same object.
  Re-running with another specification in the same folder is refused, naming what differs.
- ``trials.jsonl``: one JSON line per finished trial, appended (flushed and fsynced) as soon as
  the trial ends. Re-running the same command skips the trials already there, so a crash or
  Ctrl-C loses nothing but the trials in flight.
- ``runs.jsonl``: the wall time of each invocation that ran trials.

A trial is one or more *parts* (a traffic trial: its flight with and its flight without
avoidance), each a job of its own on the executor: in this process (one worker), a local
process pool, or a Ray cluster. A trial's record is written when its last part ends; the
records are aggregated sorted by index, so a report does not depend on the number of workers
or on interruptions.
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import json
import math
import multiprocessing as mp
import os
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, ClassVar, Protocol, TextIO

from uavmpc.config import ConfigError

if TYPE_CHECKING:
    import ray

#: The format of ``campaign.json`` this engine writes. Format 1 (uavmpc before the one engine)
#: held a random walk's ``parameters`` only; it is read as such, every other format refused.
FORMAT = 2
CAMPAIGN_FILE = "campaign.json"
TRIALS_FILE = "trials.jsonl"
#: One line per invocation that ran trials: its wall time (a random walk's report's ``wall_s``
#: is their sum, so a campaign resumed after Ctrl-C reports all the time it took).
RUNS_FILE = "runs.jsonl"


class CampaignError(ConfigError):
    """A campaign that cannot run as asked (the message says why and what to do)."""


@dataclass(frozen=True)
class Task:
    """One part of one trial, as a worker runs it: ``function(*args)`` (a module-level
    function, so that it pickles by name) returns the part's JSON-ready result."""

    index: int
    part: int
    function: Callable[..., dict[str, Any]]
    args: tuple[object, ...]


#: What a task gives back: (trial index, part, the part's JSON-ready result).
TaskResult = tuple[int, int, dict[str, Any]]


def run_task(task: Task, threads: int) -> TaskResult:
    """(trial index, part, result) of a task (what a worker runs), its world's tick on
    ``threads`` threads (the result does not depend on them)."""
    # ``threads`` has no default: ray.remote types a function by its parameters, and with a
    # default it would take this one for a function of the task alone.
    from uavmpc.jit import available_threads, using_threads

    with using_threads(min(threads, available_threads())):
        return task.index, task.part, task.function(*task.args)


class CampaignSpec(Protocol):
    """What a campaign flies; frozen, compared by value."""

    #: The campaign's kind in its ``campaign.json`` (e.g. ``"random_walk"``).
    kind: ClassVar[str]

    def to_json(self) -> dict[str, Any]:
        """JSON-ready; ``from_json`` of it is an equal spec."""
        ...

    def tasks(self, index: int) -> list[Task]:
        """The parts of trial ``index``."""
        ...

    def record(self, index: int, results: list[dict[str, Any]]) -> dict[str, Any]:
        """Trial ``index``'s record from its parts' results (in part order)."""
        ...

    def foreign(self, index: int, record: dict[str, Any]) -> str | None:
        """Why ``record`` cannot be trial ``index`` of this campaign (None: it can)."""
        ...


# ---------------------------------------------------------------------------- executors
class Executor(Protocol):
    """Where a campaign's tasks run (:func:`executor`)."""

    #: How many tasks it takes in at once (submitted, not yet waited for).
    capacity: int

    def submit(self, task: Task) -> None: ...

    def pending(self) -> int: ...

    def wait(self) -> list[TaskResult]:
        """The results of one or more tasks, once at least one has ended."""
        ...

    def close(self, cancel: bool = False) -> None: ...


class _Serial:
    """Runs tasks in this process, one at a time (workers = 1)."""

    capacity = 1

    def __init__(self, threads: int = 1) -> None:
        self._queue: list[Task] = []
        self._threads = threads

    def submit(self, task: Task) -> None:
        self._queue.append(task)

    def pending(self) -> int:
        return len(self._queue)

    def wait(self) -> list[TaskResult]:
        return [run_task(self._queue.pop(0), self._threads)]

    def close(self, cancel: bool = False) -> None:
        self._queue.clear()


class _Pool:
    """A local process pool."""

    def __init__(self, workers: int, threads: int = 1) -> None:
        self.capacity = 2 * workers
        # Workers start from a fresh server process, not forked from this one: numba's
        # default threading layer (workqueue) aborts a forked child of a process that has run
        # a parallel kernel (a world flown before the campaign, in the same process).
        methods = mp.get_all_start_methods()
        ctx = mp.get_context("forkserver" if "forkserver" in methods else "spawn")
        self._ex = cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx)
        self._threads = threads
        self._futures: set[cf.Future[TaskResult]] = set()

    def submit(self, task: Task) -> None:
        self._futures.add(self._ex.submit(run_task, task, self._threads))

    def pending(self) -> int:
        return len(self._futures)

    def wait(self) -> list[TaskResult]:
        done, self._futures = cf.wait(self._futures, return_when=cf.FIRST_COMPLETED)
        return [f.result() for f in done]

    def close(self, cancel: bool = False) -> None:
        self._ex.shutdown(wait=not cancel, cancel_futures=cancel)


class _Ray:
    """A Ray cluster (``address``: 'auto', 'local' for a fresh local one, or ray://host:port)."""

    def __init__(self, address: str, threads: int = 1) -> None:
        try:
            import ray
        except ImportError:
            raise CampaignError(
                "--ray needs Ray, which is not installed: pip install 'uavmpc[cluster]'"
            ) from None
        self._ray = ray
        if not ray.is_initialized():
            # "local" is Ray's own word for "always start a new local instance" (None would
            # attach to a cluster that `ray start` left running on this machine)
            try:
                ray.init(address=address, ignore_reinit_error=True, log_to_driver=False)
            except (ConnectionError, ValueError) as exc:
                raise CampaignError(f"--ray {address}: cannot connect to Ray ({exc})") from None
        # ray leaves cluster_resources unannotated (a dict of resource name to amount)
        cpus = int(ray.cluster_resources().get("CPU", 1))  # type: ignore[no-untyped-call]
        self.capacity = 2 * max(cpus, 1)
        self._remote = ray.remote(num_cpus=threads)(run_task)
        self._threads = threads
        self._refs: list[ray.ObjectRef[TaskResult]] = []

    def submit(self, task: Task) -> None:
        self._refs.append(self._remote.remote(task, self._threads))

    def pending(self) -> int:
        return len(self._refs)

    def wait(self) -> list[TaskResult]:
        done, self._refs = self._ray.wait(self._refs, num_returns=1)
        return list(self._ray.get(done))

    def close(self, cancel: bool = False) -> None:
        if cancel:
            for ref in self._refs:
                self._ray.cancel(ref, force=True)
        self._refs = []


def check_workers(workers: int | None) -> int:
    """The number of local workers (default: one per CPU)."""
    if workers is None:
        workers = os.cpu_count() or 1
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise CampaignError(f"workers: must be an integer ≥ 1, got {workers!r}")
    return workers


def split_cores(workers: int | None, threads: int | None, *,
                say: bool = False) -> tuple[int, int]:
    """(workers, threads per worker) for a campaign on this machine's cores. Trials are the
    cheaper parallelism (no synchronisation per tick), so by default every core is a worker
    with one thread; given one of the two, the other takes the cores left (at least 1, at
    most :func:`~uavmpc.jit.default_threads`, which ``$UAVMPC_THREADS`` may lower). With
    ``say``, the split is printed on stderr, with a warning when the threads outnumber the
    cores (on this 2-core machine ``--workers 2 --threads 2`` ran 3.8× slower)."""
    from uavmpc.jit import available_threads, default_threads

    cores = available_threads()
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int)
                                or not 1 <= threads <= cores):
        raise CampaignError(f"threads: must be an integer from 1 to {cores} (this machine's "
                            f"cores), got {threads!r}")
    if workers is None:
        workers = cores if threads is None else max(1, cores // threads)
    workers = check_workers(workers)
    if threads is None:
        threads = max(1, min(default_threads(), cores // workers))
    if say:
        print(f"campaign: {workers} worker(s) × {threads} thread(s) each", file=sys.stderr)
        if workers * threads > cores:
            print(f"campaign: {workers} workers × {threads} threads = {workers * threads} "
                  f"threads on {cores} cores: a tick on threads waits for every one of them "
                  "and the OS parks some for the others; expect it several times slower than "
                  f"--workers {min(workers, cores)} --threads 1", file=sys.stderr)
    return workers, threads


@dataclass(frozen=True)
class Execution:
    """How a campaign's trials are flown, not what they fly (its records do not depend on it):
    ``workers`` local processes, each ticking a trial's world on ``threads`` threads (None:
    :func:`split_cores` chooses), or on Ray at ``ray_address`` ('auto', 'local' or
    ray://host:port); ``progress``: a progress bar and what the campaign does on stderr.
    Validated when made; the threads against this machine's cores when the trials start
    (:meth:`cores`), as the cores are the flying machine's."""

    workers: int | None = None
    threads: int | None = None
    ray_address: str | None = None
    progress: bool = True

    def __post_init__(self) -> None:
        if self.workers is not None:
            check_workers(self.workers)
        t = self.threads
        if t is not None and (isinstance(t, bool) or not isinstance(t, int) or t < 1):
            raise CampaignError(f"threads: must be an integer ≥ 1, got {t!r}")
        if self.ray_address is not None and (not isinstance(self.ray_address, str)
                                             or not self.ray_address.strip()):
            raise CampaignError(f"ray_address: must be 'auto', 'local' or ray://host:port, "
                                f"got {self.ray_address!r}")
        if not isinstance(self.progress, bool):
            raise CampaignError(f"progress: must be true or false, got {self.progress!r}")

    def cores(self) -> tuple[int, int]:
        """(workers, threads per worker) on this machine (:func:`split_cores`; said on
        stderr with ``progress``)."""
        return split_cores(self.workers, self.threads, say=self.progress)

    def on_this_machine(self) -> Execution:
        """This execution with its workers and threads as :meth:`cores` chooses them here."""
        workers, threads = self.cores()
        return dataclasses.replace(self, workers=workers, threads=threads)

    @property
    def counts(self) -> tuple[int, int]:
        """(workers, threads) as set (1 where not: :meth:`on_this_machine` sets both)."""
        return self.workers or 1, self.threads or 1


#: The default of a campaign flown from code: the machine's cores, nothing said on stderr.
QUIET = Execution(progress=False)


def executor(*, ray_address: str | None, workers: int, threads: int = 1) -> Executor:
    """Where tasks run: Ray, this process (one worker) or a local pool; each task's world
    ticks on ``threads`` threads."""
    if ray_address is not None:
        return _Ray(ray_address, threads)
    if workers == 1:
        return _Serial(threads)
    return _Pool(workers, threads)


# ------------------------------------------------------------------------------ storage
def stored_spec(out: str | Path, kind: str) -> dict[str, Any] | None:
    """The ``to_json`` of the campaign of kind ``kind`` stored in ``out`` (None: no campaign
    there yet). An unreadable file, another kind or an unknown format is a
    :class:`CampaignError` naming it."""
    path = Path(out) / CAMPAIGN_FILE
    if not path.exists():
        if (Path(out) / TRIALS_FILE).exists():
            raise CampaignError(
                f"{out} holds trials but no {CAMPAIGN_FILE} (a campaign written before "
                f"campaigns were resumable): use another --out folder")
        return None
    try:
        data = json.loads(path.read_text())
        fmt = data.get("format")
    except (ValueError, AttributeError) as exc:
        raise CampaignError(f"{path}: unreadable campaign file ({exc})") from None
    if fmt == 1 and kind == "random_walk" and isinstance(data.get("parameters"), dict):
        return dict(data["parameters"])  # format 1: a random walk's parameters, same fields
    if fmt != FORMAT:
        raise CampaignError(
            f"{path}: campaign file format {fmt!r} (written by uavmpc "
            f"{data.get('version', '?')}); this uavmpc reads format {FORMAT}: continue it with "
            f"the uavmpc that wrote it, or use another --out folder")
    if data.get("kind") != kind:
        raise CampaignError(f"{path}: a {data.get('kind')!r} campaign, not {kind!r}; use "
                            f"another --out folder")
    if not isinstance(data.get("spec"), dict):
        raise CampaignError(f"{path}: unreadable campaign file (no spec)")
    return dict(data["spec"])


def open_campaign(out: Path, spec: CampaignSpec,
                  load: Callable[[dict[str, Any]], CampaignSpec]) -> None:
    """Create ``out`` with ``spec``'s campaign.json, or check that the campaign stored there is
    ``spec`` (``load``: the spec type's ``from_json``)."""
    out.mkdir(parents=True, exist_ok=True)
    stored_json = stored_spec(out, spec.kind)
    if stored_json is None:
        from uavmpc import __version__

        (out / CAMPAIGN_FILE).write_text(json.dumps(
            {"format": FORMAT, "kind": spec.kind, "version": __version__,
             "spec": spec.to_json()}, indent=2) + "\n")
        return
    try:
        same = load(stored_json) == spec
    except (ConfigError, KeyError, TypeError, ValueError) as exc:
        raise CampaignError(f"{out / CAMPAIGN_FILE}: unreadable campaign spec ({exc})") from None
    if not same:
        now = json.loads(json.dumps(spec.to_json()))  # as it would be stored
        diff = ", ".join(f"{k}: {stored_json.get(k)!r} there, {now.get(k)!r} now"
                         for k in sorted(set(stored_json) | set(now))
                         if stored_json.get(k) != now.get(k))
        raise CampaignError(
            f"{out} holds a campaign with other parameters ({diff or 'as written'}); use "
            f"another --out folder, or the same parameters to continue it")


def load_records(out: str | Path, foreign: Callable[[int, dict[str, Any]], str | None]
                 ) -> dict[int, dict[str, Any]]:
    """The finished trials in ``out`` by index (a torn last line is dropped); ``foreign`` says
    why a record is not of this campaign (None: it is)."""
    path = Path(out) / TRIALS_FILE
    if not path.exists():
        return {}
    data = path.read_bytes()
    end = data.rfind(b"\n") + 1
    if end < len(data):  # a crash mid-write: drop the partial line so appends stay valid
        with open(path, "r+b") as f:
            f.truncate(end)
        data = data[:end]
    trials: dict[int, dict[str, Any]] = {}
    for n, line in enumerate(data.decode().splitlines(), 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
            i = int(rec["index"])
        except (ValueError, KeyError, TypeError) as exc:
            raise CampaignError(f"{path}:{n}: not a trial record ({exc})") from None
        why = foreign(i, rec)
        if why is not None:
            raise CampaignError(f"{path}:{n}: trial {i} {why}; the file belongs elsewhere")
        trials.setdefault(i, rec)
    return trials


def iter_trials(out_dir: str | Path) -> Iterator[dict[str, Any]]:
    """The trial records of a campaign folder, in file order."""
    path = Path(out_dir) / TRIALS_FILE
    if path.exists():
        for line in path.read_text().splitlines():
            if line.strip():
                yield json.loads(line)


def append(f: IO[str], rec: dict[str, Any]) -> None:
    f.write(json.dumps(rec) + "\n")
    f.flush()
    os.fsync(f.fileno())


def campaign_wall_s(out: Path, wall0: float) -> float:
    """The wall time spent on the campaign over all its runs so far."""
    runs = out / RUNS_FILE
    return (sum(json.loads(line)["wall_s"] for line in runs.read_text().splitlines()
                if line.strip()) if runs.exists() else time.perf_counter() - wall0)


# ------------------------------------------------------------------------------ progress
class Progress:
    def __init__(self, enabled: bool, stream: TextIO | None = None) -> None:
        self.enabled = enabled
        self.stream = stream if stream is not None else sys.stderr
        self.t0 = time.perf_counter()
        self.width = 0

    def show(self, done: int, total: int | None, sim_h: float | None, new: int) -> None:
        """``sim_h``: the simulated hours of the ``done`` trials (None: they do not say)."""
        if not self.enabled:
            return
        el = time.perf_counter() - self.t0
        tot = f"{total}" if total is not None else "?"
        eta = "?"
        if new > 0 and total is not None:
            eta = _hms(el / new * max(total - done, 0))
        frac = done / total if total else 0.0
        bar = "#" * int(20 * min(frac, 1.0))
        sim = "" if sim_h is None else f"{sim_h:.2f} h simulated, "
        line = f"\r[{bar:<20}] {done}/{tot} trials, {sim}{_hms(el)} elapsed, ETA {eta}"
        self.width = max(self.width, len(line))
        self.stream.write(line.ljust(self.width))
        self.stream.flush()

    def end(self) -> None:
        if self.enabled:
            self.stream.write("\n")
            self.stream.flush()


def _hms(seconds: float) -> str:
    s = round(seconds)
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


# ------------------------------------------------------------------------------ selection
def selected(trials: dict[int, dict[str, Any]], n_trials: int | None,
             target_s: float | None) -> tuple[list[dict[str, Any]], bool]:
    """The trials a report covers (an index prefix: ``n_trials`` of them, or the shortest
    whose ``sim_s`` add up to ``target_s``) and whether that prefix is complete."""
    out: list[dict[str, Any]] = []
    total = 0.0
    i = 0
    while True:
        if n_trials is not None and i >= n_trials:
            return out, True
        if target_s is not None and total >= target_s - 1e-9:
            return out, True
        rec = trials.get(i)
        if rec is None:
            return out, False
        out.append(rec)
        if target_s is not None:
            total += rec["sim_s"]
        i += 1


@dataclass
class _Run:
    """The state of one invocation's loop over the missing trials."""

    spec: CampaignSpec
    trials: dict[int, dict[str, Any]]
    n_trials: int | None
    target_s: float | None
    max_trial_s: float
    progress: Progress
    nxt: int = 0
    new: int = 0

    def status(self) -> None:
        sel, _ = selected(self.trials, self.n_trials, self.target_s)
        sim_h = (sum(r["sim_s"] for r in sel) / 3600.0
                 if sel and all("sim_s" in r for r in sel) else None)
        total = self.n_trials
        if total is None and self.target_s is not None:
            done = self.trials.values()
            mean = (sum(r["sim_s"] for r in done) / len(done)) if done else 0
            total = max(len(sel), math.ceil(self.target_s / mean)) if mean > 0 else None
        self.progress.show(len(sel), total, sim_h, self.new)

    def want_more(self) -> bool:
        if self.n_trials is not None:
            return self.nxt < self.n_trials
        # hours: submit while the done prefix plus in-flight trials at their longest might
        # still fall short of the target
        assert self.target_s is not None
        bound = sum(self.trials[i]["sim_s"] if i in self.trials else self.max_trial_s
                    for i in range(self.nxt))
        return bound < self.target_s - 1e-9


def _execute(out: Path, run: _Run, ex: Executor) -> None:
    """Runs the missing trials until the selection is complete."""
    parts: dict[int, dict[int, dict[str, Any]]] = {}  # trial → its parts done so far
    counts: dict[int, int] = {}
    queue: list[Task] = []
    run.status()
    with open(out / TRIALS_FILE, "a") as f:
        try:
            while True:
                while ex.pending() < ex.capacity and (queue or run.want_more()):
                    if not queue:
                        if run.nxt not in run.trials:
                            queue = run.spec.tasks(run.nxt)
                            counts[run.nxt] = len(queue)
                        run.nxt += 1
                        continue
                    ex.submit(queue.pop(0))
                if not ex.pending():
                    break
                for index, part, result in ex.wait():
                    parts.setdefault(index, {})[part] = result
                    if len(parts[index]) < counts[index]:
                        continue
                    done = parts.pop(index)
                    rec = run.spec.record(index, [done[k] for k in sorted(done)])
                    run.trials[index] = rec
                    append(f, rec)
                    run.new += 1
                    run.status()
        except BaseException:
            ex.close(cancel=True)
            run.progress.end()
            raise
    ex.close()
    run.progress.end()


def run_trials(out: Path, spec: CampaignSpec, load: Callable[[dict[str, Any]], CampaignSpec],
               execution: Execution, *, trials: int | None, target_s: float | None = None,
               max_trial_s: float = math.inf) -> list[dict[str, Any]]:
    """Open (or continue) the campaign ``spec`` in ``out`` and fly its missing trials as
    ``execution`` says (its cores chosen: :meth:`Execution.on_this_machine`); the records of
    the selection (``trials`` of them, or the shortest prefix whose ``sim_s`` reach
    ``target_s``; ``max_trial_s``: a trial's longest ``sim_s``), sorted by index."""
    workers, threads = execution.counts
    open_campaign(out, spec, load)
    done = load_records(out, spec.foreign)
    wall0 = time.perf_counter()
    if not selected(done, trials, target_s)[1]:
        ex = executor(ray_address=execution.ray_address, workers=workers, threads=threads)
        before = len(done)
        try:
            _execute(out, _Run(spec, done, trials, target_s, max_trial_s,
                               Progress(execution.progress)), ex)
        finally:  # also when interrupted: the time was spent on this campaign
            with open(out / RUNS_FILE, "a") as f:
                append(f, {"wall_s": time.perf_counter() - wall0,
                            "new_trials": len(done) - before, "workers": workers,
                            "threads": threads, "ray": execution.ray_address})
    chosen, complete = selected(done, trials, target_s)
    assert complete
    return chosen
