"""Sweep files: one scene, the parameters to vary, as a grid and/or an explicit list of jobs.

```toml
scene = "plane-rack"          # a built-in scene or a scene .toml (relative to this file)
engine = "lammps"             # lammps | reference            (default lammps)
mode = "exact"                # exact | fast                  (default exact)
steps = 600                   # iterations of every job       (default: the scene's)
# dt = 0.01                   # time step                     (default: the scene's)
# dump_every = 100            # trajectory frames             (default: ~100 a run)
# allow_unstable = false      # run jobs the stability check would refuse

[params]                      # scene parameters fixed for every job (like --set)
n = 20

[grid]                        # cartesian product: 2 × 3 = 6 jobs
dt = [0.01, 0.005]
plane_bind = [50, 100, 200]

[[job]]                       # and/or explicit jobs, each with its own values
name = "stiff"                # optional: [A-Za-z0-9._=+-], unique
plane_bind = 1e5
allow_unstable = true
```

In ``[grid]``, ``[[job]]`` and ``[params]``, the keys ``dt``, ``mode``, ``steps``, ``engine``,
``dump_every`` and ``allow_unstable`` set the run; every other key is a scene parameter
(``rackstress scenes`` lists them). Grid jobs are named ``gNNN-key=value-...`` (the keys with more
than one value), explicit jobs
``jNNN`` unless named. Errors name the file and the table or field.
"""
from __future__ import annotations

import itertools
import re
from dataclasses import dataclass, field
from pathlib import Path

from rackstress.errors import SceneError

#: Keys that set the run rather than the scene.
RUN_KEYS = ("dt", "mode", "steps", "engine", "dump_every", "allow_unstable")
TOP_KEYS = ("scene", "name", "params", "grid", "job") + RUN_KEYS
ENGINES = ("lammps", "reference")
MODES = ("exact", "fast")
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._=+-]{0,99}$")


class SweepError(SceneError):
    """A sweep file is malformed; the message names the file and the table or field."""


@dataclass
class Job:
    index: int
    name: str
    #: the values this job varies (grid point or explicit job table), as written
    params: dict
    #: scene parameter overrides: the sweep's [params] and this job's scene keys
    scene_sets: dict
    engine: str = "lammps"
    mode: str = "exact"
    steps: int | None = None
    dt: float | None = None
    dump_every: int | None = None
    allow_unstable: bool = False

    def build(self, spec: str):
        """The job's scene (as ``rackstress run SPEC --set ... --steps --dt`` builds it)."""
        from rackstress import scenes

        sc = scenes.load(spec, dict(self.scene_sets))
        if self.dt is not None:
            sc = sc.with_dt(float(self.dt))   # a scene given by duration keeps its time
        if self.steps is not None:
            sc = sc.with_steps(int(self.steps))
        return sc

    def record(self) -> dict:
        return {"index": self.index, "name": self.name, "params": self.params,
                "engine": self.engine, "mode": self.mode, "steps": self.steps, "dt": self.dt,
                "allow_unstable": self.allow_unstable, "scene_sets": self.scene_sets}


@dataclass
class Sweep:
    path: Path
    name: str
    scene: str          # as given in the file
    spec: str           # what scenes.load takes (a built-in name or an absolute .toml path)
    jobs: list
    swept: list = field(default_factory=list)   # the names of the varied parameters, in order

    def validate(self, ranks_per_job: int = 1) -> None:
        """Build every job's scene (raises SweepError naming the job) before anything runs."""
        for job in self.jobs:
            if job.engine == "reference" and ranks_per_job != 1:
                raise SweepError(f"{self.path}: job '{job.name}': the reference engine runs on "
                                 f"one rank; use --ranks-per-job 1 (got {ranks_per_job})")
            try:
                job.build(self.spec)
            except SceneError as exc:
                raise SweepError(f"{self.path}: job '{job.name}' {job.params}: {exc}") from None


def _err(path, where, msg) -> SweepError:
    return SweepError(f"{path}: {where}: {msg}")


def _check_run_value(path, where, key, value):
    if key == "dt":
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
            raise _err(path, where, f"dt must be a positive number, got {value!r}")
        return float(value)
    if key in ("steps", "dump_every"):
        if isinstance(value, bool) or not isinstance(value, int) or value < (0 if key == "steps" else 1):
            raise _err(path, where, f"{key} must be an integer >= {0 if key == 'steps' else 1}, "
                                    f"got {value!r}")
        return int(value)
    if key == "mode":
        if value not in MODES:
            raise _err(path, where, f"mode must be one of {', '.join(MODES)}, got {value!r}")
        return value
    if key == "engine":
        if value not in ENGINES:
            raise _err(path, where, f"engine must be one of {', '.join(ENGINES)}, got {value!r}")
        return value
    if key == "allow_unstable":
        if not isinstance(value, bool):
            raise _err(path, where, f"allow_unstable must be true or false, got {value!r}")
        return value
    return value


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:g}"
    return str(v)


