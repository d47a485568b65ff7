"""Progress display for long work: a bar on a terminal, silence otherwise.

tqdm is imported only for a bar that is shown: a silent run (stderr not a terminal, a campaign's
worker, a test) does not load it.
"""

from __future__ import annotations

import sys


class Silent:
    """What :func:`progress` returns when no bar is shown: a context manager whose updates do nothing."""

    def update(self, n: int = 1) -> None:
        """Count ``n`` more updates (nothing is shown)."""

    def close(self) -> None:
        """End the display (there is none)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        return None


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

    Returns
    -------
    tqdm.tqdm or Silent
        A context manager with ``update(n)``.
    """
    if enabled is None:
        enabled = sys.stderr.isatty()
    if not enabled:
        return Silent()
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, leave=False, file=sys.stderr, dynamic_ncols=True)


__all__ = ["Silent", "progress"]
