"""lib/numtext.py: a dump frame's numbers, compiled, bit for bit what NumPy's parser
(``np.fromstring(text, sep=" ")``, strtod: correctly rounded) gives, and None wherever the
compiled loop cannot be sure, so that NumPy parses it (and says what is wrong)."""
import numpy as np
import pytest

from rackstress.lib import numtext

numtext.warm()


def _bits(a):
    return np.asarray(a, dtype=np.float64).view(np.int64)


@pytest.mark.parametrize("fmt", ["%.10g", "%.15g", "%.17g", "%.6e", "%.3f", "%g", "%d",
                                 "%.10e", "%.1f"])
@pytest.mark.parametrize("wide", [False, True])
def test_the_values_are_numpys_bit_for_bit(fmt, wide):
    """Random values and signs written as LAMMPS and others write them, magnitudes 1e-5 to
    1e5 (a dump's positions: always read here, but for %.17g's 17 digits and more) and 1e-14
    to 1e14 (a token out of the exact range leaves the whole text to NumPy, never parsed
    differently)."""
    rng = np.random.default_rng(3)
    span = 14 if wide else 5
    x = rng.uniform(1, 10, size=30000) * 10.0 ** rng.integers(-span, span, size=30000)
    x *= rng.choice([-1.0, 1.0], size=x.size)
    if fmt == "%d":
        x = np.round(x / 1e3 if wide else x)
    rows = [" ".join(fmt % v for v in x[k:k + 6]) for k in range(0, len(x), 6)]
    text = ("\n".join(rows) + "\n").encode()
    want = np.fromstring(text.decode(), sep=" ")
    got = numtext.numbers(text)
    if got is None:
        assert wide or fmt in ("%.17g",), fmt
        return
    assert np.array_equal(_bits(got), _bits(want))


def test_edges_by_hand():
    cases = {b"-0": [-0.0], b"0 -0.0 0.0": [0.0, -0.0, 0.0], b"1E5 2e-3 3e+02": [1e5, 2e-3, 300.0],
             b".5 5. -.5": [0.5, 5.0, -0.5], b"  1 \t 2\r\n3  ": [1.0, 2.0, 3.0], b"": [],
             b"9007199254740992": [9007199254740992.0], b"1e22 1e-22": [1e22, 1e-22],
             b"0.1 0.2 0.3 -18.2305 17 -1.5e-05": [0.1, 0.2, 0.3, -18.2305, 17.0, -1.5e-05],
             b"1234567890123456": [1234567890123456.0],
             b"0.000489814246212826": [0.000489814246212826]}
    for text, want in cases.items():
        got = numtext.numbers(text)
        assert got is not None and np.array_equal(_bits(got), _bits(want)), text
        assert np.array_equal(_bits(got), _bits(np.fromstring(text.decode(), sep=" ")))
    # not read here: NumPy parses (or refuses) them
    for text in (b"1 2 x", b"1 nan 2", b"inf", b"1e400", b"1e23", b"1e-23", b"1..2", b"--1",
                 b"1e", b"+1", b"1-2", b"123456789012345678", b"12345678901234567", b".", b"1e+", b"e5", b"1e1000",
                 b"9007199254740993", b"1,2"):
        assert numtext.numbers(text) is None, text


def test_a_real_dump_reads_alike_either_way(tmp_path):
    """The reader's tables (stress/dump.read_table) of a dump written as LAMMPS writes one,
    with the compiled parser loaded and with NumPy's: equal, bit for bit."""
    from rackstress.engines.dumpio import frame_text
    from rackstress.stress.dump import index_dump, read_table

    rng = np.random.default_rng(5)
    cols = ("id", "type", "mol", "x", "y", "z")
    text = ""
    for step in range(0, 50, 10):
        p = rng.normal(size=(300, 3)) * 20.0
        table = np.column_stack([np.arange(1, 301), np.ones(300), np.ones(300), p])
        text += frame_text(step, p, cols, table, ["%d", "%d", "%d"] + ["%.10g"] * 3)
    path = tmp_path / "trajectory.dump"
    path.write_text(text)
    idx = index_dump(path)
    fast = [read_table(idx, k) for k in range(len(idx.steps))]
    ready = numtext.ready
    numtext.ready = lambda: False
    try:
        slow = [read_table(idx, k) for k in range(len(idx.steps))]
    finally:
        numtext.ready = ready
    assert len(fast) == 5 and all(np.array_equal(_bits(a), _bits(b)) for a, b in zip(fast, slow))
