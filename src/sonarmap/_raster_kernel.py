"""The numba kernels behind :mod:`sonarmap.raster` (private)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numba as nb
import numpy as np
import numpy.typing as npt
from llvmlite import ir  # type: ignore[import-untyped]
from numba.core import types
from numba.extending import intrinsic

# Inclusive slack on the beam's edges and the band's limits (metres): large against
# rounding (1e-16 relative), small against any cell. A centre lying on a beam edge is
# inside, and one on the free / occupied boundary is in Omega_occ, whichever way the
# world is rotated.
EDGE_TOL = 1e-9


@nb.njit(cache=True, inline="always")
def _span(
    planes: npt.NDArray[np.float64],
    cos_t: float,
    sin_t: float,
    sx: float,
    sy: float,
    yc: float,
    radius: float,
) -> tuple[float, float]:
    """x-interval of world row ``y = yc`` inside a region posed at (sx, sy, theta)."""
    dy = yc - sy
    r2 = radius * radius - dy * dy
    if r2 < 0.0:
        return 1.0, -1.0
    half = math.sqrt(r2) + EDGE_TOL
    lo = sx - half
    hi = sx + half
    for k in range(planes.shape[0]):
        a = planes[k, 0]
        b = planes[k, 1]
        # Normal rotated into the world; the plane then reads aw*x + bw*y <= cw.
        aw = a * cos_t - b * sin_t
        bw = a * sin_t + b * cos_t
        rhs = planes[k, 2] + aw * sx + bw * sy - bw * yc + EDGE_TOL
        if abs(aw) < 1e-12:
            if rhs < 0.0:
                return 1.0, -1.0
        elif aw > 0.0:
            hi = min(hi, rhs / aw)
        else:
            lo = max(lo, rhs / aw)
    return lo, hi


@nb.njit(cache=True, inline="always")
def _keep(
    x: float,
    y: float,
    sx: float,
    sy: float,
    radius: float,
    aw: npt.NDArray[np.float64],
    bw: npt.NDArray[np.float64],
    cw: npt.NDArray[np.float64],
    tol: float,
) -> bool:
    dx = x - sx
    dy = y - sy
    if dx * dx + dy * dy > (radius + tol) * (radius + tol):
        return False
    for j in range(aw.shape[0]):  # noqa: SIM110 -- numba compiles loops, not all()
        if aw[j] * x + bw[j] * y > cw[j] + tol:
            return False
    return True


@nb.njit(cache=True)
def _y_extent(
    planes: npt.NDArray[np.float64],
    cos_t: float,
    sin_t: float,
    sx: float,
    sy: float,
    radius: float,
    aw: npt.NDArray[np.float64],
    bw: npt.NDArray[np.float64],
    cw: npt.NDArray[np.float64],
) -> tuple[float, float]:
    """y-range of the region (posed at sx, sy, theta) cut by the disk of ``radius``.

    The cut is convex, so its extreme y lies at the disk's top or bottom, where an
    edge meets the circle, or at a corner of two edges; each candidate counts if it is
    inside everything else. ``aw``, ``bw``, ``cw`` are scratch space, one per edge.
    """
    k = planes.shape[0]
    for j in range(k):
        aw[j] = planes[j, 0] * cos_t - planes[j, 1] * sin_t
        bw[j] = planes[j, 0] * sin_t + planes[j, 1] * cos_t
        cw[j] = planes[j, 2] + aw[j] * sx + bw[j] * sy
    tol = 1e-7 * (1.0 + radius)
    y_lo = math.inf
    y_hi = -math.inf
    for y in (sy + radius, sy - radius):
        if _keep(sx, y, sx, sy, radius, aw, bw, cw, tol):
            y_lo = min(y_lo, y)
            y_hi = max(y_hi, y)
    for j in range(k):
        norm = math.sqrt(aw[j] * aw[j] + bw[j] * bw[j])
        if norm < 1e-12:
            continue
        # The edge a x + b y = c meets the circle at the foot of the perpendicular
        # from the centre, plus or minus t along the edge.
        dist = (cw[j] - aw[j] * sx - bw[j] * sy) / norm
        if abs(dist) <= radius:
            fx = sx + aw[j] / norm * dist
            fy = sy + bw[j] / norm * dist
            t = math.sqrt(max(radius * radius - dist * dist, 0.0))
            for sgn in (1.0, -1.0):
                x = fx - sgn * t * bw[j] / norm
                y = fy + sgn * t * aw[j] / norm
                if _keep(x, y, sx, sy, radius, aw, bw, cw, tol):
                    y_lo = min(y_lo, y)
                    y_hi = max(y_hi, y)
        for q in range(j + 1, k):
            det = aw[j] * bw[q] - aw[q] * bw[j]
            if abs(det) < 1e-12:
                continue
            x = (cw[j] * bw[q] - cw[q] * bw[j]) / det
            y = (aw[j] * cw[q] - aw[q] * cw[j]) / det
            if _keep(x, y, sx, sy, radius, aw, bw, cw, tol):
                y_lo = min(y_lo, y)
                y_hi = max(y_hi, y)
    return y_lo, y_hi


@nb.njit(cache=True, inline="always")
def _row_range(
    planes: npt.NDArray[np.float64],
    cos_t: float,
    sin_t: float,
    sx: float,
    sy: float,
    reach: float,
    oy: float,
    h: float,
    rows: int,
    scratch: npt.NDArray[np.float64],
) -> tuple[int, int]:
    """Rows whose centre may lie in the beam, with a cell of margin."""
    y_lo, y_hi = _y_extent(planes, cos_t, sin_t, sx, sy, reach, scratch[0], scratch[1], scratch[2])
    if y_hi < y_lo:
        return 0, -1
    lo = max(0, math.ceil((max(y_lo, sy - reach) - h - oy) / h - 0.5))
    hi = min(rows - 1, math.floor((min(y_hi, sy + reach) + h - oy) / h - 0.5))
    return lo, hi


@nb.njit(cache=True, inline="always")
def _bearing(dx: float, dy: float, cos_t: float, sin_t: float, d: float) -> float:
    """Angle off the beam axis; 0 for a cell centred on the sensor, where it is undefined."""
    if d < EDGE_TOL:
        return 0.0
    return math.atan2(-dx * sin_t + dy * cos_t, dx * cos_t + dy * sin_t)


@nb.njit(cache=True)
def _grow_i(a: npt.NDArray[np.int32], n: int, need: int) -> npt.NDArray[np.int32]:
    if n + need <= a.shape[0]:
        return a
    b = np.empty(max(2 * a.shape[0], n + need), dtype=a.dtype)
    b[:n] = a[:n]
    return b


@nb.njit(cache=True)
def _grow_f(a: npt.NDArray[np.float32], n: int, need: int) -> npt.NDArray[np.float32]:
    if n + need <= a.shape[0]:
        return a
    b = np.empty(max(2 * a.shape[0], n + need), dtype=a.dtype)
    b[:n] = a[:n]
    return b


@nb.njit(cache=True)
def rasterise_kernel(
    h: float,
    ox: float,
    oy: float,
    rows: int,
    cols: int,
    sx: npt.NDArray[np.float64],
    sy: npt.NDArray[np.float64],
    st: npt.NDArray[np.float64],
    free_lim: npt.NDArray[np.float64],
    occ_hi: npt.NDArray[np.float64],
    beam_planes: npt.NDArray[np.float64],
    beam_radius: float,
    zone_planes: npt.NDArray[np.float64],
    zone_radius: npt.NDArray[np.float64],
    zone_w0: npt.NDArray[np.float64],
    beam_w0: float,
    with_bearing: bool,
    capacity: int,
) -> tuple[
    npt.NDArray[np.int64],
    npt.NDArray[np.int32],
    npt.NDArray[np.float32],
    npt.NDArray[np.float32],
    npt.NDArray[np.float32],
    npt.NDArray[np.int64],
    npt.NDArray[np.int32],
    npt.NDArray[np.float32],
    npt.NDArray[np.float32],
    npt.NDArray[np.float32],
]:
    """Cells of each reading: free if d < free_lim[i], occupied if free_lim[i] <= d <= occ_hi[i].

    Returns the free set then the occupied set, each as
    (offsets, cells, distance, weight w0, bearing).
    """
    n = sx.shape[0]
    nz = zone_radius.shape[0]
    f_off = np.zeros(n + 1, dtype=np.int64)
    o_off = np.zeros(n + 1, dtype=np.int64)
    cap = max(capacity, 16)
    f_cell = np.empty(cap, dtype=np.int32)
    f_dist = np.empty(cap, dtype=np.float32)
    f_w = np.empty(cap, dtype=np.float32)
    f_b = np.empty(cap if with_bearing else 0, dtype=np.float32)
    o_cell = np.empty(cap // 4 + 16, dtype=np.int32)
    o_dist = np.empty(cap // 4 + 16, dtype=np.float32)
    o_w = np.empty(cap // 4 + 16, dtype=np.float32)
    o_b = np.empty(cap // 4 + 16 if with_bearing else 0, dtype=np.float32)
    nf = 0
    no = 0
    zlo = np.empty(nz, dtype=np.int64)
    zhi = np.empty(nz, dtype=np.int64)
    scratch = np.empty((3, beam_planes.shape[0]))
    for i in range(n):
        x0 = sx[i]
        y0 = sy[i]
        c = math.cos(st[i])
        s = math.sin(st[i])
        a_lim = free_lim[i]
        b_lim = occ_hi[i]
        # Rows and spans are taken with the slack too, or a centre exactly at the reach
        # could lose its whole row to rounding before its own test.
        reach = min(max(a_lim, b_lim), beam_radius) + EDGE_TOL
        if reach > EDGE_TOL:
            iy_lo, iy_hi = _row_range(beam_planes, c, s, x0, y0, reach, oy, h, rows, scratch)
            for iy in range(iy_lo, iy_hi + 1):
                yc = oy + (iy + 0.5) * h
                lo, hi = _span(beam_planes, c, s, x0, y0, yc, reach)
                if hi < lo:
                    continue
                c_lo = max(0, math.ceil((lo - ox) / h - 0.5))
                c_hi = min(cols - 1, math.floor((hi - ox) / h - 0.5))
                if c_hi < c_lo:
                    continue
                for z in range(nz):
                    zl, zh = _span(zone_planes[z], c, s, x0, y0, yc, zone_radius[z] + EDGE_TOL)
                    zlo[z] = math.ceil((zl - ox) / h - 0.5)
                    zhi[z] = math.floor((zh - ox) / h - 0.5)
                need = c_hi - c_lo + 1
                f_cell = _grow_i(f_cell, nf, need)
                f_dist = _grow_f(f_dist, nf, need)
                f_w = _grow_f(f_w, nf, need)
                o_cell = _grow_i(o_cell, no, need)
                o_dist = _grow_f(o_dist, no, need)
                o_w = _grow_f(o_w, no, need)
                if with_bearing:
                    f_b = _grow_f(f_b, nf, need)
                    o_b = _grow_f(o_b, no, need)
                base = (rows - 1 - iy) * cols
                dy = yc - y0
                dy2 = dy * dy
                for col in range(c_lo, c_hi + 1):
                    dx = ox + (col + 0.5) * h - x0
                    d = math.sqrt(dx * dx + dy2)
                    # The same slack as on the beam's edges: a centre within EDGE_TOL of
                    # a band limit is in the band, however the world is rotated.
                    if d < a_lim - EDGE_TOL:
                        occ = False
                    elif d <= b_lim + EDGE_TOL:
                        occ = True
                    else:
                        continue
                    w = beam_w0
                    for z in range(nz):
                        if zlo[z] <= col <= zhi[z]:
                            w = zone_w0[z]
                            break
                    if occ:
                        o_cell[no] = base + col
                        o_dist[no] = d
                        o_w[no] = w
                        if with_bearing:
                            o_b[no] = _bearing(dx, dy, c, s, d)
                        no += 1
                    else:
                        f_cell[nf] = base + col
                        f_dist[nf] = d
                        f_w[nf] = w
                        if with_bearing:
                            f_b[nf] = _bearing(dx, dy, c, s, d)
                        nf += 1
        f_off[i + 1] = nf
        o_off[i + 1] = no
    return (
        f_off,
        f_cell[:nf].copy(),
        f_dist[:nf].copy(),
        f_w[:nf].copy(),
        f_b[:nf].copy() if with_bearing else f_b,
        o_off,
        o_cell[:no].copy(),
        o_dist[:no].copy(),
        o_w[:no].copy(),
        o_b[:no].copy() if with_bearing else o_b,
    )


# Cells the insertion kernel updates at once (one AVX-512 vector of float64, two AVX2
# ones). Numba's loop vectoriser leaves scalar whatever does not fill several vectors,
# and most rows of a beam hold a few dozen cells; blocks of LANES cells vectorise every
# row whole (read and written whole inside the grid, through masks at its edge).
LANES = 8

# Relative margin around a threshold's square inside which the insertion kernel takes
# the square root to compare a distance: sixteen machine epsilons cover the rounding of
# the square, of the margin and of the correctly rounded root with room to spare.
SQRT_SLACK = 16 * 2.0**-52

# The insertion kernel's row parameters, in this order (see _update_blocks).
_ROW_PARAMS = (
    "ox",
    "h",
    "x0",
    "dy",
    "cos",
    "sin",
    "inc_free",
    "inc_occ",
    "lo",
    "hi",
    "f_thr",
    "o_thr",
    "t_free",
    "t_occ",
)

# A row this close to the sensor (metres) is weighted cell by cell: there a centre may
# lie nearer than EDGE_TOL (angle 0 by convention), or well outside the beam's angles
# yet within EDGE_TOL of its edges.
ROW_TOL = 1e-5


def _splat(builder: Any, x: Any) -> Any:
    vec = ir.VectorType(x.type, LANES)
    undef = ir.Constant(vec, ir.Undefined)
    zeros = ir.Constant(ir.VectorType(ir.IntType(32), LANES), [0] * LANES)
    return builder.shuffle_vector(
        builder.insert_element(undef, x, ir.Constant(ir.IntType(32), 0)), undef, zeros
    )


def _declare(builder: Any, name: str, ret: Any, args: list[Any]) -> Any:
    fn = builder.module.globals.get(name)
    return fn if fn is not None else ir.Function(builder.module, ir.FunctionType(ret, args), name)


def _masked(builder: Any, op: str, vec: Any, ptr: Any, suffix: str) -> Any:
    """llvm.masked.load / llvm.masked.store for ``vec`` through ``ptr``."""
    # LLVM names the pointer type in the intrinsic: p0 when pointers are opaque (LLVM
    # 15 on), p0v8f64 and the like with llvmlite's older typed pointers.
    pname = "p0" if str(ptr.type) == "ptr" else "p0" + suffix
    mask = ir.VectorType(ir.IntType(1), LANES)
    i32 = ir.IntType(32)
    if op == "load":
        return _declare(
            builder, f"llvm.masked.load.{suffix}.{pname}", vec, [ptr.type, i32, mask, vec]
        )
    return _declare(
        builder, f"llvm.masked.store.{suffix}.{pname}", ir.VoidType(), [vec, ptr.type, i32, mask]
    )


def _arrays_ok(values: Any, touched: Any, params: Any) -> bool:
    """Flat contiguous arrays only (the blocks address them as base + column), and a
    full set of row parameters."""
    for arr, dtype in ((values, types.float64), (touched, types.boolean)):
        if not (isinstance(arr, types.Array) and arr.dtype == dtype and arr.ndim == 1):
            return False
        if arr.layout != "C":
            return False
    return len(params) == len(_ROW_PARAMS)


class _Row:
    """A row's values splat over LANES, and the block operations both insertion
    intrinsics share (the same instructions, so the same bits)."""

    def __init__(self, context: Any, builder: Any, sig: Any, args: Any) -> None:
        vals, tch, _, _, _, _, *rest = args
        params, coef = rest[-2], rest[-1]
        self.b = builder
        self.f64 = ir.DoubleType()
        self.i64 = ir.IntType(64)
        self.vd = ir.VectorType(self.f64, LANES)
        self.vi = ir.VectorType(self.i64, LANES)
        self.vb = ir.VectorType(ir.IntType(8), LANES)
        self.bits = ir.IntType(LANES)
        self.p = {n: builder.extract_value(params, k) for k, n in enumerate(_ROW_PARAMS)}
        self.s = {n: _splat(builder, v) for n, v in self.p.items()}
        ncoef = len(sig.args[-1])
        self.coefs = [_splat(builder, builder.extract_value(coef, j)) for j in range(ncoef)]
        self.dy_s = _splat(builder, builder.fmul(self.p["dy"], self.p["sin"]))
        self.dy_c = _splat(builder, builder.fmul(self.p["dy"], self.p["cos"]))
        self.half = _splat(builder, ir.Constant(self.f64, 0.5))
        self.varr = context.make_array(sig.args[0])(context, builder, vals)
        self.tarr = context.make_array(sig.args[1])(context, builder, tch)

    def dx(self, col_f: Any) -> Any:
        """x offsets of the cell centres from the sensor: the rasteriser's, operation for
        operation, so that a centre decides alike."""
        b, s = self.b, self.s
        return b.fsub(b.fadd(s["ox"], b.fmul(b.fadd(col_f, self.half), s["h"])), s["x0"])

    def weigh(self, inc: Any, dx: Any) -> Any:
        """``inc`` times the fall-off polynomial at each cell's angle (none without one)."""
        if not self.coefs:
            return inc
        b, s = self.b, self.s
        # Contraction into fused multiply-adds, where the machine has them, for the
        # fall-off only: it changes the last bit of the weight, never the cells.
        fma = ("contract",)
        along = b.fadd(b.fmul(dx, s["cos"], flags=fma), self.dy_s, flags=fma)
        across = b.fsub(self.dy_c, b.fmul(dx, s["sin"], flags=fma), flags=fma)
        q = b.fdiv(across, along)
        u = b.fmul(q, q)
        w = self.coefs[-1]
        for c in reversed(self.coefs[:-1]):
            w = b.fadd(b.fmul(w, u, flags=fma), c, flags=fma)
        return b.fmul(inc, w)

    def write(
        self,
        base: Any,
        col: Any,
        col_end: Any,
        in_row: Any,
        update: Any,
        free: Any,
        dx: Callable[[], Any],
    ) -> None:
        """Add each cell's increment (``inc_free`` where ``free``, else ``inc_occ``, times
        its fall-off weight) to the cells of the block at ``col`` where ``update``,
        clamped. ``dx`` emits the cells' x offsets (:meth:`dx`) where the weights need
        them.

        With a fall-off, a block whose updated cells all hold their increment's clamp
        target (``t_free``, ``t_occ``: see :func:`_clamp_target`) takes that target
        without its weights being computed: clamping would give it whatever the weight.
        """
        b, s = self.b, self.s
        i32 = ir.IntType(32)
        at = b.add(base, col)
        vptr = b.bitcast(b.gep(self.varr.data, [at]), self.vd.as_pointer())
        tptr = b.bitcast(b.gep(self.tarr.data, [at]), self.vb.as_pointer())

        def clamp(v: Any) -> Any:
            v = b.select(b.fcmp_ordered(">", v, s["lo"]), v, s["lo"])
            return b.select(b.fcmp_ordered("<", v, s["hi"]), v, s["hi"])

        # A block inside the grid's row is read and written whole, its lanes off the
        # span written back unchanged: the row is this thread's alone. Masked stores
        # are slow without AVX-512 (a byte-masked one becomes eight branches), and most
        # blocks of a beam's row lie inside the grid. A block passing the grid's edge
        # goes through masks: its masked lanes are neither read nor written, so nothing
        # beyond the row (another thread's, or past the array) is touched.
        whole = b.icmp_signed("<=", b.add(col, ir.Constant(self.i64, LANES - 1)), col_end)
        load_whole = b.append_basic_block("blocks.load_whole")
        load_edge = b.append_basic_block("blocks.load_edge")
        loaded = b.append_basic_block("blocks.loaded")
        b.cbranch(whole, load_whole, load_edge)
        b.position_at_end(load_whole)
        old_whole = b.load(vptr, align=8)
        b.branch(loaded)
        b.position_at_end(load_edge)
        zero = _splat(b, ir.Constant(self.f64, 0.0))
        old_edge = b.call(
            _masked(b, "load", self.vd, vptr, f"v{LANES}f64"),
            [vptr, ir.Constant(i32, 8), in_row, zero],
        )
        b.branch(loaded)
        b.position_at_end(loaded)
        old = b.phi(self.vd)
        old.add_incoming(old_whole, load_whole)
        old.add_incoming(old_edge, load_edge)
        inc = b.select(free, s["inc_free"], s["inc_occ"])
        if not self.coefs:
            new = clamp(b.fadd(old, inc))
        else:
            # Most of a long log's updates find their cell already at the clamp bound
            # their increment pushes towards (72 % of 2 minutes of the office ring):
            # the weight, the dearest part of an update, is then not needed.
            target = b.select(free, s["t_free"], s["t_occ"])
            held = b.fcmp_ordered("==", old, target)
            todo = b.and_(update, b.not_(held))
            skip = b.block
            weigh = b.append_basic_block("blocks.weigh")
            joined = b.append_basic_block("blocks.joined")
            b.cbranch(
                b.icmp_unsigned("!=", b.bitcast(todo, self.bits), ir.Constant(self.bits, 0)),
                weigh,
                joined,
            )
            b.position_at_end(weigh)
            weighed = clamp(b.fadd(old, self.weigh(inc, dx())))
            b.branch(joined)
            b.position_at_end(joined)
            new = b.phi(self.vd)
            new.add_incoming(target, skip)
            new.add_incoming(weighed, weigh)
        store_whole = b.append_basic_block("blocks.store_whole")
        store_edge = b.append_basic_block("blocks.store_edge")
        latch = b.append_basic_block("blocks.latch")
        b.cbranch(whole, store_whole, store_edge)

        b.position_at_end(store_whole)
        b.store(b.select(update, new, old), vptr, align=8)
        flags = b.load(tptr, align=1)
        b.store(b.or_(flags, b.zext(update, self.vb)), tptr, align=1)
        b.branch(latch)

        b.position_at_end(store_edge)
        b.call(
            _masked(b, "store", self.vd, vptr, f"v{LANES}f64"),
            [new, vptr, ir.Constant(i32, 8), update],
        )
        b.call(
            _masked(b, "store", self.vb, tptr, f"v{LANES}i8"),
            [ir.Constant(self.vb, [1] * LANES), tptr, ir.Constant(i32, 1), update],
        )
        b.branch(latch)
        b.position_at_end(latch)


