"""A recording logged faster than the muscle needs, merged to a longer sampling period.

Data acquisition boards log at 1-10 kHz; the paper samples the muscle at 10 Hz, and every tool here
works at 1 ms .. 10 s (:data:`tapmuscle.io.sampling.TS_RANGE_S`). Merging ``n`` samples into one keeps
the first sample's time, displacement and other readings (instants) and gives it the block's mean
command: the tools take the command as held from one sample to the next (docs/recordings.md,
"Sampling convention"), and what a valve passes over a block is, to first order, what the block's mean
command passes. *Decided:* a mean, not the first value, so that a command a faster controller moved
within the block is not shifted by up to a block (a step that comes in mid-block shows as a partial
step for one sample).
"""

from __future__ import annotations

import numpy as np

from tapmuscle.io.recording import Recording
from tapmuscle.io.sampling import MAX_DECIMATION

__all__ = ["decimated", "MAX_DECIMATION"]


def decimated(rec: Recording, n: int) -> tuple[Recording, str | None]:
    """``rec`` with every ``n`` samples merged into one, and a note where the command moved within
    the blocks (None where it did not).

    Parameters
    ----------
    rec : Recording
        Uniformly sampled; its ``lines`` (if any) name each merged sample by its block's first line.
    n : int
        Samples per block, 1 .. :data:`MAX_DECIMATION` (1 returns ``rec`` itself). A last block that is
        short is kept, with the mean of the samples it has.

    Returns
    -------
    Recording, str or None
        The merged recording (metadata ``decimated``: the samples of the original in one, ``n`` times
        what ``rec`` says; a ``ts_s`` header the merged period) and the note.

    Raises
    ------
    TypeError
        ``rec`` not a :class:`~tapmuscle.io.recording.Recording`.
    ValueError
        ``n`` not an integer within 1 .. :data:`MAX_DECIMATION`.
    """
    if not isinstance(rec, Recording):
        raise TypeError(f"decimated takes a Recording (tm.Recording(columns, metadata), or tm.read_recording), got "
                        f"{type(rec).__name__}")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= MAX_DECIMATION:
        raise ValueError(f"decimation n = {n!r} must be an integer within 1..{MAX_DECIMATION} (samples merged into one)")
    n = int(n)
    if n == 1:
        return rec, None
    starts = np.arange(0, len(rec), n)
    counts = np.diff(np.append(starts, len(rec)))
    columns = {name: values[starts] for name, values in rec.columns.items()}
    u = rec.columns["u_v"]
    columns["u_v"] = np.add.reduceat(u, starts) / counts
    swing = np.maximum.reduceat(u, starts) - np.minimum.reduceat(u, starts)
    moved = int(np.count_nonzero(swing > 1e-9))
    note = None
    if moved:
        note = (f"the command moved within {moved} of the {len(starts)} blocks of {n} samples (by up to "
                f"{float(swing.max()):.3g} V): each merged sample holds its block's mean command")
    lines = None if rec.lines is None else rec.lines[starts]
    metadata = dict(rec.metadata)
    if "ts_s" in metadata:  # the header states the period: the merged one
        metadata["ts_s"] = f"{rec.ts_s * n:.12g}"
    before = metadata.get("decimated", "1")
    metadata["decimated"] = str(n * int(before)) if before.isdigit() else str(n)  # merged again: the product
    return Recording(columns, metadata, lines), note
