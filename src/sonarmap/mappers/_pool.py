"""The footprints of the readings in play, for streaming mappers.

Readings enter and leave in any order (a selection strategy decides which leave), so
each reading gets a *slot*; its Omega_free and Omega_occ entries live in one growing
arena. Removing a reading marks its entries dead; the arena is compacted when dead
entries outnumber live ones, so its size stays within twice the live footprint and
insertion costs O(1) amortised. Nothing here depends on how many readings came before.

On request (``spans=True``) the pool also keeps each part as *spans*: maximal runs of
entries whose cells follow each other (``c, c + 1, ...``) with one weight. The
rasteriser lists a beam row by row, so a span is most of a row of the beam (44 cells on
average on the office ring); a pass over a footprint's spans reads its cells' values as
contiguous slices instead of one cell index per entry, which lets numba vectorise it.
The spans hold the entries in arena order, so a sum over them takes the terms in the
same order as a sum over the entries, to the bit. A pool with spans keeps only the
cells entry by entry (the strategies and the search for readings touching a cell read
them): the weights are in the spans, and the engines that use spans have no use for
distances. That is a third of the arena that insertion writes and compaction moves.
"""

from __future__ import annotations

import numba as nb
import numpy as np
import numpy.typing as npt

from ..raster import Footprint

I64 = npt.NDArray[np.int64]
I32 = npt.NDArray[np.int32]
F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]


@nb.njit(cache=True)
def _move(a: npt.NDArray[np.generic], src: int, dst: int, n: int) -> None:
    """Move ``a[src:src + n]`` down to ``a[dst:dst + n]`` (``dst <= src``)."""
    to = a[dst : dst + n]
    frm = a[src : src + n]
    # Front to back, so an overlap is safe; numba vectorises it when there is none.
    for j in range(n):
        to[j] = frm[j]


@nb.njit(cache=True)
def _compact(
    alive: npt.NDArray[np.bool_],
    f_start: I64,
    f_len: I64,
    o_start: I64,
    o_len: I64,
    cell: I32,
    w: F32,
    dist: F32,
    fs_start: I64,
    fs_len: I64,
    os_start: I64,
    os_len: I64,
    sp_cell: I32,
    sp_len: I32,
    sp_w: F32,
) -> tuple[int, int]:
    """Move the live slots' entries (and spans, when kept: ``sp_cell`` not empty) to the
    front of their arenas, in arena order; the new ends. ``w`` and ``dist`` are empty
    when the pool keeps spans."""
    order = np.argsort(f_start)
    spans = sp_cell.shape[0] > 0
    end = 0
    sp_end = 0
    for s in order:
        if not alive[s]:
            continue
        # A slot's free entries are followed by its occ entries, so one block moves.
        a = f_start[s]
        n = f_len[s] + o_len[s]
        _move(cell, a, end, n)
        if not spans:
            _move(w, a, end, n)
            _move(dist, a, end, n)
        f_start[s] = end
        o_start[s] = end + f_len[s]
        end += n
        if spans:
            # Spans were written in the entries' order, so sorting by entry start
            # sorts them too and no block moves past a live one.
            a = fs_start[s]
            n = fs_len[s] + os_len[s]
            _move(sp_cell, a, sp_end, n)
            _move(sp_len, a, sp_end, n)
            _move(sp_w, a, sp_end, n)
            fs_start[s] = sp_end
            os_start[s] = sp_end + fs_len[s]
            sp_end += n
    return end, sp_end


@nb.njit(cache=True)
def _gather(slots: I64, start: I64, length: I64, cell: I32, dist: F32) -> tuple[I64, I64, F64]:
    off = np.zeros(slots.shape[0] + 1, np.int64)
    for i in range(slots.shape[0]):
        off[i + 1] = off[i] + length[slots[i]]
    cells = np.empty(off[-1], np.int64)
    d = np.empty(off[-1], np.float64)
    for i in range(slots.shape[0]):
        a = start[slots[i]]
        for j in range(off[i + 1] - off[i]):
            cells[off[i] + j] = cell[a + j]
            d[off[i] + j] = dist[a + j]
    return cells, off, d