def _block_loop(row: _Row, col_from: Any, col_to: Any, body: Callable[[Any, Any, Any], Any]) -> Any:
    """Run ``body(col, col_f, col_i)`` on the blocks of columns ``col_from .. col_to``
    (the block's first column, and its LANES columns as floats and as integers); sums
    what each call returns."""
    b = row.b
    lanes_f = ir.Constant(row.vd, [float(k) for k in range(LANES)])
    first_f = b.fadd(_splat(b, b.sitofp(col_from, row.f64)), lanes_f)
    first_i = b.add(_splat(b, col_from), ir.Constant(row.vi, list(range(LANES))))
    entry = b.block
    head = b.append_basic_block("blocks.head")
    start = b.append_basic_block("blocks.body")
    done = b.append_basic_block("blocks.done")
    b.branch(head)
    b.position_at_end(head)
    col = b.phi(row.i64)
    col_f = b.phi(row.vd)
    col_i = b.phi(row.vi)
    count = b.phi(row.i64)
    col.add_incoming(col_from, entry)
    col_f.add_incoming(first_f, entry)
    col_i.add_incoming(first_i, entry)
    count.add_incoming(ir.Constant(row.i64, 0), entry)
    b.cbranch(b.icmp_signed("<=", col, col_to), start, done)
    b.position_at_end(start)
    n = body(col, col_f, col_i)
    latch = b.block
    col.add_incoming(b.add(col, ir.Constant(row.i64, LANES)), latch)
    col_f.add_incoming(b.fadd(col_f, _splat(b, ir.Constant(row.f64, LANES))), latch)
    col_i.add_incoming(b.add(col_i, _splat(b, ir.Constant(row.i64, LANES))), latch)
    count.add_incoming(b.add(count, n), latch)
    b.branch(head)
    b.position_at_end(done)
    return count


