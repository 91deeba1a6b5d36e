"""Progress of long work: a bar on a terminal (tqdm), one line per phase otherwise.

No silent minutes (a 70,000-particle part once took 4 minutes without a word): every phase that can take more than ``PROGRESS_DELAY_S`` shows
that it is under way. :func:`progress_bar` counts steps or frames on a terminal; :func:`phase`
announces a phase — on a terminal, where the phase has no bar of its own, a line with the
seconds elapsed appears after ``PROGRESS_DELAY_S``; elsewhere (a log, a batch job, CI) one plain
line on stderr when the phase starts.
"""
from __future__ import annotations

import sys
import threading
import time
from contextlib import contextmanager

#: Work shorter than this many seconds shows no progress bar.
PROGRESS_DELAY_S = 2.0


def progress_bar(total: int, enabled: bool, desc: str):
    if "IPython" in sys.modules:        # a notebook's bar where one may be shown
        from tqdm.auto import tqdm
    else:                               # (tqdm.auto's own look for one: 0.08 s to import)
        from tqdm import tqdm

    # disable=None: tqdm stays quiet when stderr is not a terminal (batch jobs, CI logs)
    return tqdm(total=total, disable=True if not enabled else None, delay=PROGRESS_DELAY_S,
                unit="step", desc=desc, dynamic_ncols=True, leave=False)


@contextmanager
def phase(desc: str, enabled: bool = True, ticker: bool = True):
    """Announce the phase ``desc`` (e.g. "building the scene 'magpod'") while it runs.

    Parameters
    ----------
    desc : str
        What is being done, in words.
    enabled : bool
        False: nothing is shown (``--no-progress``).
    ticker : bool
        On a terminal, show ``desc… N s`` after ``PROGRESS_DELAY_S`` until the phase ends
        (off for phases that draw bars of their own).

    Example
    -------
    >>> with phase("building the scene 'magpod'", enabled=False):
    ...     pass
    """
    if not enabled:
        yield
        return
    stream = sys.stderr
    if not stream.isatty():
        stream.write(f"rackstress: {desc} …\n")
        stream.flush()
        yield
        return
    if not ticker:
        yield
        return
    done = threading.Event()
    t0 = time.monotonic()
    shown = []

    def tick():
        if done.wait(PROGRESS_DELAY_S):
            return
        while not done.is_set():
            stream.write(f"\r{desc}… {time.monotonic() - t0:.0f} s\x1b[K")
            stream.flush()
            shown.append(True)
            done.wait(0.5)

    thread = threading.Thread(target=tick, daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join()
        if shown:
            stream.write("\r\x1b[K")
            stream.flush()