class ReadingPool:
    """Slot-addressed store of rasterised readings.

    Parameters
    ----------
    cols : int
        Columns of the grid (for the per-reading bounding boxes).
    sort_band : bool
        Keep each reading's Omega_occ entries sorted by distance (Thrun's model needs it).
    spans : bool
        Keep each part as spans of consecutive cells of one weight, and of the entries
        only their cells (see the module notes).

    Attributes
    ----------
    f_start, f_len, o_start, o_len : ndarray of int64, per slot
        Where the slot's Omega_free and Omega_occ entries are in the arena.
    fs_start, fs_len, os_start, os_len : ndarray of int64, per slot
        Where the slot's free and occ spans are in the span arena (with ``spans``).
    f_sum, o_sum : ndarray of float64, per slot
        Sum of the sensitivity weights ``w0`` over each part.
    z : ndarray of float64, per slot
        Range.
    echo, alive : ndarray of bool, per slot
    box : ndarray of int32, shape (slots, 4)
        Row and column bounds (inclusive) of the cells the reading touches.
    cell, w, dist : arena arrays
        Flat cell index, weight ``w0`` and distance of every entry (``w`` and ``dist``
        empty with ``spans``).
    sp_cell, sp_len, sp_w : span arena arrays
        First cell, number of cells and weight ``w0`` of every span (empty without
        ``spans``).
    """

    f_start: I64
    f_len: I64
    o_start: I64
    o_len: I64
    fs_start: I64
    fs_len: I64
    os_start: I64
    os_len: I64
    f_sum: F64
    o_sum: F64
    z: F64
    echo: npt.NDArray[np.bool_]
    alive: npt.NDArray[np.bool_]
    box: I32

    def __init__(self, cols: int, *, sort_band: bool = False, spans: bool = False) -> None:
        self.cols = cols
        self.sort_band = sort_band
        self.spans = spans
        self._grow_slots(256)
        self.cell = np.empty(1 << 16, np.int32)
        self.w = np.empty(0 if spans else 1 << 16, np.float32)
        self.dist = np.empty(0 if spans else 1 << 16, np.float32)
        self.end = 0
        self.dead = 0
        n_spans = 1 << 12 if spans else 0
        self.sp_cell = np.empty(n_spans, np.int32)
        self.sp_len = np.empty(n_spans, np.int32)
        self.sp_w = np.empty(n_spans, np.float32)
        self.sp_end = 0
        self._free: list[int] = list(range(255, -1, -1))

    def _grow_slots(self, cap: int) -> None:
        old = getattr(self, "alive", None)
        n = 0 if old is None else len(old)

        def grow(name: str, dtype: type, shape: tuple[int, ...] = ()) -> None:
            arr: npt.NDArray[np.generic] = np.zeros((cap, *shape), dtype)
            if old is not None:
                arr[:n] = getattr(self, name)
            setattr(self, name, arr)

        for name in ("f_start", "f_len", "o_start", "o_len"):
            grow(name, np.int64)
        for name in ("fs_start", "fs_len", "os_start", "os_len"):
            grow(name, np.int64)
        for name in ("f_sum", "o_sum", "z"):
            grow(name, np.float64)
        grow("echo", np.bool_)
        grow("alive", np.bool_)
        grow("box", np.int32, (4,))
        if old is not None:
            self._free.extend(range(cap - 1, n - 1, -1))

    @property
    def capacity(self) -> int:
        return len(self.alive)

    @property
    def n_alive(self) -> int:
        return self.capacity - len(self._free)

    @property
    def n_entries(self) -> int:
        """Live entries."""
        return self.end - self.dead

    def nbytes(self) -> int:
        """Memory held by the pool's arrays."""
        names = ["f_start", "f_len", "o_start", "o_len", "f_sum", "o_sum", "z", "echo"]
        if self.spans:
            names += ["fs_start", "fs_len", "os_start", "os_len"]
        slot: int = sum(int(getattr(self, n).nbytes) for n in names)
        arenas = sum(
            int(getattr(self, n).nbytes) for n in ("cell", "w", "dist", "sp_cell", "sp_len", "sp_w")
        )
        return slot + self.alive.nbytes + self.box.nbytes + arenas

    def _fits(self, n: int) -> bool:
        # A batch of n entries makes at most n spans.
        spans_fit = not self.spans or self.sp_end + n <= len(self.sp_cell)
        return self.end + n <= len(self.cell) and spans_fit

    def _grow(self, names: tuple[str, ...], end: int, need: int) -> None:
        cap = len(getattr(self, names[0]))
        if need <= cap:
            return
        while cap < need:
            cap *= 2
        for name in names:
            arr = getattr(self, name)
            new = np.empty(cap, arr.dtype)
            new[:end] = arr[:end]
            setattr(self, name, new)

    def _reserve(self, n: int) -> None:
        if self._fits(n):
            return
        if self.dead > 0:
            self.compact()
        if self.spans:
            self._grow(("cell",), self.end, self.end + n)
            self._grow(("sp_cell", "sp_len", "sp_w"), self.sp_end, self.sp_end + n)
        else:
            self._grow(("cell", "w", "dist"), self.end, self.end + n)

    def compact(self) -> None:
        """Drop dead entries (and spans) from the arenas."""
        self.end, sp_end = _compact(
            self.alive,
            self.f_start,
            self.f_len,
            self.o_start,
            self.o_len,
            self.cell,
            self.w,
            self.dist,
            self.fs_start,
            self.fs_len,
            self.os_start,
            self.os_len,
            self.sp_cell,
            self.sp_len,
            self.sp_w,
        )
        if self.spans:
            self.sp_end = sp_end
        self.dead = 0

    def add(self, fp: Footprint, z: F64, echo: npt.NDArray[np.bool_]) -> I64:
        """Store a rasterised batch; returns the slot of each reading."""
        n = fp.free.n_readings
        while len(self._free) < n:
            self._grow_slots(2 * self.capacity)
        slots = np.array([self._free.pop() for _ in range(n)], dtype=np.int64)
        total = int(fp.free.offsets[-1] - fp.free.offsets[0])
        total += int(fp.occ.offsets[-1] - fp.occ.offsets[0])
        self._reserve(total)
        occ_cells, occ_w, occ_d = fp.occ.cells, fp.occ.weight, fp.occ.distance
        if self.sort_band and len(occ_cells):
            # Within each reading by distance; the readings keep their order, so the
            # offsets still hold.
            order = np.lexsort((occ_d, fp.occ.reading_index()))
            occ_cells, occ_w, occ_d = occ_cells[order], occ_w[order], occ_d[order]
        self.end, self.sp_end = _insert(
            slots,
            self.end,
            self.sp_end,
            fp.free.offsets,
            fp.free.cells,
            fp.free.weight,
            fp.free.distance,
            fp.occ.offsets,
            occ_cells,
            occ_w,
            occ_d,
            self.cols,
            self.cell,
            self.w,
            self.dist,
            self.f_start,
            self.f_len,
            self.o_start,
            self.o_len,
            self.f_sum,
            self.o_sum,
            self.box,
            self.fs_start,
            self.fs_len,
            self.os_start,
            self.os_len,
            self.sp_cell,
            self.sp_len,
            self.sp_w,
        )
        self.z[slots] = z
        self.echo[slots] = echo
        self.alive[slots] = True
        return slots

    def remove(self, slots: I64) -> None:
        """Forget readings; their slots are reused."""
        if len(slots) == 0:
            return
        if not self.alive[slots].all():
            raise RuntimeError("removing a slot that is not in the pool")
        self.alive[slots] = False
        self.dead += int((self.f_len[slots] + self.o_len[slots]).sum())
        self._free.extend(slots.tolist())
        if self.dead > max(self.end - self.dead, 1 << 16):
            self.compact()

    def gather(self, slots: I64) -> tuple[I64, I64, I64, F64, I64]:
        """The slots' entries as CSR: free cells, free offsets, band cells, band
        distances, band offsets (not for a pool with spans, which keeps no distances)."""
        if self.spans:
            raise RuntimeError("a pool with spans keeps no distances to gather")
        f_cells, f_off, _ = _gather(slots, self.f_start, self.f_len, self.cell, self.dist)
        o_cells, o_off, o_dist = _gather(slots, self.o_start, self.o_len, self.cell, self.dist)
        return f_cells, f_off, o_cells, o_dist, o_off

    def alive_slots(self) -> I64:
        return np.flatnonzero(self.alive).astype(np.int64)

    def span_terms(
        self,
    ) -> tuple[I64, I64, I64, I64, I64, I64, F64, F64, npt.NDArray[np.bool_], I32, I32, F32]:
        """The arrays a span kernel reads a slot's terms from, in the order the
        gradient's stream kernels take them: ``fs_start``, ``fs_len``, ``os_start``,
        ``os_len``, ``f_len``, ``o_len``, ``f_sum``, ``o_sum``, ``echo``, ``sp_cell``,
        ``sp_len``, ``sp_w`` (views, not copies; valid until the pool next grows)."""
        return (
            self.fs_start,
            self.fs_len,
            self.os_start,
            self.os_len,
            self.f_len,
            self.o_len,
            self.f_sum,
            self.o_sum,
            self.echo,
            self.sp_cell,
            self.sp_len,
            self.sp_w,
        )


