"""Progress display for long work: a bar on a terminal, silence otherwise."""

from __future__ import annotations

import sys

from tqdm import tqdm


def progress(total: int | None = None, desc: str = "", unit: str = "it", enabled: bool | None = None):
    """A tqdm bar on stderr, shown only when stderr is a terminal.

    Parameters
    ----------
    total : int, optional
        Expected number of updates.
    desc : str
        Label in front of the bar.
    unit : str
        Unit name of one update.
    enabled : bool, optional
        Force the bar on or off; by default it follows ``sys.stderr.isatty()``.
    """
    if enabled is None:
        enabled = sys.stderr.isatty()
    return tqdm(total=total, desc=desc, unit=unit, disable=not enabled, leave=False,
                file=sys.stderr, dynamic_ncols=True)
