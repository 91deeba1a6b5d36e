"""Batch runs of a sweep over MPI ranks: ``rackstress batch SWEEP.toml``.

``mpiexec -n K rackstress batch SWEEP.toml --ranks-per-job J`` splits COMM_WORLD into K/J groups
of J ranks (``Split(color = rank // J)``); each group runs one job at a time, one LAMMPS instance
on its sub-communicator. Without ``mpiexec`` the jobs run one after another.

**Hand-out.** World rank 0 is the manager. It hands out job indices on request, in order, so a
slow job holds up only its own group. By default the manager is a thread on rank 0 that polls for
requests (``Iprobe``, then sleeps 10 ms: it costs no core) while rank 0's own group runs jobs
too; this needs ``MPI_THREAD_MULTIPLE`` (``rackstress batch`` asks for it before MPI starts, where
the rest of rackstress asks for ``funneled``: lib/mpi.py; MPICH gives it). ``--manager rank``
(or a library without it) makes rank 0 a manager only, and the other K−1 ranks form the groups.
A group's root asks the manager (reporting the job it finished), then tells its members the job
with a broadcast on the sub-communicator. Every wait on another rank polls and sleeps, so idle
ranks do not spin.

**Atomic job directories.** A job runs into ``BATCHDIR/.tmp-NAME-PID``; once its
``summary.json`` is written (``ok``, ``diverged`` by the watchdog, ``not settled`` (a static
analysis whose residual stayed above its tolerance), or ``failed`` with the error)
the directory is renamed to ``BATCHDIR/NAME`` (``os.replace``): a job directory is complete or
absent. A job is finished iff ``BATCHDIR/NAME/summary.json`` exists.

**Restarting.** ``rackstress batch`` on a batch directory that holds part of the same sweep
removes leftover ``.tmp-*`` directories and runs only the unfinished jobs (``--retry-failed``
also reruns failed ones). Nothing finished is lost or run again: a run killed at any moment
leaves only complete job directories and temporary ones.

**Index.** ``BATCHDIR/batch.json`` is written only by the manager, atomically (temp file +
``os.replace``), after every hand-out and completion: every job with its parameters, status
(pending, running, ok, diverged, not settled, failed), attempts, group, wall time, error and summary figures,
and one entry per pass (ranks, groups, wall time). ``BATCHDIR/events.log`` gets one line when a
job starts and one when it ends (appended by the group root that runs it), so how often each job
ran is checkable from outside. ``BATCHDIR/.lock`` (``flock``) keeps two batches out of one
directory.
"""
from __future__ import annotations

import fcntl
import inspect
import json
import re
import os
import shutil
import threading
import time
from pathlib import Path

from rackstress.errors import DivergenceError, RackstressError, RunDirError, storage_error
from rackstress.lib.mpi import on_root
from rackstress.runs.sweep import Sweep, SweepError, load_sweep

INDEX = "batch.json"
EVENTS = "events.log"
TAG_REQ, TAG_REP = 7101, 7102
#: Poll intervals (s) of the manager thread and of ranks waiting on another rank.
MANAGER_POLL, WAIT_POLL = 0.01, 0.002
FINISHED = ("ok", "diverged", "not settled", "failed")


# ---------------------------------------------------------------------------- small helpers
def _write_json(path: Path, data) -> None:
    from rackstress.lib.jsonio import write_json

    write_json(path, data)


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S")


def _event(batchdir: Path, text: str) -> None:
    """Append one line to events.log (one write on an O_APPEND file: lines do not interleave)."""
    line = f"{_now()} {text} pid={os.getpid()}\n".encode()
    fd = os.open(batchdir / EVENTS, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, line)
    finally:
        os.close(fd)


def _wait(req, poll: float = WAIT_POLL):
    """Complete an MPI request without spinning a core."""
    while True:
        done, value = req.test()
        if done:
            return value
        time.sleep(poll)


def _sleepy_bcast(comm, obj, root: int = 0):
    """A broadcast whose waiters sleep between polls (members idle while their root asks)."""
    if comm.Get_size() == 1:
        return obj
    if comm.Get_rank() == root:
        reqs = [comm.isend(obj, dest=r, tag=TAG_REP + 1) for r in range(comm.Get_size()) if r != root]
        for r in reqs:
            _wait(r)
        return obj
    return _wait(comm.irecv(source=root, tag=TAG_REP + 1))


