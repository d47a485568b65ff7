"""The staging folder of a campaign's outputs: written there, moved into place together."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from ...runtime.files import OutputError, check_output_file

#: The outputs of a campaign, replaced together.
OUTPUTS = ("campaign.csv", "summary.json", "campaign.png")


class Staging:
    """A folder ``campaign.partial-*`` in the output folder that receives every output of a campaign
    (and its checkpoints); :meth:`install` moves them into place together, so the outputs of the
    folder are all of one campaign. On failure the folder is removed, unless it holds a checkpoint
    (the rows of a campaign that did not finish).

    Parameters
    ----------
    out : Path
        The output folder (created).
    """

    def __init__(self, out: Path):
        for name in OUTPUTS:
            check_output_file(out / name, "campaign output")
        try:
            out.mkdir(parents=True, exist_ok=True)
            self.folder = Path(tempfile.mkdtemp(prefix="campaign.partial-", dir=out))
        except OSError as exc:
            raise OutputError(f"{out}: cannot write the campaign outputs there ({exc.strerror or exc})") from None
        self.out = out
        self.checkpointed = False

    def path(self, name: str) -> Path:
        """Where the output ``name`` is written before it is installed."""
        return self.folder / name

    def install(self) -> None:
        """Move every output into the output folder (each rename atomic), then remove the staging folder."""
        try:
            for name in OUTPUTS:
                os.replace(self.folder / name, self.out / name)
        except OSError as exc:
            raise OutputError(f"{self.out}: cannot put the campaign outputs in place ({exc.strerror or exc})") \
                from None
        self.checkpointed = False

    def close(self) -> None:
        """Remove the staging folder (kept when it holds the checkpoint of a campaign that failed)."""
        if not self.checkpointed:
            shutil.rmtree(self.folder, ignore_errors=True)


__all__ = ["OUTPUTS", "Staging"]
