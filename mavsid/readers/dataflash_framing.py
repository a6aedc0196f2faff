"""DataFlash framing: which header candidates are records, and the damage between them.

A candidate is a record when its type is defined, it fits in the file, and either a header
follows exactly where it ends (forward evidence) or the record before it ends exactly where it
starts (backward evidence; a record with only backward evidence may not swallow a record with
forward evidence), or it is a well-formed FMT record, or it has no evidence but lies outside
the declared span of every header that has some and has no header inside its own span (a lone
record between two stretches of garbage; not a header-like pattern inside a cut last record,
nor one of a flood of header patterns). From the first record, each record is followed by the
next one at or after its end, so garbage is skipped and reading resumes on the next valid
record. The rules are evaluated on the few candidates not followed at once by the next one;
every other candidate is a record of the chain. :class:`Framing` holds the result and the
byte ranges no record covers (reported as skipped).

Examples
--------
>>> chain(np.array([0, 3, 5, 6]), np.array([3, 6, 9, 9])).tolist()  # 5 lies inside 3..6
[0, 1, 3]
"""

from __future__ import annotations

import array
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from mavsid.readers import dataflash_spec as dfspec
from mavsid.readers.arrays import unique
from mavsid.readers.dataflash_formats import Definitions

__all__ = ["NEAR", "Framing", "chain", "chain_nodes", "frame", "near", "sweep"]


NEAR = 16  # candidates looked at around a record when checking overlaps


def sweep(
    pos: np.ndarray, types: np.ndarray, table: Definitions, lengths: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The definition of each candidate ``pos`` (index into ``table.defs``, -1: type
    undefined) and its forward evidence (the next candidate starts where it ends, by
    ``lengths``: per definition, one more entry for -1), in one pass of cache-sized slices
    (each type converted to an index once, both looked up from it).

    A type's first definition applies up to its next FMT record (also before the first one,
    so that a log whose first FMT records are damaged still decodes). The log is cut into
    epochs at each redefinition; a 256-entry table per epoch then gives its candidates their
    definitions and lengths.

    Examples
    --------
    >>> from mavsid.readers.dataflash_formats import FMT_DEFINITION, Definition
    >>> table = Definitions(defs=[FMT_DEFINITION, Definition(1, "A", 5, "h", ("V",))],
    ...                     by_type={128: [(-1, 0)], 1: [(-1, 1)]})
    >>> defid, fwd = sweep(np.array([0, 5, 10]), np.array([1, 1, 7], np.uint8), table,
    ...                    np.array([89, 5, 0]))
    >>> defid.tolist(), fwd.tolist()
    ([1, 1, -1], [True, True, False])
    """
    m = pos.size
    dt = np.int16 if len(table.defs) < 2**15 else np.int32
    events = sorted((p, t, i) for t, e in table.by_type.items() for p, i in e[1:])
    # per epoch: candidate range and type -> definition table (None: ``defid`` given)
    epochs: list[tuple[int, int, np.ndarray | None]]
    if len(events) > 4096:  # pathological: per-type lookup instead of a big table
        defid = _assign_per_type(pos, types, table, dt)
        epochs = [(0, m, None)]
    else:
        defid = np.empty(m, dt)
        lut = np.full(256, -1, dt)
        for t, entries in table.by_type.items():
            lut[t] = entries[0][1]
        starts = np.array([p for p, _, _ in events], pos.dtype)
        edges = [0, *np.searchsorted(pos, starts, side="left").tolist(), m]
        epochs = [(edges[0], edges[1], lut.copy())]
        for k, (_, t, i) in enumerate(events, start=1):
            lut[t] = i
            epochs.append((edges[k], edges[k + 1], lut.copy()))
    fwd = np.zeros(m, bool)
    step = 1 << 16
    for lo, hi, of_type in epochs:
        length_of = lengths if of_type is None else lengths[of_type]
        for k in range(lo, hi, step):
            e = min(k + step, hi)
            if of_type is None:
                key = defid[k:e].astype(np.intp)
            else:
                key = types[k:e].astype(np.intp)
                np.take(of_type, key, out=defid[k:e])
            ends = np.take(length_of, key)
            ends += pos[k:e]
            j = min(e, m - 1) - k  # the last candidate has no next one
            np.equal(ends[:j], pos[k + 1 : k + 1 + j], out=fwd[k : k + j])
    return defid, fwd


def _assign_per_type(
    pos: np.ndarray, types: np.ndarray, table: Definitions, dt: type[np.signedinteger]
) -> np.ndarray:
    first = np.full(256, -1, dt)
    for t, entries in table.by_type.items():
        first[t] = entries[0][1]
    defid = first[types]
    order = np.argsort(types, kind="stable")
    bounds = np.concatenate([[0], np.cumsum(np.bincount(types, minlength=256))])
    for t, entries in table.by_type.items():
        if len(entries) > 1:
            sel = order[bounds[t] : bounds[t + 1]]
            starts = np.array([p for p, _ in entries], np.int64)
            ids = np.array([i for _, i in entries], dt)
            k = np.searchsorted(starts, pos[sel], side="right") - 1
            defid[sel] = ids[np.maximum(k, 0)]
    return defid


def chain(pos: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Greedy chain from the first node: indices of the nodes it visits (see
    :func:`_chain_mask`)."""
    return np.flatnonzero(_chain_mask(pos, end)).astype(pos.dtype)