def _sleepy_barrier(comm):
    req = comm.Ibarrier()
    while not req.Test():
        time.sleep(MANAGER_POLL)


def figures(summary: dict) -> dict:
    """The summary figures kept in the index: steps, status facts, per group max_deformation."""
    out = {"steps": summary.get("steps"), "n_particles": summary.get("n_particles")}
    for g, rec in (summary.get("groups") or {}).items():
        out[f"groups.{g}.max_deformation"] = rec.get("max_deformation")
        for m, pk in (rec.get("peak") or {}).items():
            if pk is not None:
                out[f"groups.{g}.peak.{m}.value"] = pk.get("value")
    cycles = (summary.get("report") or {}).get("cycles") or []
    if cycles:
        for k, v in cycles[-1].items():
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                out[f"report.cycles.-1.{k}"] = v
    return out


def lookup(summary: dict, dotted: str):
    """``groups.plane.max_deformation``, ``groups.plane.com_end.1``, ``report.cycles.-1.advance``."""
    cur = summary
    for part in dotted.split("."):
        if isinstance(cur, dict):
            if part not in cur:
                return None
            cur = cur[part]
        elif isinstance(cur, list):
            try:
                cur = cur[int(part)]
            except (ValueError, IndexError):
                return None
        else:
            return None
    return cur


