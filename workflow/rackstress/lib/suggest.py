"""The closest valid name to a typo ("did you mean 'held'?"), for every message that refuses a
name: scene keys, parameters, scenes, CLI choices."""
from __future__ import annotations

import difflib


def did_you_mean(word: str, names, cutoff: float = 0.6) -> str:
    """`` (did you mean 'X'?)``-style text for the name closest to ``word``, or ``""``.

    Example
    -------
    >>> did_you_mean("hled", ["held", "mesh", "radius"])
    "did you mean 'held'?"
    """
    names = [str(n) for n in names]
    close = difflib.get_close_matches(str(word), names, n=1, cutoff=cutoff)
    if not close:           # a case slip (Held) or a prefix (plane_b) is close as well
        lower = {n.lower(): n for n in names}
        close = [lower[w] for w in difflib.get_close_matches(str(word).lower(), list(lower),
                                                               n=1, cutoff=cutoff)]
    return f"did you mean '{close[0]}'?" if close else ""
