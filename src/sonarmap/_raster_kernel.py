"""The numba kernel behind :mod:`sonarmap.raster` (private)."""

from __future__ import annotations

import math

import numba as nb
import numpy as np
import numpy.typing as npt

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


@nb.njit(cache=True, inline="always")
def _side(ox: float, h: float, col: int, x0: float, dy2: float, lim: float) -> int:
    """Sign of ``sqrt(dx^2 + dy^2) - lim`` for the centre of column ``col``, exactly as
    the per-cell test computes the distance; the square root is taken only near ``lim``."""
    if lim < 0.0:
        return 1
    dx = ox + (col + 0.5) * h - x0
    q = dx * dx + dy2
    l2 = lim * lim
    if abs(q - l2) > 1e-9 * l2:
        return 1 if q > l2 else -1
    d = math.sqrt(q)
    return 1 if d > lim else (-1 if d < lim else 0)


@nb.njit(cache=True, inline="always")
def _bump(
    values: npt.NDArray[np.float64],
    touched: npt.NDArray[np.bool_],
    a: int,
    b: int,
    inc: float,
    lo: float,
    hi: float,
) -> None:
    # A local view and a slice fill compile to tighter loops than indexing the grid.
    seg = values[a : b + 1]
    for k in range(seg.shape[0]):
        v = seg[k] + inc
        v = v if v > lo else lo
        seg[k] = v if v < hi else hi
    touched[a : b + 1] = True


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
    part: int = 0,
    parts: int = 1,
    stripe: int = 8,
) -> int:
    """Add ``inc_free`` to the Omega_free cells and ``inc_occ`` to the Omega_occ cells of
    each reading, in reading order, clamping to [lo, hi] after each addition; returns
    the number of cell updates.

    The cells are exactly those of :func:`rasterise_kernel` (the same spans and tests),
    visited as runs: along a row, distance to the sensor is convex, so the free cells
    (d below a limit) form one run and the occupied cells the rest of the beam's span.
    Only the run ends are tested cell by cell.

    With ``parts > 1`` only the rows of stripes ``part``, ``part + parts``, ... (stripes
    of ``stripe`` rows) are updated: parts can run in parallel, and each cell still sees
    the readings in order.
    """
    n = sx.shape[0]
    total = 0
    scratch = np.empty((3, beam_planes.shape[0]))
    inv_h = 1.0 / h
    for i in range(n):
        x0 = sx[i]
        y0 = sy[i]
        c = math.cos(st[i])
        s = math.sin(st[i])
        a_lim = free_lim[i] - EDGE_TOL
        b_lim = occ_hi[i] + EDGE_TOL
        reach = min(max(free_lim[i], occ_hi[i]), beam_radius) + EDGE_TOL
        if reach <= EDGE_TOL:
            continue
        # A no-echo reading has no band: only its free cells are updated.
        band = b_lim >= a_lim
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
            dy2 = dy * dy
            if band:
                # The span reaches b_lim plus rounding slack; a cell in that slack is
                # outside the band, and only the span's end cells can be.
                while c_lo <= c_hi and _side(ox, h, c_lo, x0, dy2, b_lim) > 0:
                    c_lo += 1
                while c_hi >= c_lo and _side(ox, h, c_hi, x0, dy2, b_lim) > 0:
                    c_hi -= 1
                if c_hi < c_lo:
                    continue
            # The free run from the chord of the circle d = a_lim; a run end is checked
            # cell by cell only when a centre lies within rounding of the circle.
            fl = c_hi + 1
            fh = c_hi
            if a_lim > 0.0 and a_lim * a_lim > dy2:
                half = math.sqrt(a_lim * a_lim - dy2)
                u = (x0 - half - ox) * inv_h - 0.5
                v = (x0 + half - ox) * inv_h - 0.5
                fl = math.ceil(u)
                fh = math.floor(v)
                if abs(u - math.floor(u + 0.5)) < 1e-6:
                    while _side(ox, h, fl - 1, x0, dy2, a_lim) < 0:
                        fl -= 1
                    while fl <= fh and _side(ox, h, fl, x0, dy2, a_lim) >= 0:
                        fl += 1
                if abs(v - math.floor(v + 0.5)) < 1e-6:
                    while _side(ox, h, fh + 1, x0, dy2, a_lim) < 0:
                        fh += 1
                    while fh >= fl and _side(ox, h, fh, x0, dy2, a_lim) >= 0:
                        fh -= 1
                fl = max(fl, c_lo)
                fh = min(fh, c_hi)
                if fh < fl:
                    fl = c_hi + 1
                    fh = c_hi
            _bump(values, touched, base + fl, base + fh, inc_free, lo, hi)
            total += fh - fl + 1
            if band:
                _bump(values, touched, base + c_lo, base + fl - 1, inc_occ, lo, hi)
                _bump(values, touched, base + fh + 1, base + c_hi, inc_occ, lo, hi)
                total += (fl - c_lo) + (c_hi - fh)
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
    parts: int,
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
            p,
            parts,
            8,
        )
    return int(counts.sum())
