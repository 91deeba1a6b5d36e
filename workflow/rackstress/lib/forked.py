"""A call in a forked child process, stopped after a time limit.

gmsh's classification of a surface does not end on some pieces of a file's facets (an SO-100
upper arm's ball: seven minutes, killed) and cannot be interrupted inside its process, so the
submodels that mesh such pieces (stress.notch, validity.solid.local_peak) run in a child.
"""
from __future__ import annotations


class Timeout(RuntimeError):
    """The call had not returned within its time limit; its child was stopped."""


def call(fn, timeout: float):
    """``fn()`` in a forked child process; its result (picklable) or its exception again here
    (ImportError and others as RuntimeError with its words), :class:`Timeout` after
    ``timeout`` seconds. Where the platform cannot fork, ``fn()`` in this process.

    >>> call(lambda: 6 * 7, 30.0)
    42
    """
    import multiprocessing as mp

    try:
        ctx = mp.get_context("fork")
    except ValueError:
        return fn()
    recv, send = ctx.Pipe(duplex=False)

    def child():
        try:
            send.send(("ok", fn()))
        except ImportError as exc:
            send.send(("import", exc.name or str(exc)))
        except BaseException as exc:  # noqa: BLE001 - reported in the parent, in its own words
            send.send(("error", str(exc)))

    proc = ctx.Process(target=child, daemon=True)
    proc.start()
    send.close()                     # the child's end only: its exit is then an end of file
    try:
        kind, got = recv.recv() if recv.poll(timeout) else ("timeout", None)
    except EOFError:
        kind, got = "error", "its process ended without a result"
    finally:
        if proc.is_alive():
            proc.kill()
        proc.join()
        recv.close()
    if kind == "ok":
        return got
    if kind == "import":
        raise ImportError(got, name=got)
    if kind == "timeout":
        raise Timeout(f"not done after {timeout:.0f} s")
    raise RuntimeError(got)