def _blocks_intrinsic(
    typingctx: Any,
    values: Any,
    touched: Any,
    base: Any,
    col_from: Any,
    col_to: Any,
    col_end: Any,
    params: Any,
    coef: Any,
) -> Any:
    """Update cells ``base + col_from .. base + col_to`` of one row, LANES at a time,
    each decided by its distance to the sensor.

    ``col_end`` is the row's last column in the grid: a block that ends by it is read
    and written whole, one that passes it through masks.

    ``params`` holds the row's values named in _ROW_PARAMS. A cell is free if its
    distance d to the sensor is below ``f_thr``, occupied if d <= ``o_thr`` (the
    rasteriser's test, computed the same way), otherwise left alone. ``coef`` is empty
    for uniform increments; otherwise both increments are scaled by the polynomial with
    these coefficients (lowest first) in u = tan^2 of the cell's angle off the axis.
    Returns the number of cells updated.
    """
    if not _arrays_ok(values, touched, params):
        return None
    sig = types.int64(values, touched, base, col_from, col_to, col_end, params, coef)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        row = _Row(context, builder, signature, args)
        b, p, s = builder, row.p, row.s
        base, col_from, col_to, col_end = args[2:6]
        dy2 = _splat(b, b.fmul(p["dy"], p["dy"]))
        sqrt = _declare(b, f"llvm.sqrt.v{LANES}f64", row.vd, [row.vd])
        ctpop = _declare(b, f"llvm.ctpop.i{LANES}", row.bits, [row.bits])

        def band(t: Any) -> tuple[Any, Any]:
            # Squared distances below the first bound have sqrt(d2) < t once rounded,
            # those at or above the second sqrt(d2) > t; between, the root decides. A
            # threshold <= 0 (or NaN) admits no centre: both bounds below any d2.
            t2 = b.fmul(t, t)
            pos = b.fcmp_ordered(">", t, ir.Constant(row.f64, 0.0))
            lo2 = b.fmul(t2, ir.Constant(row.f64, 1.0 - SQRT_SLACK))
            hi2 = b.fmul(t2, ir.Constant(row.f64, 1.0 + SQRT_SLACK))
            none = ir.Constant(row.f64, -1.0)
            return _splat(b, b.select(pos, lo2, none)), _splat(b, b.select(pos, hi2, none))

        f_band = band(p["f_thr"])
        o_band = band(p["o_thr"])

        def body(col: Any, col_f: Any, col_i: Any) -> Any:
            dx = row.dx(col_f)
            d2 = b.fadd(b.fmul(dx, dx), dy2)
            in_row = b.icmp_signed("<=", col_i, _splat(b, col_to))
            # The square root is the block's slowest step on AVX2 (vsqrtpd), and only
            # a centre within a few ulps of a threshold's square needs it to decide
            # alike.
            near = b.or_(
                b.and_(b.fcmp_ordered(">", d2, f_band[0]), b.fcmp_ordered("<", d2, f_band[1])),
                b.and_(b.fcmp_ordered(">", d2, o_band[0]), b.fcmp_ordered("<", d2, o_band[1])),
            )
            near = b.bitcast(b.and_(near, in_row), row.bits)
            free_s = b.fcmp_ordered("<", d2, f_band[1])
            occ_s = b.fcmp_ordered("<", d2, o_band[1])
            sure = b.block
            exact = b.append_basic_block("blocks.exact")
            decide = b.append_basic_block("blocks.decide")
            b.cbranch(b.icmp_unsigned("!=", near, ir.Constant(row.bits, 0)), exact, decide)
            b.position_at_end(exact)
            d = b.call(sqrt, [d2])
            free_x = b.fcmp_ordered("<", d, s["f_thr"])
            occ_x = b.fcmp_ordered("<=", d, s["o_thr"])
            b.branch(decide)
            b.position_at_end(decide)
            mask = ir.VectorType(ir.IntType(1), LANES)
            free = b.phi(mask)
            free.add_incoming(free_s, sure)
            free.add_incoming(free_x, exact)
            occ = b.phi(mask)
            occ.add_incoming(occ_s, sure)
            occ.add_incoming(occ_x, exact)
            update = b.and_(in_row, b.or_(free, occ))
            row.write(base, col, col_end, in_row, update, free, lambda: dx)
            return b.zext(b.call(ctpop, [b.bitcast(update, row.bits)]), row.i64)

        return _block_loop(row, col_from, col_to, body)

    return sig, codegen


