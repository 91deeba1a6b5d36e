"""A plain LAMMPS data file and dump that rackstress did not write, opened for the stress measures.

Users' own runs have no ``scene.json``: :func:`load_plain` takes the data file (its Atoms section
gives the original positions o, the rest shape every measure compares against, and the molecule
and type of every atom) and a ``dump custom`` file (``id type x y z`` or ``xu yu zu``, any other
columns kept), and makes the parts from the molecules (``parts="mol"``: one part per molecule
id) or the atom types (``parts="type"``). The result is a
:class:`~rackstress.stress.rundata.RunData` like a run directory's, so every measure, the peaks,
the VTK files and the stress dump work on it unchanged (:func:`rackstress.stress.post.postprocess`).

Atom styles read (the ``Atoms # style`` comment, else guessed from the column count):
``atomic`` (id type x y z), ``bond``/``angle``/``molecular`` (id mol type x y z), ``full`` (id
mol type q x y z), ``charge`` (id type q x y z), ``sphere`` (id type diameter density x y z; the
diameter gives the radius). Image flags after the coordinates are ignored.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from rackstress.stress.dump import (DataFile, DataMismatchError, RackDumpReader,
                                    StressInputError, index_dump)
from rackstress.stress.rundata import Part, RunData

#: atom style → (column of mol or None, column of type, column of x, column of diameter or None)
STYLES = {
    "atomic": (None, 1, 2, None),
    "bond": (1, 2, 3, None),
    "angle": (1, 2, 3, None),
    "molecular": (1, 2, 3, None),
    "full": (1, 2, 4, None),
    "charge": (None, 1, 3, None),
    "sphere": (None, 1, 4, 2),
}
_BY_COUNT = {5: "atomic", 8: "atomic", 6: "bond", 9: "bond", 7: "full", 10: "full"}
_COUNT = re.compile(rb"^\s*(\d+)\s+atoms\s*$")


def read_plain_data(path, atom_style: str | None = None) -> tuple[DataFile, np.ndarray | None, str]:
    """(DataFile, radii or None, atom style) of any-style LAMMPS data file (module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise StressInputError(f"{path}: no such data file")
    lines = path.read_bytes().splitlines()
    n = next((int(m.group(1)) for line in lines[1:]
              if (m := _COUNT.match(line.split(b"#")[0]))), None)
    if n is None:
        raise StressInputError(f"{path}: no 'N atoms' line in the header (not a LAMMPS data file?)")
    at = next((k for k, line in enumerate(lines) if line.split(b"#")[0].strip() == b"Atoms"), None)
    if at is None:
        raise StressInputError(f"{path}: no Atoms section")
    comment = lines[at].split(b"#", 1)[1].strip().decode() if b"#" in lines[at] else ""
    j = at + 1
    while j < len(lines) and not lines[j].strip():
        j += 1
    rows = [r.split(b"#")[0].split() for r in lines[j:j + n]]
    style = atom_style or (comment.split()[0] if comment else None)
    if style is None:
        style = _BY_COUNT.get(len(rows[0]) if rows else 0)
    if style not in STYLES:
        raise StressInputError(
            f"{path}: atom style '{style or comment or '?'}' of the Atoms section is not one "
            f"rackstress reads ({', '.join(STYLES)}); name it with --atom-style")
    mol_c, type_c, x_c, dia_c = STYLES[style]
    need = x_c + 3
    try:
        table = np.array([r[:need] for r in rows], dtype=float)
    except ValueError:
        raise StressInputError(f"{path}: the Atoms section is not '{style}' lines") from None
    if table.shape != (n, need):
        raise StressInputError(f"{path}: the header declares {n} atoms but the Atoms section "
                               f"holds {len(rows)} line(s) of at least {need} numbers "
                               f"(atom style {style})")
    table = table[np.argsort(table[:, 0], kind="stable")]
    ids = table[:, 0].astype(np.int64)
    if len(np.unique(ids)) != n:
        raise StressInputError(f"{path}: atom ids repeat in the Atoms section")
    mols = table[:, mol_c].astype(np.int64) if mol_c is not None else np.zeros(n, np.int64)
    types = table[:, type_c].astype(np.int64)
    radii = 0.5 * table[:, dia_c] if dia_c is not None else None
    return DataFile(path, ids, mols, types, table[:, x_c:x_c + 3].copy(), {}), radii, style


def load_plain(data_path, dump_path, parts: str | None = None, atom_style: str | None = None,
               dt: float = 1.0, outdir=None, allow_truncated: bool = False) -> RunData:
    """Open a plain LAMMPS data file + dump as a run for the stress measures.

    Parameters
    ----------
    data_path, dump_path : path
        The data file (original positions, molecules, types) and the ``dump custom`` file.
    parts : {"mol", "type"}, optional
        How atoms form parts; default ``mol`` when the data file has more than one molecule id,
        else ``type``.
    atom_style : str, optional
        The data file's atom style when its Atoms section does not name it.
    dt : float
        Time per iteration (for the accumulated measure).
    outdir : path, optional
        Where post-processing writes (default: the dump's folder).

    Example
    -------
    >>> run = load_plain("my.data", "my.dump", parts="mol")      # doctest: +SKIP
    >>> postprocess(None, run=run, dump=True, out="my-stress")   # doctest: +SKIP
    """
    import MDAnalysis as mda

    data, r, style = read_plain_data(data_path, atom_style)
    index = index_dump(dump_path, allow_truncated)
    n = len(data.ids)
    if index.n_atoms != n:
        raise DataMismatchError(f"{dump_path} has {index.n_atoms} atoms per frame but "
                                f"{data_path} has {n}: the dump and the data file are not of "
                                "the same run (every atom must be in every frame)")
    if parts is None:
        parts = "mol" if len(np.unique(data.mols)) > 1 else "type"
    if parts not in ("mol", "type"):
        raise StressInputError(f"--parts must be 'mol' or 'type', got '{parts}'")
    if parts == "mol" and STYLES[style][0] is None:
        raise StressInputError(f"{data_path}: atom style '{style}' has no molecule ids; use "
                               "--parts type")
    key = data.mols if parts == "mol" else data.types
    groups, part_map = [], {}
    for value in np.unique(key):
        idx = np.flatnonzero(key == value)
        name = f"{parts}{int(value)}"
        types = np.unique(data.types[idx])
        part_map[name] = Part(name, "part", None, int(types[0]), int(np.unique(data.mols[idx])[0]),
                              idx.astype(np.int64))
        groups.append({"name": name, "kind": "part", "n": int(len(idx))})
    u = mda.Universe.empty(n, trajectory=False)
    u.add_TopologyAttr("ids", data.ids)
    u.add_TopologyAttr("types", data.types.astype(str))
    u.load_new(str(dump_path), format=RackDumpReader, index=index, dt=dt)
    ts = u.trajectory[0]
    if not np.array_equal(ts.data["ids"], data.ids):
        bad = int(np.flatnonzero(ts.data["ids"] != data.ids)[0])
        raise DataMismatchError(f"{dump_path} (step {index.steps[0]}) has atom id "
                                f"{ts.data['ids'][bad]} where {data_path} has {data.ids[bad]}: "
                                "the files are not of the same run")
    if not np.array_equal(ts.data["types"], data.types):
        bad = int(np.flatnonzero(ts.data["types"] != data.types)[0])
        raise DataMismatchError(f"atom {data.ids[bad]} has type {ts.data['types'][bad]} in "
                                f"{dump_path} but type {data.types[bad]} in {data_path}: the "
                                "files are not of the same run")
    outdir = Path(outdir) if outdir is not None else Path(dump_path).resolve().parent
    scene = {"scene": Path(data_path).stem, "dt": float(dt), "groups": groups,
             "source": {"data": str(data_path), "dump": str(dump_path), "parts": parts,
                        "atom_style": style}}
    run = RunData(outdir, scene, data, index, part_map, u)
    if r is not None:
        run.radii = r
    return run
