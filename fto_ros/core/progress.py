"""The progress bar of the commands that run many replays (fto-report, fto-sweep): a tqdm
bar on stderr with the count, the rate and the time left, shown from the start (also while
the worker processes start) and for any number of workers; off when stderr is not a
terminal (tqdm's own rule) or when asked.  Lines printed while it runs go above it."""
from __future__ import annotations

import shutil
import sys
import threading


def bar(total: int, what: str, enabled: bool = True):
    """A tqdm bar over ``total`` items named ``what``; a disabled one when not enabled."""
    from tqdm import tqdm
    # a thread lock, not tqdm's default multiprocessing one: no semaphore for the resource
    # tracker to find at exit, nothing shared with the worker processes
    tqdm.set_lock(threading.RLock())
    # the terminal's size once: a terminal that says 0 x 0 (a fresh pseudo-terminal) made
    # tqdm draw nothing at all
    size = shutil.get_terminal_size((100, 24))
    return tqdm(total=total, unit=what, file=sys.stderr, ncols=size.columns or 100,
                nrows=size.lines or 24, leave=True,
                disable=None if enabled else True, smoothing=0.1,
                bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} {unit} [{elapsed}<{remaining}]"
                           "{postfix}")


def say(progress, text: str) -> None:
    """Print a line on stderr above the bar (plainly when the bar is off)."""
    if progress is not None and not progress.disable:
        progress.write(text, file=sys.stderr)
    else:
        print(text, file=sys.stderr)