def _runs_intrinsic(
    typingctx: Any,
    values: Any,
    touched: Any,
    base: Any,
    col_from: Any,
    col_to: Any,
    col_end: Any,
    free_from: Any,
    free_to: Any,
    params: Any,
    coef: Any,
) -> Any:
    """Update every cell ``base + col_from .. base + col_to`` of one row, LANES at a
    time: free for columns ``free_from .. free_to``, occupied for the others.

    The row's band is known as column intervals (see :func:`_interval`), so no cell's
    distance is computed. ``col_end``, ``params`` and ``coef`` are those of
    :func:`_blocks_intrinsic` (``f_thr`` and ``o_thr`` unused), and a cell's weight is
    computed as there, to the bit.
    """
    if not _arrays_ok(values, touched, params):
        return None
    sig = types.none(
        values, touched, base, col_from, col_to, col_end, free_from, free_to, params, coef
    )

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        row = _Row(context, builder, signature, args)
        b = builder
        base, col_from, col_to, col_end, free_from, free_to = args[2:8]
        to_s = _splat(b, col_to)
        lo_s = _splat(b, free_from)
        hi_s = _splat(b, free_to)

        def body(col: Any, col_f: Any, col_i: Any) -> Any:
            in_row = b.icmp_signed("<=", col_i, to_s)
            free = b.and_(b.icmp_signed(">=", col_i, lo_s), b.icmp_signed("<=", col_i, hi_s))
            row.write(base, col, col_end, in_row, in_row, free, lambda: row.dx(col_f))
            return ir.Constant(row.i64, 0)

        _block_loop(row, col_from, col_to, body)
        return context.get_dummy_value()

    return sig, codegen


