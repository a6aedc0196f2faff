"""Training and validation blocks that share no sample.

Every segment of an axis is cut into blocks of about ``block_s`` seconds (one long SYSTEMID
run becomes several), the blocks are put in time order and alternate — even blocks train,
odd blocks validate (a lone block is cut in two halves). Each block carries the inputs
before it (:meth:`mavsid.data.Segment.cut`): a model's input filters and delay start there
as they were, as its state starts from the block's first measured one.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np

from mavsid.data import Segment
from mavsid.errors import NoExcitationError

__all__ = ["CHIRP_BLOCKS", "MIN_BLOCK_S", "split_segments"]


def _slice(seg: Segment, a: int, b: int, block: int) -> Segment:
    """Samples ``[a, b)`` of ``seg`` as block ``block``, with the inputs before them
    (:meth:`~mavsid.data.Segment.cut`: a block's input filters start where the record had
    them, not cold at its first sample)."""
    return seg.cut(a, b, meta={**dict(seg.meta), "block": block})


#: the shortest training or validation block a configuration may ask for, s
MIN_BLOCK_S = 0.5
#: Fewest blocks a SYSTEMID chirp is cut into, alternately training and validation: a
#: chirp's frequency rises with time, so two blocks would hold different bands (the slow
#: half against the fast one); from four on, each set holds a slow and a fast part.
CHIRP_BLOCKS = 4


def split_segments(
    segments: Sequence[Segment], block_s: float = 10.0
) -> tuple[tuple[Segment, ...], tuple[Segment, ...]]:
    """Split segments into training and validation blocks that share no sample.

    Each segment is cut into ``max(1, round(duration / block_s))`` equal blocks — a SYSTEMID
    run (``source == "sysid"``) into :data:`CHIRP_BLOCKS` at least (blocks of
    :data:`MIN_BLOCK_S` at least), so that training and validation both span its sweep; all
    blocks, in time order,
    alternate train / validation (train first). A single block is halved.

    Parameters
    ----------
    segments : sequence of Segment
    block_s : float
        Target block length, s.

    Returns
    -------
    train, validation : tuple of Segment

    Raises
    ------
    NoExcitationError
        No segment, or too few samples to give both sets.

    Examples
    --------
    >>> import dataclasses
    >>> import numpy as np
    >>> from mavsid.data import Segment
    >>> t = np.arange(0, 30, 0.01)
    >>> seg = Segment(t, t[:, None], t[:, None], ("p",), ("u_roll",), 0.01, "roll", "scan")
    >>> train, val = split_segments([seg], block_s=10.0)
    >>> [(round(s.start_s, 2), round(s.stop_s, 2)) for s in (*train, *val)]
    [(0.0, 9.99), (20.0, 29.99), (10.0, 19.99)]
    >>> run = dataclasses.replace(seg, source="sysid")
    >>> train, val = split_segments([run], block_s=10.0)
    >>> len(train), len(val), round(val[0].start_s, 2)
    (2, 2, 7.5)
    """
    if not segments:
        raise NoExcitationError("no segments to fit")
    pieces: list[tuple[Segment, int, int]] = []
    for seg in sorted(segments, key=lambda s: s.start_s):
        n = len(seg)
        k = max(1, min(round(n * seg.dt / block_s), n // 2))  # (blocks of 2 samples or more)
        if seg.source == "sysid":
            k = max(k, min(CHIRP_BLOCKS, int(n * seg.dt / MIN_BLOCK_S)))
        edges = np.linspace(0, n, k + 1).round().astype(int)
        pieces += [(seg, int(a), int(b)) for a, b in itertools.pairwise(edges)]
    if len(pieces) == 1:
        seg, a, b = pieces[0]
        mid = (a + b) // 2
        pieces = [(seg, a, mid), (seg, mid, b)]
    blocks = [_slice(s, a, b, i) for i, (s, a, b) in enumerate(pieces) if b - a >= 2]
    train = tuple(blocks[0::2])
    held_out = tuple(blocks[1::2])
    if not train or not held_out:
        raise NoExcitationError("too little data to hold out a validation segment")
    return train, held_out
