"""The numba kernels behind :mod:`sonarmap.raster` (private)."""

from __future__ import annotations

import math
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
    """Update cells ``base + col_from .. base + col_to`` of one row, LANES at a time.

    ``col_end`` is the row's last column in the grid: a block that ends by it is read
    and written whole, one that passes it through masks.

    ``params`` holds the row's values named in _ROW_PARAMS. A cell is free if its
    distance d to the sensor is below ``f_thr``, occupied if d <= ``o_thr`` (the
    rasteriser's test, computed the same way), otherwise left alone. ``coef`` is empty
    for uniform increments; otherwise both increments are scaled by the polynomial with
    these coefficients (lowest first) in u = tan^2 of the cell's angle off the axis.
    Returns the number of cells updated.
    """
    # Flat contiguous arrays only: the blocks address them as base + column.
    for arr, dtype in ((values, types.float64), (touched, types.boolean)):
        if not (isinstance(arr, types.Array) and arr.dtype == dtype and arr.ndim == 1):
            return None
        if arr.layout != "C":
            return None
    if len(params) != len(_ROW_PARAMS):
        return None
    ncoef = len(coef)
    sig = types.int64(values, touched, base, col_from, col_to, col_end, params, coef)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        vals, tch, base, col_from, col_to, col_end, params, coef = args
        f64 = ir.DoubleType()
        i64 = ir.IntType(64)
        i32 = ir.IntType(32)
        vd = ir.VectorType(f64, LANES)
        vi = ir.VectorType(i64, LANES)
        vb = ir.VectorType(ir.IntType(8), LANES)
        bits = ir.IntType(LANES)
        # Contraction into fused multiply-adds, where the machine has them, for the
        # fall-off only: it changes the last bit of the weight, never the cells.
        fma = ("contract",)
        p = {n: builder.extract_value(params, k) for k, n in enumerate(_ROW_PARAMS)}
        s = {n: _splat(builder, v) for n, v in p.items()}
        dy2 = _splat(builder, builder.fmul(p["dy"], p["dy"]))
        dy_s = _splat(builder, builder.fmul(p["dy"], p["sin"]))
        dy_c = _splat(builder, builder.fmul(p["dy"], p["cos"]))
        coefs = [_splat(builder, builder.extract_value(coef, j)) for j in range(ncoef)]
        zero = _splat(builder, ir.Constant(f64, 0.0))
        half = _splat(builder, ir.Constant(f64, 0.5))
        sqrt = _declare(builder, f"llvm.sqrt.v{LANES}f64", vd, [vd])

        def band(t: Any) -> tuple[Any, Any]:
            # Squared distances below the first bound have sqrt(d2) < t once rounded,
            # those at or above the second sqrt(d2) > t; between, the root decides. A
            # threshold <= 0 (or NaN) admits no centre: both bounds below any d2.
            t2 = builder.fmul(t, t)
            pos = builder.fcmp_ordered(">", t, ir.Constant(f64, 0.0))
            lo2 = builder.fmul(t2, ir.Constant(f64, 1.0 - SQRT_SLACK))
            hi2 = builder.fmul(t2, ir.Constant(f64, 1.0 + SQRT_SLACK))
            none = ir.Constant(f64, -1.0)
            return (
                _splat(builder, builder.select(pos, lo2, none)),
                _splat(builder, builder.select(pos, hi2, none)),
            )

        f_band = band(p["f_thr"])
        o_band = band(p["o_thr"])
        ctpop = _declare(builder, f"llvm.ctpop.i{LANES}", bits, [bits])
        varr = context.make_array(signature.args[0])(context, builder, vals)
        tarr = context.make_array(signature.args[1])(context, builder, tch)

        lanes_f = ir.Constant(vd, [float(k) for k in range(LANES)])
        first_f = builder.fadd(_splat(builder, builder.sitofp(col_from, f64)), lanes_f)
        first_i = builder.add(_splat(builder, col_from), ir.Constant(vi, list(range(LANES))))
        entry = builder.block
        head = builder.append_basic_block("blocks.head")
        body = builder.append_basic_block("blocks.body")
        done = builder.append_basic_block("blocks.done")
        builder.branch(head)
        builder.position_at_end(head)
        col = builder.phi(i64)
        col_f = builder.phi(vd)
        col_i = builder.phi(vi)
        count = builder.phi(i64)
        col.add_incoming(col_from, entry)
        col_f.add_incoming(first_f, entry)
        col_i.add_incoming(first_i, entry)
        count.add_incoming(ir.Constant(i64, 0), entry)
        builder.cbranch(builder.icmp_signed("<=", col, col_to), body, done)

        builder.position_at_end(body)
        # The rasteriser's distance, operation for operation: a centre decides alike.
        dx = builder.fsub(
            builder.fadd(s["ox"], builder.fmul(builder.fadd(col_f, half), s["h"])), s["x0"]
        )
        d2 = builder.fadd(builder.fmul(dx, dx), dy2)
        in_row = builder.icmp_signed("<=", col_i, _splat(builder, col_to))
        # The square root is the block's slowest step on AVX2 (vsqrtpd), and only a
        # centre within a few ulps of a threshold's square needs it to decide alike.
        near = builder.or_(
            builder.and_(
                builder.fcmp_ordered(">", d2, f_band[0]), builder.fcmp_ordered("<", d2, f_band[1])
            ),
            builder.and_(
                builder.fcmp_ordered(">", d2, o_band[0]), builder.fcmp_ordered("<", d2, o_band[1])
            ),
        )
        near = builder.bitcast(builder.and_(near, in_row), bits)
        free_s = builder.fcmp_ordered("<", d2, f_band[1])
        occ_s = builder.fcmp_ordered("<", d2, o_band[1])
        sure = builder.block
        exact = builder.append_basic_block("blocks.exact")
        decide = builder.append_basic_block("blocks.decide")
        builder.cbranch(builder.icmp_unsigned("!=", near, ir.Constant(bits, 0)), exact, decide)
        builder.position_at_end(exact)
        d = builder.call(sqrt, [d2])
        free_x = builder.fcmp_ordered("<", d, s["f_thr"])
        occ_x = builder.fcmp_ordered("<=", d, s["o_thr"])
        builder.branch(decide)
        builder.position_at_end(decide)
        mask = ir.VectorType(ir.IntType(1), LANES)
        free = builder.phi(mask)
        free.add_incoming(free_s, sure)
        free.add_incoming(free_x, exact)
        occ = builder.phi(mask)
        occ.add_incoming(occ_s, sure)
        occ.add_incoming(occ_x, exact)
        update = builder.and_(in_row, builder.or_(free, occ))
        inc = builder.select(free, s["inc_free"], s["inc_occ"])
        if ncoef:
            along = builder.fadd(builder.fmul(dx, s["cos"], flags=fma), dy_s, flags=fma)
            across = builder.fsub(dy_c, builder.fmul(dx, s["sin"], flags=fma), flags=fma)
            q = builder.fdiv(across, along)
            u = builder.fmul(q, q)
            w = coefs[-1]
            for c in reversed(coefs[:-1]):
                w = builder.fadd(builder.fmul(w, u, flags=fma), c, flags=fma)
            inc = builder.fmul(inc, w)
        at = builder.add(base, col)
        vptr = builder.bitcast(builder.gep(varr.data, [at]), vd.as_pointer())
        tptr = builder.bitcast(builder.gep(tarr.data, [at]), vb.as_pointer())

        def clamp(v: Any) -> Any:
            v = builder.select(builder.fcmp_ordered(">", v, s["lo"]), v, s["lo"])
            return builder.select(builder.fcmp_ordered("<", v, s["hi"]), v, s["hi"])

        whole = builder.append_basic_block("blocks.whole")
        edge = builder.append_basic_block("blocks.edge")
        latch = builder.append_basic_block("blocks.latch")
        last = builder.add(col, ir.Constant(i64, LANES - 1))
        builder.cbranch(builder.icmp_signed("<=", last, col_end), whole, edge)

        # A block inside the grid's row is read and written whole, its lanes off the
        # span written back unchanged: the row is this thread's alone. Masked stores
        # are slow without AVX-512 (a byte-masked one becomes eight branches), and most
        # blocks of a beam's row lie inside the grid.
        builder.position_at_end(whole)
        old = builder.load(vptr, align=8)
        builder.store(builder.select(update, clamp(builder.fadd(old, inc)), old), vptr, align=8)
        flags = builder.load(tptr, align=1)
        builder.store(builder.or_(flags, builder.zext(update, vb)), tptr, align=1)
        builder.branch(latch)

        # A block passing the grid's edge: masked lanes are neither read nor written,
        # so nothing beyond the row (another thread's, or past the array) is touched.
        builder.position_at_end(edge)
        old = builder.call(
            _masked(builder, "load", vd, vptr, f"v{LANES}f64"),
            [vptr, ir.Constant(i32, 8), in_row, zero],
        )
        builder.call(
            _masked(builder, "store", vd, vptr, f"v{LANES}f64"),
            [clamp(builder.fadd(old, inc)), vptr, ir.Constant(i32, 8), update],
        )
        builder.call(
            _masked(builder, "store", vb, tptr, f"v{LANES}i8"),
            [ir.Constant(vb, [1] * LANES), tptr, ir.Constant(i32, 1), update],
        )
        builder.branch(latch)

        builder.position_at_end(latch)
        n = builder.zext(builder.call(ctpop, [builder.bitcast(update, bits)]), i64)
        col.add_incoming(builder.add(col, ir.Constant(i64, LANES)), latch)
        col_f.add_incoming(builder.fadd(col_f, _splat(builder, ir.Constant(f64, LANES))), latch)
        col_i.add_incoming(builder.add(col_i, _splat(builder, ir.Constant(i64, LANES))), latch)
        count.add_incoming(builder.add(count, n), latch)
        builder.branch(head)

        builder.position_at_end(done)
        return count

    return sig, codegen