@nb.njit(cache=True)
def _insert(
    slots: I64,
    end: int,
    sp_end: int,
    f_off: I64,
    f_cells: I32,
    f_w: F32,
    f_d: F32,
    o_off: I64,
    o_cells: I32,
    o_w: F32,
    o_d: F32,
    cols: int,
    cell: I32,
    w: F32,
    dist: F32,
    f_start: I64,
    f_len: I64,
    o_start: I64,
    o_len: I64,
    f_sum: F64,
    o_sum: F64,
    box: I32,
    fs_start: I64,
    fs_len: I64,
    os_start: I64,
    os_len: I64,
    sp_cell: I32,
    sp_len: I32,
    sp_w: F32,
) -> tuple[int, int]:
    """Append each reading's free entries, then its occ entries, at ``end``; fill the
    slots' starts, lengths, weight sums and inclusive (row0, row1, col0, col1) boxes
    (empty as (max, -1, max, -1)). With spans kept (``sp_cell`` not empty), append
    each part's spans at ``sp_end`` and of the entries only their cells. Returns the new
    ends.

    Compiled, because done with whole-array numpy steps it was a fifth of a streaming
    update; part by part, in short loops over slices that numba compiles tightly (one
    loop doing everything ran out of registers and took 7 ns an entry)."""
    big = np.iinfo(np.int32).max
    spans = sp_cell.shape[0] > 0
    pos = end
    sp = sp_end
    for i in range(slots.shape[0]):
        s = slots[i]
        r0 = c0 = big
        r1 = c1 = -1
        # Start of the row of the last cell seen; none yet.
        row = -2 * cols
        for part in range(2):
            if part == 0:
                a, b, src_c, src_w, src_d = f_off[i], f_off[i + 1], f_cells, f_w, f_d
                f_start[s] = pos
                f_len[s] = b - a
            else:
                a, b, src_c, src_w, src_d = o_off[i], o_off[i + 1], o_cells, o_w, o_d
                o_start[s] = pos
                o_len[s] = b - a
            n = b - a
            cs = src_c[a:b]
            ws = src_w[a:b]
            to_c = cell[pos : pos + n]
            for j in range(n):
                to_c[j] = cs[j]
            if not spans:
                ds = src_d[a:b]
                to_w = w[pos : pos + n]
                to_d = dist[pos : pos + n]
                for j in range(n):
                    to_w[j] = ws[j]
                    to_d[j] = ds[j]
            pos += n
            tot = 0.0
            for j in range(n):
                tot += ws[j]
            for j in range(n):
                c = cs[j]
                # A footprint lists its cells row by row: divide (the dearest step of
                # this loop) only when the row changes.
                if c < row or c >= row + cols:
                    r = c // cols
                    row = r * cols
                    r0 = min(r0, r)
                    r1 = max(r1, r)
                c0 = min(c0, c - row)
                c1 = max(c1, c - row)
            sp0 = sp
            if spans:
                sp = _append_spans(cs, ws, sp_cell, sp_len, sp_w, sp)
            if part == 0:
                f_sum[s] = tot
                fs_start[s] = sp0
                fs_len[s] = sp - sp0
            else:
                o_sum[s] = tot
                os_start[s] = sp0
                os_len[s] = sp - sp0
        box[s, 0] = r0
        box[s, 1] = r1
        box[s, 2] = c0
        box[s, 3] = c1
    return pos, sp


@nb.njit(cache=True)
def _append_spans(cs: I32, ws: F32, sp_cell: I32, sp_len: I32, sp_w: F32, sp: int) -> int:
    """Append the spans of the entries (cells ``cs``, weights ``ws``) at ``sp``; the new
    end."""
    n = cs.shape[0]
    if n == 0:
        return sp
    start = 0
    for j in range(1, n):
        if cs[j] != cs[j - 1] + 1 or ws[j] != ws[j - 1]:
            sp_cell[sp] = cs[start]
            sp_len[sp] = j - start
            sp_w[sp] = ws[start]
            sp += 1
            start = j
    sp_cell[sp] = cs[start]
    sp_len[sp] = n - start
    sp_w[sp] = ws[start]
    return sp + 1