# ---------------------------------------------------------------------------- one job
def run_job(job, sweep: Sweep, batchdir: Path, comm, group: int, post=None) -> dict | None:
    """Run one job on the ranks of ``comm`` into its own directory; the root returns its record.

    ``post(rundir)``: post-processing of a finished job on its root (the CLI passes the stress
    peaks of :mod:`rackstress.stress.post`, which this layer may not import); a failure there is
    recorded in the job's ``post_error`` and the job stays ``ok``.

    Every outcome leaves a complete ``BATCHDIR/NAME`` (summary.json with the status); only a
    killed process leaves a ``.tmp-`` directory behind.
    """
    from rackstress.runs import run as run_mod

    root = comm.Get_rank() == 0
    tmp = batchdir / f".tmp-{job.name}-{os.getpid()}"
    tmp = Path(_sleepy_bcast(comm, str(tmp)))
    t0 = time.perf_counter()
    started = _now()
    if root:
        _event(batchdir, f"start {job.name} group={group} ranks={comm.Get_size()}")
    status, error, summary = "ok", None, None
    try:
        scene = job.build(sweep.spec)
        kw = dict(engine=job.engine, mode=job.mode, dump_every=job.dump_every, progress=False,
                  overwrite=True, comm=comm)
        if job.allow_unstable and "allow_unstable" in inspect.signature(run_mod.run).parameters:
            kw["allow_unstable"] = True
        summary = run_mod.run(scene, tmp, **kw)
        if isinstance(summary, dict) and summary.get("settled") is False:
            # the run is complete and its summary says so; `rackstress run` would exit 6
            status = "not settled"
            error = (f"the static analysis did not settle: the largest unbalanced force is "
                     f"{summary.get('residual', float('nan')):.3g} of the applied load after "
                     f"{summary.get('iterations')} iterations")
    except DivergenceError as exc:
        status, error = "diverged", str(exc)
    except Exception as exc:  # noqa: BLE001 - a failed job is recorded, the batch goes on
        status, error = "failed", f"{type(exc).__name__}: {exc}"
    wall = time.perf_counter() - t0
    if not root:
        return None
    final = batchdir / job.name
    tmp.mkdir(parents=True, exist_ok=True)
    post_error = None
    if post is not None and status == "ok" and summary is not None:
        try:
            post(tmp)
            summary = json.loads((tmp / "summary.json").read_text())
        except Exception as exc:  # noqa: BLE001 - the run is complete; its figures stay
            post_error = f"{type(exc).__name__}: {exc}"
    if status != "ok" or summary is None:
        try:
            summary = json.loads((tmp / "summary.json").read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            summary = {"scene": sweep.scene, "status": status, "params": job.scene_sets,
                       "error": {"message": error}}
            _write_json(tmp / "summary.json", summary)
    rec = {"name": job.name, "index": job.index, "params": job.params, "status": status,
           "error": error, "wall_s": wall, "group": group, "ranks": comm.Get_size(),
           "started": started, "ended": _now(), "figures": figures(summary)}
    if post_error is not None:
        rec["post_error"] = post_error
    _write_json(tmp / "job.json", {**job.record(), **rec})
    if final.exists():          # only possible if someone else made it: never half a job
        shutil.rmtree(final)
    os.replace(tmp, final)
    _event(batchdir, f"end {job.name} {status}")
    return rec


def _discard_job(jobdir: Path) -> None:
    """Remove a failed job's directory to run it again, unless it holds files no rackstress
    command wrote (then refused, naming them: the user's files are never removed)."""
    from rackstress.lib.runfiles import RUN_FILES
    from rackstress.runs.rundir import owned, present

    # the directory was made by the batch (a renamed temporary one): a run's names are its own
    theirs = sorted(present(jobdir) - owned(jobdir) - set(RUN_FILES))
    if theirs:
        raise RunDirError(f"{jobdir} holds {', '.join(theirs[:6])}, which rackstress did not "
                          "write: --retry-failed would remove the job's directory with them; "
                          "move them away first")
    shutil.rmtree(jobdir)


# ---------------------------------------------------------------------------- the manager
class Manager:
    """World rank 0's job table: hands out jobs, records results, writes batch.json."""

    def __init__(self, sweep: Sweep, batchdir: Path, groups: int, world, log=print,
                 retry_failed: bool = False, ranks_per_job: int = 1, mode: str = "thread"):
        self.sweep, self.dir, self.world, self.log = sweep, batchdir, world, log
        self.lock = threading.Lock()
        self.groups = groups
        self.retired: set[int] = set()
        self.t0 = time.perf_counter()
        self.jobs = {j.name: {"name": j.name, "index": j.index, "params": j.params,
                              "status": "pending", "attempts": 0, "dir": j.name,
                              "wall_s": None, "error": None, "figures": {}}
                     for j in sweep.jobs}
        old = {}
        try:
            prev = json.loads((batchdir / INDEX).read_text())
            old = {j["name"]: j for j in prev.get("jobs", [])}
            self.passes = list(prev.get("passes", []))
            self.created = prev.get("created", _now())
        except (FileNotFoundError, json.JSONDecodeError):
            self.passes, self.created = [], _now()
        for name, rec in self.jobs.items():
            if name in old:
                rec["attempts"] = int(old[name].get("attempts", 0))
            done = batchdir / name / "summary.json"
            if done.exists():
                self._adopt(name, batchdir / name, old.get(name))
            if rec["status"] == "failed" and retry_failed:
                _discard_job(batchdir / name)
                rec.update(status="pending", error=None, figures={}, wall_s=None)
        self.queue = [j.index for j in sweep.jobs if self.jobs[j.name]["status"] == "pending"]
        self.by_index = {j.index: j for j in sweep.jobs}
        self.pass_rec = {"started": _now(), "ended": None, "ranks": world.Get_size(),
                         "ranks_per_job": ranks_per_job, "groups": groups, "manager": mode,
                         "wall_s": None, "jobs_run": 0, "jobs_todo": len(self.queue)}
        self.passes.append(self.pass_rec)
        self.done_count = sum(r["status"] in FINISHED for r in self.jobs.values())
        self.write()

    def _adopt(self, name: str, jobdir: Path, old: dict | None) -> None:
        """A finished job directory found on disk: take its record (job.json, else summary)."""
        rec = self.jobs[name]
        try:
            j = json.loads((jobdir / "job.json").read_text())
            rec.update({k: j[k] for k in ("status", "error", "wall_s", "group", "ranks",
                                          "started", "ended", "figures") if k in j})
        except (FileNotFoundError, json.JSONDecodeError):
            s = json.loads((jobdir / "summary.json").read_text())
            status = {"settled": "ok"}.get(s.get("status", "ok"), s.get("status", "ok"))
            rec.update(status=status, wall_s=s.get("wall_s"), figures=figures(s),
                       error=(s.get("error") or {}).get("message"))

    def write(self) -> None:
        counts = {}
        for r in self.jobs.values():
            counts[r["status"]] = counts.get(r["status"], 0) + 1
        self.pass_rec["wall_s"] = time.perf_counter() - self.t0
        _write_json(self.dir / INDEX, {
            "sweep": "sweep.toml", "source": str(self.sweep.path), "name": self.sweep.name,
            "scene": self.sweep.scene, "swept": self.sweep.swept, "created": self.created,
            "updated": _now(), "complete": all(r["status"] in FINISHED for r in self.jobs.values()),
            "counts": counts, "passes": self.passes,
            "jobs": sorted(self.jobs.values(), key=lambda r: r["index"])})

    def next(self, group: int, result: dict | None):
        """Record ``result`` (the job the group finished, if any); hand out the next job index
        or None (the group then retires)."""
        with self.lock:
            if result is not None:
                rec = self.jobs[result["name"]]
                rec.update({k: v for k, v in result.items() if k not in ("name", "index", "params")})
                self.pass_rec["jobs_run"] += 1
                self.done_count += 1
                self.log(f"[{self.done_count}/{len(self.jobs)}] {rec['name']}: {rec['status']} "
                         f"in {rec['wall_s']:.2f} s (group {group})"
                         + (f" - {rec['error']}" if rec["error"] else ""))
            if self.queue:
                idx = self.queue.pop(0)
                rec = self.jobs[self.by_index[idx].name]
                rec["status"] = "running"
                rec["attempts"] += 1
                rec["group"] = group
                self.write()
                # no silent minutes: a long job is seen starting, not only ending
                self.log(f"  {rec['name']}: started (group {group})")
                return idx
            self.retired.add(group)
            if len(self.retired) == self.groups:
                self.pass_rec["ended"] = _now()
            self.write()
            return None

    def serve(self) -> None:
        """Answer remote groups' requests until every group has retired (thread or rank 0)."""
        from mpi4py import MPI

        st = MPI.Status()
        while True:
            with self.lock:
                if len(self.retired) == self.groups:
                    return
            if self.world.iprobe(source=MPI.ANY_SOURCE, tag=TAG_REQ, status=st):
                src = st.Get_source()
                group, result = self.world.recv(source=src, tag=TAG_REQ)
                self.world.send(self.next(group, result), dest=src, tag=TAG_REP)
            else:
                time.sleep(MANAGER_POLL)


# ---------------------------------------------------------------------------- the batch
def prepare_dir(sweep: Sweep, batchdir: Path) -> None:
    """Create the batch directory, or check it holds this sweep; remove leftover .tmp dirs."""
    batchdir.mkdir(parents=True, exist_ok=True)
    copy = batchdir / "sweep.toml"
    text = Path(sweep.path).read_text()
    index = batchdir / INDEX
    if index.exists():
        prev = json.loads(index.read_text())
        mine = {j.name: j.params for j in sweep.jobs}
        theirs = {j["name"]: j["params"] for j in prev.get("jobs", [])}
        if mine != theirs or prev.get("scene") != sweep.scene:
            raise RunDirError(f"{batchdir} holds another sweep ({prev.get('source')}); give "
                              "another --out, or remove it")
        if copy.exists() and copy.read_text() != text:
            # same jobs, edited file (e.g. comments or steps): keep the first as sweep.toml
            (batchdir / f"sweep-{time.strftime('%Y%m%d-%H%M%S')}.toml").write_text(text)
    # never over the user's files: a file or folder of the user's named like a job or the
    # batch's own files is refused, naming it (runs/rundir.py's manifest)
    from rackstress.runs.rundir import _adopt, manifest, own, present

    names = [INDEX, EVENTS, "report.html"] + [j.name for j in sweep.jobs]
    if index.exists() and manifest(batchdir) is None:   # a batch from before the manifest
        _adopt(batchdir, set(names) & present(batchdir))
    own(batchdir, names, "the batch")
    if not copy.exists():
        copy.write_text(text)
    for tmp in batchdir.glob(".tmp-*"):
        shutil.rmtree(tmp, ignore_errors=True)


def run_batch(sweep_path, out=None, ranks_per_job: int = 1, retry_failed: bool = False,
              manager: str = "thread", log=print, comm=None, post=None) -> dict | None:
    """Run (or finish) a sweep; world rank 0 returns the index, other ranks None.

    ``post(rundir)`` post-processes each finished job (see :func:`run_job`)."""
    from mpi4py import MPI

    world = comm or MPI.COMM_WORLD
    rank, size = world.Get_rank(), world.Get_size()
    J = int(ranks_per_job)
    if manager not in ("thread", "rank"):
        raise SweepError(f"--manager must be 'thread' or 'rank', got {manager!r}")
    if size > 1 and manager == "thread" and MPI.Query_thread() < MPI.THREAD_MULTIPLE:
        manager = "rank"        # no threads with MPI: a manager rank that computes nothing
    if size == 1:
        manager = "thread"      # nothing to serve: rank 0 just runs the jobs
    workers = size if manager == "thread" else size - 1
    if J < 1 or workers < J or workers % J:
        raise SweepError(f"--ranks-per-job {J} does not divide the {workers} working rank(s) "
                         f"({size} rank(s){', rank 0 managing' if manager == 'rank' else ''})")
    groups = workers // J
    sweep = load_sweep(sweep_path)
    batchdir = Path(out) if out is not None else Path("batches") / Path(sweep_path).stem

    state = {}

    def prepare():
        sweep.validate(J)
        try:
            batchdir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise storage_error(exc, "create the batch directory", batchdir) from None
        state["lockfd"] = fd = os.open(batchdir / ".lock", os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise RunDirError(f"{batchdir} is in use by another running batch") from None
        prepare_dir(sweep, batchdir)
        state["mgr"] = m = Manager(sweep, batchdir, groups, world, log=log,
                                   retry_failed=retry_failed, ranks_per_job=J, mode=manager)
        log(f"batch {sweep.name}: {len(sweep.jobs)} jobs, {len(m.queue)} to run, "
            f"{size} rank(s), {groups} group(s) of {J}, manager: "
            f"{'rank 0 (thread)' if manager == 'thread' else 'rank 0 only'} -> {batchdir}")

    # rank 0 checks every job, prepares the directory and locks it; all ranks learn the outcome
    on_root(prepare, world)
    lockfd, mgr = state.get("lockfd"), state.get("mgr")

    if manager == "thread":
        color = rank // J
    else:
        color = MPI.UNDEFINED if rank == 0 else (rank - 1) // J
    sub = world.Split(color, key=rank)
    thread = None
    try:
        if rank == 0 and size > 1:
            if manager == "thread":
                thread = threading.Thread(target=mgr.serve, name="rackstress-batch-manager",
                                          daemon=True)
                thread.start()
            else:
                mgr.serve()
        if sub != MPI.COMM_NULL:
            _work(sweep, batchdir, world, sub, color, mgr, post)
        if thread is not None:
            thread.join()
    finally:
        if sub != MPI.COMM_NULL:
            sub.Free()
    if size > 1:
        _sleepy_barrier(world)
    if rank == 0:
        mgr.write()
        os.close(lockfd)
        return json.loads((batchdir / INDEX).read_text())
    return None


def _work(sweep: Sweep, batchdir: Path, world, sub, group: int, mgr, post=None) -> None:
    """A group's loop: the root asks for jobs, the members follow; all run each job."""
    root = sub.Get_rank() == 0
    result = None
    while True:
        if root:
            if world.Get_rank() == 0:
                idx = mgr.next(group, result)
            else:
                _wait(world.isend((group, result), dest=0, tag=TAG_REQ))
                idx = _wait(world.irecv(source=0, tag=TAG_REP))
        else:
            idx = None
        idx = _sleepy_bcast(sub, idx)
        if idx is None:
            return
        job = next(j for j in sweep.jobs if j.index == idx)
        result = run_job(job, sweep, batchdir, sub, group, post)


# ---------------------------------------------------------------------------- report
def report(batchdir, figure: str | None = None, against: str | None = None, log=print) -> dict:
    """Print a table of ``figure`` per job and plot it against a swept parameter; return
    {'rows', 'figure', 'against', 'plot'}."""
    batchdir = Path(batchdir)
    try:
        index = json.loads((batchdir / INDEX).read_text())
    except FileNotFoundError:
        raise RunDirError(f"{batchdir} is not a batch directory (no {INDEX})") from None
    jobs = index["jobs"]
    swept = index.get("swept") or sorted({k for j in jobs for k in j["params"]})
    summaries = {}
    for j in jobs:
        try:
            summaries[j["name"]] = json.loads((batchdir / j["dir"] / "summary.json").read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            summaries[j["name"]] = {}
    if figure is None:
        first = next((s for s in summaries.values() if s.get("groups")), {})
        g = next(iter(first.get("groups", {"?": 0})))
        figure = f"groups.{g}.max_deformation"
    # a peak (groups.G.peak.M, summary.json after the stress post-processing): its value, and
    # where and when it was, as extra columns
    peak = re.fullmatch(r"(groups\.[^.]+\.peak\.[^.]+)(\.value)?", figure)
    if peak:
        figure = peak.group(1) + ".value"
    if against is None:
        if not swept:
            raise RackstressError(f"{batchdir}: the sweep varies nothing to plot against")
        against = swept[0]
    if against not in swept:
        raise RackstressError(f"--against {against!r}: not a swept parameter "
                              f"(swept: {', '.join(swept)})")
    rows = []
    for j in jobs:
        s = summaries[j["name"]]
        val = lookup(s, figure) if j["status"] == "ok" else None
        # a parameter the job did not set: the value it ran with (its summary's params)
        eff = {k: j["params"].get(k, (s.get("params") or {}).get(k, s.get(k))) for k in swept}
        rows.append({"name": j["name"], **eff,
                     "status": j["status"], figure: val, "wall_s": j.get("wall_s"),
                     "attempts": j.get("attempts")})
        if peak:
            rec = lookup(s, peak.group(1)) if j["status"] == "ok" else None
            rows[-1]["iteration"] = (rec or {}).get("iteration")
            rows[-1]["particle"] = (rec or {}).get("particle")
    oks = [summaries[j["name"]] for j in jobs if j["status"] == "ok" and summaries[j["name"]]]
    if oks and all(lookup(x, figure) is None for x in oks):
        known = sorted(_figure_paths(oks[0]), key=lambda k: not k.startswith("groups."))
        raise RackstressError(f"--figure {figure!r}: no finished job's summary.json has it; "
                              f"figures there are e.g. {', '.join(known[:8])}"
                              f"{', ...' if len(known) > 8 else ''}")
    cols = ["name", *swept, "status", figure, *(("iteration", "particle") if peak else ()),
            "wall_s"]

    def cell(v):
        if v is None:
            return "-"
        if isinstance(v, float):
            return f"{v:.6g}"
        if isinstance(v, list):
            return "[" + ", ".join(cell(x) for x in v) + "]"
        return str(v)
    table = [[cell(r.get(c)) for c in cols] for r in rows]
    widths = [max(len(c), *(len(t[i]) for t in table)) for i, c in enumerate(cols)]
    log("  ".join(c.ljust(w) for c, w in zip(cols, widths)))
    for t in table:
        log("  ".join(x.ljust(w) for x, w in zip(t, widths)))
    counts = index.get("counts", {})
    log(f"{len(jobs)} jobs: " + ", ".join(f"{v} {k}" for k, v in sorted(counts.items()))
        + ("" if index.get("complete") else " (batch not complete)"))
    plot = _plot(batchdir, rows, figure, against, [k for k in swept if k != against])
    log(f"plot: {plot}")
    return {"rows": rows, "figure": figure, "against": against, "plot": plot}


def _figure_paths(summary: dict, prefix: str = "") -> list[str]:
    """Dotted paths of the numeric figures in a summary (what --figure can name)."""
    out = []
    for k, v in summary.items():
        path = f"{prefix}{k}"
        if isinstance(v, dict):
            out += _figure_paths(v, path + ".")
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            out.append(path)
    return out


def _plot(batchdir: Path, rows, figure: str, against: str, others) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    series = {}
    for r in rows:
        key = tuple((k, r.get(k)) for k in others)
        series.setdefault(key, []).append(r)
    numeric = all(isinstance(r.get(against), (int, float)) or r.get(against) is None for r in rows)
    for key, rs in series.items():
        pts = [(r.get(against), r[figure]) for r in rs
               if r.get(against) is not None and isinstance(r[figure], (int, float))]
        bad = [r.get(against) for r in rs if r.get(against) is not None and r["status"] != "ok"]
        label = ", ".join(f"{k}={v}" for k, v in key if v is not None) or None
        if numeric:
            pts.sort()
        xs = [p[0] if numeric else str(p[0]) for p in pts]
        line, = ax.plot(xs, [p[1] for p in pts], "o-", label=label)
        for b in bad:
            ax.axvline(b if numeric else str(b), color=line.get_color(), ls=":", lw=1)
    xs_all = [r.get(against) for r in rows if isinstance(r.get(against), (int, float))]
    if numeric and xs_all and min(xs_all) > 0 and max(xs_all) / min(xs_all) > 100:
        ax.set_xscale("log")
    ax.set_xlabel(against)
    ax.set_ylabel(figure)
    ax.set_title(f"{figure} against {against}\n(dotted: diverged, not settled or failed jobs)", fontsize=9)
    if any(k for k in series if any(v is not None for _, v in k)):
        ax.legend(fontsize=7)
    fig.tight_layout()
    safe = "".join(c if c.isalnum() or c in "._-" else "_" for c in f"{figure}-vs-{against}")
    path = batchdir / f"report-{safe}.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