# Typed as Any: numba's intrinsic wrapper takes the arguments after typingctx.
_update_blocks: Any = intrinsic(_blocks_intrinsic)
_update_runs: Any = intrinsic(_runs_intrinsic)


# Relative margin (of the coordinates and of a threshold's square) inside which a
# band's edge computed in a row is too close to a cell centre to decide that centre:
# 2^-40, thousands of times the rounding of the rasteriser's test and of the edge's own
# computation, and still a few nanometres on a map of kilometres.
RUN_SLACK = 2.0**-40


@nb.njit(cache=True, inline="always")
def _interval(
    t2: float,
    slack: float,
    dy2: float,
    mid: float,
    inv_h: float,
    size: float,
    end: float,
) -> tuple[float, float, bool]:
    """Columns ``lo .. hi`` of a row whose centre lies nearer than t to the sensor, and
    whether that is sure (as floats holding integers; lo > hi when there are none).

    ``t2`` is t squared (negative when no centre is nearer) and ``slack``
    :data:`RUN_SLACK` times it, ``dy2`` the row's squared offset from the sensor,
    ``mid`` the sensor's x in columns (centres at integers), ``inv_h`` one over the cell
    size, ``size`` the scale of the coordinates (metres: ``|ox| + |x0| + h``) and
    ``end`` the grid's last column. A centre at x is nearer iff
    ``|x - x0| < sqrt(t^2 - dy2)``: the columns between two edges. An edge within
    :data:`RUN_SLACK` of a centre (rounding could decide that centre either way), or a
    row that only grazes the circle, is not sure: the caller then tests each centre as
    the rasteriser does. Away from the edges ``d <= t`` gives the same columns as
    ``d < t``. Free of branches, so that a loop over rows vectorises.
    """
    g = t2 - dy2
    none = g < -slack
    half = math.sqrt(max(g, 0.0))
    w = half * inv_h
    left = min(max(mid - w, -1.5), end + 1.5)
    right = min(max(mid + w, -1.5), end + 1.5)
    fl = np.floor(left)
    fr = np.floor(right)
    # An edge's error, in columns: rounding of the coordinates (size) and of the
    # squares (t^2 / half), times the slack; multiplied through by half.
    gap = min(min(left - fl, fl + 1.0 - left), min(right - fr, fr + 1.0 - right))
    clear = (g > slack) & (gap * half > RUN_SLACK * ((size + half) * half + t2) * inv_h)
    return (1.0 if none else fl + 1.0), (0.0 if none else fr), none | clear


