"""``rackstress run``'s chunks on the compiled plugin (issue 23): the runner checks every
``PLUGIN_CHECK_EVERY`` steps there, and a chunk still ends at every checkpoint's step, so the
checkpoints fall where they fell with 10-step chunks and a resumed run stays bit for bit."""
from __future__ import annotations

from rackstress import scenes
from rackstress.engines.lammps.deck import compile_deck
from rackstress.engines.lammps.runner import CHECK_EVERY, PLUGIN_CHECK_EVERY, LammpsRun


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
