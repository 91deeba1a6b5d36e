"""``rackstress run``'s chunks on the compiled plugin: the runner checks every
``PLUGIN_CHECK_EVERY`` steps there, and a chunk still ends at every checkpoint's step, so the
checkpoints fall where they fell with 10-step chunks and a resumed run stays bit for bit."""
from __future__ import annotations

from rackstress import scenes
from rackstress.engines.lammps.deck import compile_deck
from rackstress.engines.lammps.runner import CHECK_EVERY, PLUGIN_CHECK_EVERY, LammpsRun
from conftest import HANG_S


def test_checkpoints_fall_on_their_steps_with_long_chunks(tmp_path):
    from rackstress.engines.driver import drive
    from rackstress.runs.checkpoint import Checkpointer

    class Recorded(Checkpointer):
        """The real checkpoint writer, noting the step of each checkpoint it writes (only the
        last is kept on disk)."""
        steps: list = []

        def write(self, runner, *args):
            self.steps.append(runner.step)
            super().write(runner, *args)

    sc = scenes.build("plane-rack").with_steps(250)
    run = LammpsRun(compile_deck(sc, "exact", plugin=True), None, log=False)
    try:
        assert run.check_every == PLUGIN_CHECK_EVERY > 30
        ck = Recorded(tmp_path, run.comm, 30, mode="exact", dump_every=100)
        assert drive(run, checkpoint=ck).steps == 250
    finally:
        run.close()
    # every multiple of 30 (100-step chunks alone would end at 100 and 200), then the end
    assert Recorded.steps == list(range(30, 250, 30)) + [250]
    assert (tmp_path / "restart" / "state-000000250.restart").is_file()


def test_plugin_runner_checks_less_often_than_the_callback(tmp_path):
    sc = scenes.build("plane-rack").with_steps(10)
    plugin = LammpsRun(compile_deck(sc, "exact", plugin=True), None, log=False)
    callback = LammpsRun(compile_deck(sc, "exact", plugin=False), None, log=False)
    try:
        assert plugin.deck.plugin and not plugin.deck.python_ops
        assert callback.deck.python_ops
        assert (plugin.check_every, callback.check_every) == (PLUGIN_CHECK_EVERY, CHECK_EVERY)
    finally:
        plugin.close()
        callback.close()


def test_plugin_deck_without_pair_style_has_no_reverse_communication():
    """newton off on a plugin deck with no pair style: a ghost never holds a force (the
    styles add to owned atoms only), so LAMMPS sends nothing back after each step's forces."""
    deck = compile_deck(scenes.build("magpod-small"), "exact", plugin=True)
    cmds = deck.setup_commands("x.data", None, 100)
    assert "newton off off" in cmds and not any(c.startswith("pair_style") for c in cmds)
    assert cmds.index("newton off off") < next(k for k, c in enumerate(cmds)
                                               if c.startswith("read_data"))


#: Two particles 1,000 apart (two groups; a collides with b, which puts the deck on the plugin:
#: rs/collide, and adds nothing this far apart); the second pushed along +x by a = 1 (dt = 1) from rest, the watchdog
#: bound 50. Eq. 5 from rest under a constant acceleration puts it n(n+1)/2 from its origin after
#: n steps (n²/2 for velocity Verlet): beyond 50 from step 10 (or 11), long before the first
#: check; the plugin's chunks end every PLUGIN_CHECK_EVERY = 100 steps, so the watchdog names step
#: 100 on any number of ranks (5,050 or 5,000 units out), not a later chunk's end.
FLYAWAY = """name = "flyaway"
dt = 1.0
steps = 250
bound = 50.0

[[group]]
name = "a"
kind = "part"
positions = [[0.0, 0.0, 0.0]]
radius = 0.4

[[group]]
name = "b"
kind = "part"
positions = [[1000.0, 0.0, 0.0]]
radius = 0.4

[[operator]]
on = "b"
op = "force"
accel = [1.0, 0.0, 0.0]

[[operator]]
on = "a"
op = "collide"
from = "b"
c = 1.0
"""


def test_watchdog_names_the_first_chunk_end_past_the_bound_on_1_and_2_ranks(tmp_path):
    """The plugin path's watchdog, serial and under ``mpiexec -n 2`` (where its check is one
    fused reduction and the gather of the worst particle follows only when a rank found one):
    exit 3, ``diverged`` at step 100, 'b' particle 0 (atom id 2), same on both."""
    import json
    import subprocess

    from test_faults import MPIEXEC, QUIET, RS

    scene = tmp_path / "flyaway.toml"
    scene.write_text(FLYAWAY)
    assert PLUGIN_CHECK_EVERY == 100
    for mpi in ([], [MPIEXEC, "-n", "2"]):
        out = tmp_path / f"r{len(mpi)}"
        r = subprocess.run([*mpi, RS, "run", str(scene), "--allow-unstable", "--out", str(out),
                            *QUIET], capture_output=True, text=True, timeout=HANG_S)
        assert r.returncode == 3, r.stderr
        s = json.loads((out / "summary.json").read_text())
        assert s["status"] == "diverged" and s["ranks"] == (2 if mpi else 1)
        assert (s["error"]["step"], s["error"]["atom_id"]) == (100, 2), s["error"]
        assert "run diverged at step 100: 'b' particle 0 (atom id 2)" in r.stderr, r.stderr
        assert json.loads((out / "scene.json").read_text())["fingerprint"]["operators"] \
            == "plugin"