# The rows _row_pass fills, one per quantity.
_ROW_C_LO, _ROW_C_HI, _ROW_DY, _ROW_F_LO, _ROW_F_HI, _ROW_O_LO, _ROW_O_HI, _ROW_SURE = range(8)


@nb.njit(cache=True)
def _row_pass(
    out: npt.NDArray[np.float64],
    iy_lo: int,
    n: int,
    planes: npt.NDArray[np.float64],
    cos_t: float,
    sin_t: float,
    sx: float,
    sy: float,
    radius: float,
    ox: float,
    oy: float,
    h: float,
    cols: int,
    f_thr: float,
    o_thr: float,
) -> None:
    """Per row ``iy_lo + j`` (j < n) of one reading, into ``out[:, j]``: the beam's
    columns (:func:`_span` and the kernels' rounding, operation for operation), the
    row's offset dy from the sensor, and the band's column intervals
    (:func:`_interval`).

    Each quantity is a loop over the rows without branches, so that it vectorises: a
    beam's row holds a few blocks of cells, and the scalar row work was as dear as
    they.
    """
    inv_h = 1.0 / h
    end = cols - 1.0
    mid = (sx - ox) * inv_h - 0.5
    size = abs(ox) + abs(sx) + h
    f_t2 = f_thr * f_thr if f_thr > 0.0 else -1.0
    o_t2 = o_thr * o_thr if o_thr > 0.0 else -1.0
    f_slack = RUN_SLACK * f_t2
    o_slack = RUN_SLACK * o_t2
    lo = out[_ROW_C_LO]
    hi = out[_ROW_C_HI]
    dys = out[_ROW_DY]
    for j in range(n):
        yc = oy + (iy_lo + j + 0.5) * h
        dy = yc - sy
        r2 = radius * radius - dy * dy
        half = math.sqrt(max(r2, 0.0)) + EDGE_TOL
        inside = r2 >= 0.0
        lo[j] = sx - half if inside else math.inf
        hi[j] = sx + half if inside else -math.inf
        dys[j] = dy
    for k in range(planes.shape[0]):
        a = planes[k, 0]
        b = planes[k, 1]
        aw = a * cos_t - b * sin_t
        bw = a * sin_t + b * cos_t
        c0 = planes[k, 2] + aw * sx + bw * sy
        if abs(aw) < 1e-12:
            for j in range(n):
                yc = oy + (iy_lo + j + 0.5) * h
                if c0 - bw * yc + EDGE_TOL < 0.0:
                    lo[j] = math.inf
        elif aw > 0.0:
            for j in range(n):
                yc = oy + (iy_lo + j + 0.5) * h
                hi[j] = min(hi[j], (c0 - bw * yc + EDGE_TOL) / aw)
        else:
            for j in range(n):
                yc = oy + (iy_lo + j + 0.5) * h
                lo[j] = max(lo[j], (c0 - bw * yc + EDGE_TOL) / aw)
    f_lo = out[_ROW_F_LO]
    f_hi = out[_ROW_F_HI]
    o_lo = out[_ROW_O_LO]
    o_hi = out[_ROW_O_HI]
    sure = out[_ROW_SURE]
    for j in range(n):
        a_lo = lo[j]
        a_hi = hi[j]
        empty = a_hi < a_lo
        lo[j] = 1.0 if empty else max(0.0, np.ceil((a_lo - ox) / h - 0.5))
        hi[j] = 0.0 if empty else min(end, np.floor((a_hi - ox) / h - 0.5))
        dy2 = dys[j] * dys[j]
        f_lo[j], f_hi[j], f_sure = _interval(f_t2, f_slack, dy2, mid, inv_h, size, end)
        o_lo[j], o_hi[j], o_sure = _interval(o_t2, o_slack, dy2, mid, inv_h, size, end)
        sure[j] = 1.0 if f_sure and o_sure else 0.0


