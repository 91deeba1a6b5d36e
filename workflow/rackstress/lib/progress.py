"""The progress bar of long work (tqdm; quiet when stderr is not a terminal)."""
from __future__ import annotations

#: Work shorter than this many seconds shows no progress bar.
PROGRESS_DELAY_S = 2.0


def progress_bar(total: int, enabled: bool, desc: str):
    from tqdm.auto import tqdm

    # disable=None: tqdm stays quiet when stderr is not a terminal (batch jobs, CI logs)
    return tqdm(total=total, disable=True if not enabled else None, delay=PROGRESS_DELAY_S,
                unit="step", desc=desc, dynamic_ncols=True, leave=False)
