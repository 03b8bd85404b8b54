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
            iy_lo = max(0, math.ceil((y0 - reach - oy) / h - 0.5))
            iy_hi = min(rows - 1, math.floor((y0 + reach - oy) / h - 0.5))
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