@nb.njit(cache=True, inline="always")
def _clamp_target(inc: float, lo: float, hi: float) -> float:
    """The value a cell holding it keeps when ``inc`` times any weight w >= 0 is added
    and the sum clamped to [lo, hi] (the kernels' clamp); NaN, equal to no value, when
    there is none to rely on.

    ``v = lo + inc * w`` with inc < 0 is at most lo (or NaN, for an infinite inc and w
    = 0), which the clamp's first step maps to lo and its second keeps when lo < hi;
    with inc > 0 and finite, v >= hi > lo, which the clamp maps to hi. So the result is
    the bound itself, bit for bit (its sign of zero included), whatever w is.
    """
    if not lo < hi:
        return math.nan
    if inc < 0.0:
        return lo
    if inc > 0.0 and inc < math.inf:
        return hi
    return math.nan


@nb.njit(cache=True)
def _update_cells(
    values: npt.NDArray[np.float64],
    touched: npt.NDArray[np.bool_],
    base: int,
    col_from: int,
    col_to: int,
    params: tuple[float, ...],
    sigma: float,
) -> int:
    """:func:`_update_blocks` one cell at a time, with the fall-off weight (standard
    deviation ``sigma``, radians; 0 for none) computed exactly from each cell's angle."""
    ox, h, x0, dy, c, s, inc_free, inc_occ, lo, hi, f_thr, o_thr, _, _ = params
    n = 0
    for col in range(col_from, col_to + 1):
        dx = ox + (col + 0.5) * h - x0
        d = math.sqrt(dx * dx + dy * dy)
        if d < f_thr:
            inc = inc_free
        elif d <= o_thr:
            inc = inc_occ
        else:
            continue
        if sigma > 0.0:
            b = _bearing(dx, dy, c, s, d) / sigma
            inc *= math.exp(-0.5 * b * b)
        v = values[base + col] + inc
        v = v if v > lo else lo
        values[base + col] = v if v < hi else hi
        touched[base + col] = True
        n += 1
    return n