def load_sweep(path) -> Sweep:
    """Parse and check a sweep file (its scenes are built by :meth:`Sweep.validate`)."""
    from rackstress.lib.toml import tomllib

    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SweepError(f"sweep file {path} does not exist") from None
    except IsADirectoryError:
        raise SweepError(f"{path}: is a directory, not a sweep file") from None
    except UnicodeDecodeError as exc:
        raise SweepError(f"{path}: is not UTF-8 text ({exc.reason} at byte {exc.start}); a TOML "
                         "file must be UTF-8") from None
    except OSError as exc:
        raise SweepError(f"{path}: cannot read the sweep file: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise SweepError(f"{path}: not valid TOML: {exc}") from None
    unknown = sorted(set(data) - set(TOP_KEYS))
    if unknown:
        raise _err(path, "top level", f"unknown key(s) {', '.join(map(repr, unknown))}; "
                                      f"known: {', '.join(TOP_KEYS)}")
    if "scene" not in data or not isinstance(data["scene"], str):
        raise _err(path, "top level", "'scene' (a built-in scene name or a .toml file) is required")
    scene = data["scene"]
    spec = scene
    if scene.endswith(".toml"):
        p = Path(scene)
        spec = str(p if p.is_absolute() else (path.parent / p).resolve())
        if not Path(spec).is_file():
            raise _err(path, "scene", f"scene file {spec} does not exist")
    else:
        from rackstress import scenes

        if scene not in scenes.BUILDERS:
            raise _err(path, "scene", f"unknown scene '{scene}'; built-in scenes: "
                                      f"{', '.join(scenes.BUILDERS)} (or a .toml scene file)")
    base = {k: _check_run_value(path, "top level", k, data[k]) for k in RUN_KEYS if k in data}
    fixed = data.get("params", {})
    if not isinstance(fixed, dict):
        raise _err(path, "params", "must be a table of scene parameters")
    for k in list(fixed):
        if k in RUN_KEYS:
            base[k] = _check_run_value(path, f"[params] {k}", k, fixed[k])
    fixed = {k: v for k, v in fixed.items() if k not in RUN_KEYS}

    points: list[tuple[str | None, dict, str]] = []      # (name, values, where)
    swept: list[str] = []
    grid = data.get("grid")
    if grid is not None:
        if not isinstance(grid, dict) or not grid:
            raise _err(path, "[grid]", "must be a table of lists")
        for k, vals in grid.items():
            if not isinstance(vals, list) or not vals:
                raise _err(path, f"[grid] {k}", f"must be a non-empty list, got {vals!r}")
            for v in vals:
                if k in RUN_KEYS:
                    _check_run_value(path, f"[grid] {k}", k, v)
            if len(set(map(repr, vals))) != len(vals):
                raise _err(path, f"[grid] {k}", f"repeats a value: {vals!r}")
        swept += list(grid)
        keys = list(grid)
        for combo in itertools.product(*(grid[k] for k in keys)):
            points.append((None, dict(zip(keys, combo)), "[grid]"))
    tables = data.get("job", [])
    if not isinstance(tables, list):
        raise _err(path, "[[job]]", "must be an array of tables ([[job]])")
    for i, t in enumerate(tables):
        where = f"[[job]] #{i + 1}"
        if not isinstance(t, dict):
            raise _err(path, where, "must be a table")
        t = dict(t)
        name = t.pop("name", None)
        if name is not None and (not isinstance(name, str) or not NAME_RE.match(name)):
            raise _err(path, f"{where} name", f"{name!r} is not a usable directory name "
                                              "(letters, digits, . _ = + -)")
        for k in t:
            if k not in swept and k != "allow_unstable":
                swept.append(k)
        points.append((name, t, where if name is None else f"[[job]] '{name}'"))
    if not points:
        raise _err(path, "top level", "no jobs: give a [grid] and/or [[job]] tables")

    jobs, names = [], set()
    for idx, (name, values, where) in enumerate(points):
        run = dict(base)
        sets = dict(fixed)
        for k, v in values.items():
            if k in RUN_KEYS:
                run[k] = _check_run_value(path, f"{where} {k}", k, v)
            else:
                sets[k] = v
        if name is None:
            if where == "[grid]":
                shown = {k: v for k, v in values.items() if len(grid[k]) > 1} or values
                name = f"g{idx:03d}-" + "-".join(f"{k}={_fmt(v)}" for k, v in shown.items())
                name = re.sub(r"[^A-Za-z0-9._=+-]", "_", name)[:100]
            else:
                name = f"j{idx:03d}"
        if name in names:
            raise _err(path, where, f"job name '{name}' is used twice")
        names.add(name)
        jobs.append(Job(idx, name, dict(values), sets, engine=run.get("engine", "lammps"),
                        mode=run.get("mode", "exact"), steps=run.get("steps"), dt=run.get("dt"),
                        dump_every=run.get("dump_every"),
                        allow_unstable=bool(run.get("allow_unstable", False))))
    return Sweep(path, str(data.get("name", path.stem)), scene, spec, jobs, swept)
