"""Help that teaches: every command's --help has a one-line purpose and
examples, the command list is not cut short, ``rackstress scenes`` prints a table, and a typo
in a scene key, a parameter, a scene name or a CLI choice names the closest valid one. Real
processes of the installed ``rackstress`` command."""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import click
import pytest

from rackstress.cli import main
from conftest import HANG_S

RS = str(Path(sys.executable).parent / "rackstress")


def rs(*args, timeout=HANG_S):
    return subprocess.run([RS, *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


def commands(group=main, path=()):
    """Every command and group under ``rackstress`` as (path, command)."""
    out = [(path, group)]
    for name, sub in getattr(group, "commands", {}).items():
        out += commands(sub, path + (name,)) if isinstance(sub, click.Group) else [
            (path + (name,), sub)]
    return out


COMMANDS = commands()


@pytest.mark.parametrize("path, cmd", COMMANDS, ids=[" ".join(p) or "rackstress"
                                                      for p, _ in COMMANDS])
def test_every_help_has_a_purpose_and_examples(path, cmd):
    r = rs(*path, "--help")
    assert r.returncode == 0, r.stderr
    text = r.stdout
    assert cmd.short_help and len(cmd.short_help) <= 70 and not cmd.short_help.endswith("...")
    assert "Examples:" in text
    examples = [ln.strip() for ln in text.split("Examples:", 1)[1].splitlines()
                if re.match(r"\s+(rackstress|mpiexec|\(cd) ", ln)]
    assert 2 <= len(examples) <= 4, text
    # every option an example gives is one the command takes
    for ex in examples:
        words = ex.split()
        if "rackstress" not in words:
            continue
        words = words[words.index("rackstress") + 1:]
        target = main
        while isinstance(target, click.Group) and words and words[0] in target.commands:
            target, words = target.commands[words[0]], words[1:]
        known = {o for p in target.params for o in (*p.opts, *p.secondary_opts)}
        for w in words:
            if w.startswith("--"):
                assert w.split("=")[0] in known, (ex, w)


def test_the_command_list_is_not_cut_short():
    r = rs("--help")
    listed = r.stdout.split("Commands:", 1)[1]
    for name, sub in main.commands.items():
        assert sub.short_help.split()[0] in listed and "..." not in listed
        line = next(ln for ln in listed.splitlines() if ln.strip().startswith(name + " "))
        assert line.split(None, 1)[1].strip() == sub.short_help, line


def test_scenes_prints_a_table():
    r = rs("scenes")
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert out.splitlines()[0].split() == ["SCENE", "PARTICLES", "WHAT", "IT", "SHOWS"]
    assert "{" not in out                       # no raw dictionaries
    # particle counts by hand: the plane is 20 × 20; plane-rack adds its six rack particles
    assert re.search(r"^plane-bound\s+400\s+Eq\. 17", out, re.M)
    assert re.search(r"^plane-rack\s+406\s+Eqs\. 24", out, re.M)
    assert "plane_bind=100.0" in out and "rack_bind=0.5" in out
    from rackstress.scenes import BUILDERS

    for name in BUILDERS:
        assert re.search(rf"^{re.escape(name)}\s+[\d,]+\s+\S", out, re.M), name
    assert out.count("parameters:") == len(BUILDERS)
    r = rs("scenes", "--json", "scenes/two-blobs.toml")
    assert r.returncode == 0, r.stderr
    rec = json.loads(r.stdout)["scenes/two-blobs.toml"]
    assert rec["particles"] == 2 * 27 + 2 * 6                     # two 3³ blobs, two racks
    assert rec["parameters"]["steps"] == 300 and rec["shows"].startswith("Two 3 x 3 x 3 blobs")


SCENE = """name = "s"
steps = 1
[params]
gap = 1.0
[[group]]
name = "plate"
kind = "part"
lattice = {{ shape = [3, 3, 1] }}
radius = 0.5
{extra}
[[operator]]
on = "plate"
op = "{op}"
c = "$({ref} * 2)"
"""


@pytest.mark.parametrize("edit, hint", [
    ({"extra": 'hled = { ids = [0] }'}, "did you mean 'held'?"),
    ({"op": "dampn"}, "did you mean 'dampen'?"),
    ({"ref": "gpa"}, "did you mean 'gap'?"),
])
def test_a_typo_in_a_scene_file_names_the_closest_key(tmp_path, edit, hint):
    scene = tmp_path / "s.toml"
    scene.write_text(SCENE.format(**{"extra": "", "op": "dampen", "ref": "gap", **edit}))
    r = rs("deck", scene, "--out", tmp_path / "d")
    assert r.returncode == 2, r.stderr
    assert hint in r.stderr and "Traceback" not in r.stderr


@pytest.mark.parametrize("args, hint", [
    (["run", "plane-rak"], "did you mean 'plane-rack'?"),
    (["run", "plane-rack", "--set", "plane_bnd=5"], "did you mean 'plane_bind'?"),
    (["run", "plane-rack", "--engine", "lamps"], "did you mean 'lammps'?"),
    (["run", "plane-rack", "--mode", "exct"], "did you mean 'exact'?"),
])
def test_a_typo_on_the_command_line_names_the_closest_choice(tmp_path, args, hint):
    r = rs(*args, "--out", tmp_path / "r", "--no-progress")
    assert r.returncode == 2, r.stderr
    assert hint in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "r").exists()


def test_a_typo_in_a_files_own_parameter_names_it(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text(SCENE.format(extra="", op="dampen", ref="gap"))
    r = rs("deck", scene, "--set", "gpa=2", "--out", tmp_path / "d")
    assert r.returncode == 2 and "did you mean 'gap'?" in r.stderr, r.stderr


def test_scenes_table_keeps_its_columns_for_a_scene_file_with_a_long_path():
    """A scene file's path longer than the first column goes on a line of its own; the
    description and the parameters keep whole words (a 78-character path once left them 10
    characters a line, 'spacing' and 'budget' broken apart)."""
    from rackstress.cli import scenes_table

    name = "/tmp/pytest-of-someone/pytest-12/popen-gw1/test_spacing_chosen_and_set0/bar.toml"
    row = {"name": name, "particles": 5600, "shows": "A bar bolted at two holes and pulled",
           "parameters": {"spacing": None, "budget": 20000}}
    lines = scenes_table([row]).splitlines()
    assert name in lines
    assert any(line.rstrip().endswith("5,600  A bar bolted at two holes and pulled")
               for line in lines)
    assert any("parameters: spacing=None, budget=20000" in line for line in lines)