@nb.njit(cache=True)
def accumulate_kernel(
    values: npt.NDArray[np.float64],
    touched: npt.NDArray[np.bool_],
    h: float,
    ox: float,
    oy: float,
    rows: int,
    cols: int,
    sx: npt.NDArray[np.float64],
    sy: npt.NDArray[np.float64],
    st: npt.NDArray[np.float64],
    free_lim: npt.NDArray[np.float64],
    occ_hi: npt.NDArray[np.float64],
    beam_planes: npt.NDArray[np.float64],
    beam_radius: float,
    inc_free: float,
    inc_occ: float,
    lo: float,
    hi: float,
    sigma: float,
    coef: tuple[float, ...],
    part: int = 0,
    parts: int = 1,
    stripe: int = 8,
    weight: npt.NDArray[np.float64] | None = None,
    runs: bool = True,
    positive: bool = False,
) -> int:
    """Add ``inc_free`` to the Omega_free cells and ``inc_occ`` to the Omega_occ cells of
    each reading, in reading order, clamping to [lo, hi] after each addition; returns
    the number of cell updates.

    The cells are exactly those of :func:`rasterise_kernel`: the same rows and spans,
    and the same decision at each centre. A row's band is taken as column intervals,
    their edges computed once (:func:`_row_pass`), and its cells updated as one run,
    LANES at a time, with no distance test (:func:`_update_runs`); a row with an edge
    within :data:`RUN_SLACK` of a centre, and every row when ``runs`` is False (the
    reference the runs are tested against, bit for bit), tests each cell's distance as
    the rasteriser does (:func:`_update_blocks`).

    With ``sigma > 0`` both increments are scaled by ``exp(-b^2 / (2 sigma^2))``, b the
    cell's angle off the beam axis (the rasteriser's bearing). ``coef`` is a polynomial
    in u = tan^2 b that gives that weight over all the beam's angles (its caller fits
    it, :func:`sonarmap.raster.falloff_fit`); rows within ROW_TOL of the sensor, and all
    rows when ``coef`` is empty, are weighted cell by cell with atan2 and exp.

    With ``parts > 1`` only the rows of stripes ``part``, ``part + parts``, ... (stripes
    of ``stripe`` rows) are updated: parts can run in parallel, and each cell still sees
    the readings in order.

    With ``weight`` (one per reading) reading i's increments are ``weight[i]`` times
    ``inc_free`` and ``inc_occ``. Without it (None) numba compiles the branch away: the
    unweighted insertion runs the code it ran before weights existed.

    ``positive`` is the caller's word that the polynomial ``coef`` is positive over the
    beam's angles (:func:`sonarmap.raster.falloff_positive`). A block of cells that all
    hold the clamp bound their increment pushes towards then takes that bound without
    its weights computed (:func:`_clamp_target`): the same values, to the bit, as with
    ``positive`` False, which computes every weight.
    """
    n = sx.shape[0]
    total = 0
    scratch = np.empty((3, beam_planes.shape[0]))
    row_buf = np.empty((8, rows + 1))
    for i in range(n):
        x0 = sx[i]
        y0 = sy[i]
        c = math.cos(st[i])
        s = math.sin(st[i])
        inc_f = inc_free
        inc_o = inc_occ
        if weight is not None:
            inc_f = inc_free * weight[i]
            inc_o = inc_occ * weight[i]
        # NaN targets (no cell equals them) leave every weight to compute.
        t_f = _clamp_target(inc_f, lo, hi) if positive else math.nan
        t_o = _clamp_target(inc_o, lo, hi) if positive else math.nan
        # The rasteriser's band limits with its slack; a no-echo reading has no band.
        f_thr = free_lim[i] - EDGE_TOL
        o_thr = occ_hi[i] + EDGE_TOL
        reach = min(max(free_lim[i], occ_hi[i]), beam_radius) + EDGE_TOL
        if reach <= EDGE_TOL:
            continue
        iy_lo, iy_hi = _row_range(beam_planes, c, s, x0, y0, reach, oy, h, rows, scratch)
        n_rows = iy_hi - iy_lo + 1
        if n_rows <= 0:
            continue
        _row_pass(
            row_buf, iy_lo, n_rows, beam_planes, c, s, x0, y0, reach, ox, oy, h, cols, f_thr, o_thr
        )
        for j in range(n_rows):
            iy = iy_lo + j
            if parts > 1 and (iy // stripe) % parts != part:
                continue
            if not row_buf[_ROW_C_LO, j] <= row_buf[_ROW_C_HI, j]:
                continue
            c_lo = int(row_buf[_ROW_C_LO, j])
            c_hi = int(row_buf[_ROW_C_HI, j])
            dy = row_buf[_ROW_DY, j]
            base = (rows - 1 - iy) * cols
            params = (ox, h, x0, dy, c, s, inc_f, inc_o, lo, hi, f_thr, o_thr, t_f, t_o)
            flat = sigma <= 0.0
            if not flat and (len(coef) == 0 or abs(dy) <= ROW_TOL):
                total += _update_cells(values, touched, base, c_lo, c_hi, params, sigma)
                continue
            if not runs or row_buf[_ROW_SURE, j] == 0.0:
                if flat:
                    total += _update_blocks(values, touched, base, c_lo, c_hi, cols - 1, params, ())
                else:
                    total += _update_blocks(
                        values, touched, base, c_lo, c_hi, cols - 1, params, coef
                    )
                continue
            f_lo = max(int(row_buf[_ROW_F_LO, j]), c_lo)
            f_hi = min(int(row_buf[_ROW_F_HI, j]), c_hi)
            o_lo = max(int(row_buf[_ROW_O_LO, j]), c_lo)
            o_hi = min(int(row_buf[_ROW_O_HI, j]), c_hi)
            # Both sets are centred on the sensor's column: the smaller lies in the
            # larger, and together they are one run.
            u_lo, u_hi = (o_lo, o_hi) if f_hi < f_lo else (f_lo, f_hi)
            if f_lo <= f_hi and o_lo <= o_hi:
                u_lo, u_hi = min(f_lo, o_lo), max(f_hi, o_hi)
            if u_hi < u_lo:
                continue
            total += u_hi - u_lo + 1
            if flat:
                _update_runs(values, touched, base, u_lo, u_hi, cols - 1, f_lo, f_hi, params, ())
            else:
                _update_runs(values, touched, base, u_lo, u_hi, cols - 1, f_lo, f_hi, params, coef)
    return total


@nb.njit(cache=True, parallel=True)
def accumulate_parallel(
    values: npt.NDArray[np.float64],
    touched: npt.NDArray[np.bool_],
    h: float,
    ox: float,
    oy: float,
    rows: int,
    cols: int,
    sx: npt.NDArray[np.float64],
    sy: npt.NDArray[np.float64],
    st: npt.NDArray[np.float64],
    free_lim: npt.NDArray[np.float64],
    occ_hi: npt.NDArray[np.float64],
    beam_planes: npt.NDArray[np.float64],
    beam_radius: float,
    inc_free: float,
    inc_occ: float,
    lo: float,
    hi: float,
    sigma: float,
    coef: tuple[float, ...],
    parts: int,
    weight: npt.NDArray[np.float64] | None = None,
    positive: bool = False,
) -> int:
    """:func:`accumulate_kernel` split over ``parts`` threads by interleaved row stripes;
    the result is the same as one thread's."""
    counts = np.zeros(parts, dtype=np.int64)
    for p in nb.prange(parts):
        counts[p] = accumulate_kernel(
            values,
            touched,
            h,
            ox,
            oy,
            rows,
            cols,
            sx,
            sy,
            st,
            free_lim,
            occ_hi,
            beam_planes,
            beam_radius,
            inc_free,
            inc_occ,
            lo,
            hi,
            sigma,
            coef,
            p,
            parts,
            8,
            weight,
            True,
            positive,
        )
    return int(counts.sum())