# Typed as Any: numba's intrinsic wrapper takes the arguments after typingctx.
_update_blocks: Any = intrinsic(_blocks_intrinsic)


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
    ox, h, x0, dy, c, s, inc_free, inc_occ, lo, hi, f_thr, o_thr = params
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
) -> int:
    """Add ``inc_free`` to the Omega_free cells and ``inc_occ`` to the Omega_occ cells of
    each reading, in reading order, clamping to [lo, hi] after each addition; returns
    the number of cell updates.

    The cells are exactly those of :func:`rasterise_kernel`: the same rows and spans, and
    the same distance test, made LANES cells at a time (:func:`_update_blocks`).

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
    """
    n = sx.shape[0]
    total = 0
    scratch = np.empty((3, beam_planes.shape[0]))
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
        # The rasteriser's band limits with its slack; a no-echo reading has no band.
        f_thr = free_lim[i] - EDGE_TOL
        o_thr = occ_hi[i] + EDGE_TOL
        reach = min(max(free_lim[i], occ_hi[i]), beam_radius) + EDGE_TOL
        if reach <= EDGE_TOL:
            continue
        iy_lo, iy_hi = _row_range(beam_planes, c, s, x0, y0, reach, oy, h, rows, scratch)
        for iy in range(iy_lo, iy_hi + 1):
            if parts > 1 and (iy // stripe) % parts != part:
                continue
            yc = oy + (iy + 0.5) * h
            lo_x, hi_x = _span(beam_planes, c, s, x0, y0, yc, reach)
            if hi_x < lo_x:
                continue
            c_lo = max(0, math.ceil((lo_x - ox) / h - 0.5))
            c_hi = min(cols - 1, math.floor((hi_x - ox) / h - 0.5))
            if c_hi < c_lo:
                continue
            dy = yc - y0
            base = (rows - 1 - iy) * cols
            params = (ox, h, x0, dy, c, s, inc_f, inc_o, lo, hi, f_thr, o_thr)
            if sigma <= 0.0:
                total += _update_blocks(values, touched, base, c_lo, c_hi, cols - 1, params, ())
            elif len(coef) > 0 and abs(dy) > ROW_TOL:
                total += _update_blocks(values, touched, base, c_lo, c_hi, cols - 1, params, coef)
            else:
                total += _update_cells(values, touched, base, c_lo, c_hi, params, sigma)
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
        )
    return int(counts.sum())