def _chain_mask(pos: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Greedy chain from the first node: which nodes it visits.

    Each node is followed by the first node at or after its end. Runs of nodes that end
    exactly where the next one starts are taken whole; the successors of the other
    ("irregular") nodes are found at once, and a plain walk hops from run to run, once per
    irregular node at most.
    """
    m = pos.size
    irr = np.flatnonzero(end[:-1] != pos[1:])
    if irr.size == 0:
        return np.ones(m, bool)
    after = np.searchsorted(pos, end[irr], side="left")  # where the chain goes on
    # compact int arrays (not lists): bounded memory however many irregular nodes there are
    next_irr = array.array("q", np.searchsorted(irr, after, side="left").tobytes())
    after_a = array.array("q", after.astype(np.int64).tobytes())
    irr_a = array.array("q", irr.astype(np.int64).tobytes())
    starts, stops = array.array("q"), array.array("q")
    c, k = 0, 0
    while True:  # c strictly increases: always progresses
        starts.append(c)
        if k >= len(irr_a):
            stops.append(m)
            break
        stops.append(irr_a[k] + 1)
        c = after_a[k]
        if c >= m:
            break
        k = next_irr[k]
    return _runs_mask(m, np.frombuffer(starts, np.int64), np.frombuffer(stops, np.int64))


def near(
    idx: np.ndarray, span: int, flag: np.ndarray | None,
    hit: Callable[[int, np.ndarray], np.ndarray], size: int | None = None,
) -> np.ndarray:
    """For each candidate index in ``idx``: is one of the ``|span|`` candidates before
    (``span < 0``) or after it ``flag``-ged and satisfying ``hit``?

    ``hit(k, nb)`` receives the first position ``k`` in ``idx`` of a block and the
    neighbours' indices (shape ``(block, |span|)``) and returns a boolean array of that
    shape. Headers inside one record are few, so a short look-around replaces a search over
    all candidates. ``flag`` None stands for every one of ``size`` candidates (default: as
    many as ``flag`` has).
    """
    size = flag.size if flag is not None else size
    assert size is not None
    out = np.zeros(idx.size, bool)
    steps = np.arange(1, abs(span) + 1) * (1 if span > 0 else -1)
    block = 1 << 12  # bounded temporaries, whatever the number of such candidates
    for k in range(0, idx.size, block):
        nb = idx[k : k + block, None] + steps
        valid = (nb >= 0) & (nb < size)
        nb = np.clip(nb, 0, size - 1)
        if flag is not None:
            valid &= flag[nb]
        out[k : k + block] = np.any(valid & hit(k, nb), axis=1)
    return out


@dataclass
class Framing:
    """The header candidates and which of them are records.

    Candidates that are not records (header patterns inside a record, garbage) stay in
    place, marked by the definition index ``len(defs)`` (:attr:`none`): a log has few, and
    leaving them costs no copy of the full-length arrays.
    """

    pos: np.ndarray  # offsets of the candidates, ascending
    defid: np.ndarray  # their definition index; ``none`` for those that are not records
    skip_at: np.ndarray  # offsets of the byte ranges no record covers
    skip_len: np.ndarray  # and their sizes
    none: int  # the definition index of a candidate that is not a record
    count: int  # how many candidates are records

    def records(self) -> tuple[np.ndarray, np.ndarray]:
        """Offsets and definition indices of the records alone."""
        if self.count == self.pos.size:
            return self.pos, self.defid
        keep = self.defid != self.none
        return self.pos[keep], self.defid[keep]


def frame(a: np.ndarray, cand: np.ndarray, types: np.ndarray, table: Definitions) -> Framing:
    """The accepted records among the header candidates ``cand`` (see the module doc).

    Nearly every candidate of a log is followed by the next one exactly where it ends; only
    the others (*suspects*: header-like bytes inside a record, garbage, the last record,
    undefined types) need the evidence rules, so these are evaluated on the suspects alone
    and the full-length flags are set from them: few passes over the candidates and little
    fresh memory, which is what a cold read pays for.
    """
    n = a.size
    m = cand.size
    lengths = np.array([d.length for d in table.defs] + [0], cand.dtype)
    # definitions and forward evidence (the next header starts where this record ends: the
    # common case, checked on the very next candidate; only the rest needs a binary search)
    defid, fwd = sweep(cand, types, table, lengths)
    end = _Ends(cand, defid, lengths)  # undefined (-1) -> the sentinel 0
    sus = np.flatnonzero(~fwd).astype(cand.dtype)  # not followed at once (few, in a log)
    # outside ``sus`` a candidate is known (defined types have a length), complete (it ends
    # at the next candidate), has forward and backward evidence: a node
    known = end[sus] > cand[sus]
    complete = known & (end[sus] <= n)
    # backward evidence of the suspects: the candidate before ends here, or a suspect's
    # end is found further on
    has_in = np.zeros(sus.size, bool)
    has_in[sus > 0] = fwd[sus[sus > 0] - 1]
    rest = sus[complete]
    j = np.searchsorted(cand, end[rest], side="left")
    found = j < m
    found[found] = cand[j[found]] == end[rest[found]]
    fwd[rest[found]] = True
    at = np.searchsorted(sus, j[found])  # found candidates that are suspects themselves
    inside = at < sus.size
    inside[inside] = sus[at[inside]] == j[found][inside]
    has_in[at[inside]] = True
    del rest, j, found, at, inside
    fwd_sus = fwd[sus]
    backed_sus = (fwd_sus | has_in) & known
    backed = np.ones(m, bool)
    backed[sus] = backed_sus
    node_sus = complete & backed_sus
    # a lone record between two stretches of garbage has neither kind of evidence: take it
    # unless it lies inside the declared span of a backed header (e.g. a cut last record)
    # (FMT records need plausible content instead, below)
    weak = sus[complete & ~backed_sus & (types[sus] != dfspec.FMT_TYPE)]
    weak = weak[~near(weak, -NEAR, backed,
                      lambda k, nb: end[nb] > cand[weak[k : k + nb.shape[0]], None])]
    # ... and that has no other header inside it (not one of a flood of header patterns)
    weak = weak[~near(weak, NEAR, None,
                      lambda k, nb: cand[nb] < end[weak[k : k + nb.shape[0]]][:, None], m)]
    node = backed  # reused: every candidate outside ``sus`` is a node
    node[sus] = node_sus
    node[weak] = True
    plausible = np.searchsorted(cand, np.array(table.plausible, cand.dtype))
    node[plausible] = True
    del backed, backed_sus, node_sus, known, complete, has_in
    # a record with backward evidence only must not swallow one with forward evidence, nor
    # an FMT record whose content checks out (garbage on both sides of it leaves it no chain,
    # and its own header bytes can look like a defined type's header just before it)
    back_only = sus[node[sus] & ~fwd_sus]
    fwd[plausible] = True  # now: forward evidence or plausible content
    swallows = near(back_only, NEAR, fwd,
                    lambda k, nb: cand[nb] < end[back_only[k : k + nb.shape[0]]][:, None])
    node[back_only[swallows]] = False
    del fwd, fwd_sus, swallows, plausible
    # a node may break the chain only where it is a suspect or the next one is not a node
    skip = np.flatnonzero(~node).astype(cand.dtype)
    _, starts, stops = chain_nodes(cand, end, node, (sus, skip - 1), skip, mask=False)
    del node
    skipped = _run_gaps(n, cand, end, starts, stops)
    none = len(table.defs)
    defid[_outside_runs(m, starts, stops)] = none  # (``defid`` is this function's own)
    return Framing(cand, defid, *skipped, none=none, count=int((stops - starts).sum()))


class _Ends:
    """End offsets of header candidates (offset + their definition's length; 0 for an
    undefined type), computed for the candidates asked for: the framing needs them for a
    few, and a full-length array would be fresh memory a cold read pays for.

    Examples
    --------
    >>> e = _Ends(np.array([0, 5]), np.array([1, -1]), np.array([9, 3, 0]))
    >>> e[np.array([0, 1])].tolist(), e[:1].tolist()
    ([3, 5], [3])
    """

    def __init__(self, cand: np.ndarray, defid: np.ndarray, lengths: np.ndarray) -> None:
        self.cand, self.defid, self.lengths = cand, defid, lengths

    def __getitem__(self, idx: np.ndarray | slice) -> np.ndarray:
        ends = self.lengths[self.defid[idx]]
        ends += self.cand[idx]
        return ends


def _runs_mask(m: int, starts: np.ndarray, stops: np.ndarray) -> np.ndarray:
    """Which of ``0..m-1`` lie in the ranges ``starts[k]..stops[k]`` (ascending, disjoint).

    Examples
    --------
    >>> _runs_mask(6, np.array([1, 4]), np.array([3, 5])).astype(int).tolist()
    [0, 1, 1, 0, 1, 0]
    """
    # off before each run, on along it, off after the last
    edges = np.empty(2 * starts.size + 2, np.int64)
    edges[0], edges[-1] = 0, m
    edges[1:-1:2] = starts
    edges[2:-1:2] = stops
    on = np.zeros(edges.size - 1, bool)
    on[1::2] = True
    return np.repeat(on, np.diff(edges))


def _outside_runs(m: int, starts: np.ndarray, stops: np.ndarray) -> np.ndarray:
    """Indices ``0..m-1`` outside the ranges ``starts[k]..stops[k]`` (ascending, disjoint).

    Examples
    --------
    >>> _outside_runs(10, np.array([1, 6]), np.array([3, 8])).tolist()
    [0, 3, 4, 5, 8, 9]
    """
    lo = np.concatenate([[0], stops]).astype(np.int64)
    hi = np.concatenate([starts, [m]]).astype(np.int64)
    size = np.maximum(hi - lo, 0)
    total = int(size.sum())
    return np.arange(total, dtype=np.int64) + np.repeat(lo - (np.cumsum(size) - size), size)


def chain_nodes(
    pos: np.ndarray, end: np.ndarray | _Ends, node: np.ndarray,
    suspects: Sequence[np.ndarray] | None = None, skip: np.ndarray | None = None,
    mask: bool = True,
) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
    """:func:`_chain_mask` over the ``node`` candidates only, without copying them out:
    which candidates the chain visits, and the runs it takes whole (``starts``, ``stops``:
    candidate index ranges, each record of a run ending where the next one starts).

    A node is *regular* when the next candidate is a node starting where it ends; the chain
    takes runs of regular nodes whole and looks up, for each other node, the first node at
    or after its end (skipping the few candidates that are not nodes).

    Examples
    --------
    >>> pos, end = np.array([0, 3, 5, 6, 9]), np.array([3, 6, 6, 9, 12])
    >>> keep, starts, stops = chain_nodes(pos, end, np.array([1, 1, 0, 1, 1], bool))
    >>> keep.tolist(), starts.tolist(), stops.tolist()
    ([True, True, False, True, True], [0, 3], [2, 5])

    ``suspects`` (arrays of candidate indices) and ``skip`` (the non-nodes, ascending), when
    given, spare the passes over all candidates: only suspects may be irregular. Without
    ``mask`` only the runs are returned (the mask is None).
    """
    m = pos.size
    none = np.zeros(0, np.int64)
    if m == 0:
        return np.zeros(0, bool), none, none
    if suspects is None:
        regular = np.zeros(m, bool)
        np.equal(end[:-1], pos[1:], out=regular[:-1])
        regular[:-1] &= node[1:]
        irr = np.flatnonzero(node & ~regular)  # never empty when a node exists: the last one
        del regular
    else:  # only these may be irregular
        some = np.concatenate([s[(s >= 0) & (s < m)] for s in suspects]).astype(np.int64)
        irr = unique(some[node[some]])[0]
        nxt = np.minimum(irr + 1, m - 1)
        irr = irr[(irr == m - 1) | (end[irr] != pos[nxt]) | ~node[nxt]]
    if irr.size == 0:
        return np.zeros(m, bool) if mask else None, none, none
    if skip is None:
        skip = np.flatnonzero(~node)  # candidates that are not nodes (few)
    # per non-node: the first index after its run of consecutive non-nodes
    brk = np.flatnonzero(np.diff(skip) != 1)
    run_end = np.repeat(np.append(skip[brk], skip[-1:]) + 1 if skip.size else skip,
                        np.diff(np.concatenate([[0], brk + 1, [skip.size]])))

    def next_node(j: np.ndarray) -> np.ndarray:  # first node at index >= j
        k = np.searchsorted(skip, j)
        inside = k < skip.size
        inside[inside] = skip[k[inside]] == j[inside]
        out = j.copy()
        out[inside] = run_end[k[inside]]
        return out

    after = next_node(np.searchsorted(pos, end[irr], side="left"))  # where the chain goes on
    next_irr = array.array("q", np.searchsorted(irr, after, side="left").astype(np.int64)
                           .tobytes())
    after_a = array.array("q", after.astype(np.int64).tobytes())
    irr_a = array.array("q", irr.astype(np.int64).tobytes())
    starts, stops = array.array("q"), array.array("q")
    c = int(next_node(np.zeros(1, np.int64))[0])
    k = int(np.searchsorted(irr, c))
    while c < m:  # c strictly increases: always progresses
        starts.append(c)
        stops.append(irr_a[k] + 1)
        c = after_a[k]
        if c >= m:
            break
        k = next_irr[k]
    first, last = np.frombuffer(starts, np.int64), np.frombuffer(stops, np.int64)
    if not mask:
        return None, first, last
    return _runs_mask(m, first, last), first, last


def _run_gaps(
    n: int, pos: np.ndarray, end: np.ndarray | _Ends, starts: np.ndarray, stops: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_skipped_regions` of the records in runs ``starts..stops`` of candidates
    (records within a run leave no gap: only the runs' edges are looked at)."""
    if starts.size == 0:
        return pos[:0], pos[:0]
    return _skipped_regions(n, pos[starts], end[stops - 1])


def _skipped_regions(n: int, pos: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Offsets and sizes of the byte ranges not covered by accepted records."""
    inner = pos[1:] - end[:-1]
    k = np.flatnonzero(inner > 0)
    starts = np.concatenate([[0], end[k], [end[-1]]])
    sizes = np.concatenate([[pos[0]], inner[k], [n - end[-1]]])
    keep = sizes > 0
    return starts[keep], sizes[keep]
