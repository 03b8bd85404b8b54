"""The lossy form a pose may travel in (issue 15's bandwidth goal): coarser descriptors,
half-precision landmark geometry and ternary local maps.

The records keep their fields and dtypes, so a quantised pose encodes and decodes
exactly as any other (:func:`.records.encode`); what shrinks is the deflated message,
because the quantised values carry fewer distinct bytes: 3-bit descriptors kept in
uint8 deflate to about 3/8 of the exact ones, float32 points exact in float16 have zero
low mantissa bytes, and a ternary map is a known mask and a sign.

Every function is idempotent: a quantised pose quantised again is unchanged, so a relay
never quantises twice and every holder of a pose holds the values its source sent, but
for the landmark stamps, which the thesis lets every holder raise.

What each setting saves, and what it costs the central map, is measured by
``python -m benchmarks.team_quantise`` (docs/results/2026-12-03-team-code-notes.md).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..errors import ConfigError
from .records import Landmarks, LocalMap, Pose

__all__ = ["check_quantisation", "quantise_descriptors", "quantise_pose", "ternary_logodds"]

#: Magnitudes float16 holds with room to round.
_HALF_MAX = 60000.0


def check_quantisation(descriptor_bits: int, ternary_maps: bool) -> None:
    """Check the quantisation settings.

    Parameters
    ----------
    descriptor_bits : int
        Must be an integer in 1..8.
    ternary_maps : bool
        Must be a bool.

    Raises
    ------
    ConfigError
        Naming the setting that is not.
    """
    v = descriptor_bits
    if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 8:
        raise ConfigError(
            f"exchange: descriptor_bits must be an integer in 1..8, got {v!r}",
            field="descriptor_bits",
        )
    if not isinstance(ternary_maps, bool):
        raise ConfigError(
            f"exchange: ternary_maps must be true or false, got {ternary_maps!r}",
            field="ternary_maps",
        )


def quantise_descriptors(desc: npt.NDArray[np.uint8], bits: int) -> npt.NDArray[np.uint8]:
    """Each byte kept to its ``bits`` high bits, the dropped ones set to the middle of
    the range they span (so the error is at most half a step, centred on zero).

    Parameters
    ----------
    desc : ndarray of uint8
    bits : int
        1..8; 8 returns ``desc`` unchanged.

    Returns
    -------
    ndarray of uint8, the shape of ``desc``.
    """
    if bits >= 8:
        return desc
    drop = 8 - bits
    high = (desc >> drop) << drop
    return np.asarray(high | (1 << (drop - 1)), dtype=np.uint8)


def ternary_logodds(logodds: npt.NDArray[np.int8]) -> npt.NDArray[np.int8]:
    """A local map reduced to free, occupied and unknown: every free cell (negative
    log-odds) carries the mean of the map's free values, every occupied cell the mean of
    its occupied values (rounded, at least 1 unit), unknown cells stay 0.

    Which cells are known and their class are exact, and so is the map's total evidence
    of each class up to rounding; what is lost is how it is spread over the cells.

    Parameters
    ----------
    logodds : ndarray of int8

    Returns
    -------
    ndarray of int8, the shape of ``logodds``.
    """
    lo = logodds.astype(np.int16)
    out = np.zeros_like(lo)
    for side in (lo < 0, lo > 0):
        if side.any():
            mag = max(1, int(np.rint(np.abs(lo[side]).mean())))
            out[side] = np.sign(lo[side]) * mag
    return np.asarray(out, dtype=np.int8)


def quantise_pose(pose: Pose, descriptor_bits: int, ternary_maps: bool) -> Pose:
    """The pose as it travels quantised.

    With ``descriptor_bits < 8`` its landmarks get descriptors of that many bits
    (:func:`quantise_descriptors`), points and reliabilities rounded to float16 (under
    8 mm at 16 m from the pose) and stamps to float32 (under 1 ms in the first 9 hours
    of a mission, 4 ms after a day).
    With ``ternary_maps`` its local map goes through :func:`ternary_logodds`.
    UID, time, region, estimate, landmark identities and merge history are exact.

    Parameters
    ----------
    pose : Pose
    descriptor_bits : int
        1..8; 8 leaves the landmarks exact.
    ternary_maps : bool

    Returns
    -------
    Pose
        A new pose, or ``pose`` itself when there is nothing to quantise.
    """
    lm = pose.landmarks
    landmarks = lm
    if descriptor_bits < 8 and len(lm):
        # A point beyond float16's range (none a stereo pair sees) keeps float32.
        half = bool(np.abs(lm.points).max() < _HALF_MAX)
        landmarks = Landmarks(
            lm.points.astype(np.float16).astype(np.float32) if half else lm.points,
            quantise_descriptors(lm.descriptors, descriptor_bits),
            lm.reliability.astype(np.float16).astype(np.float32),
            lm.stamp.astype(np.float32).astype(np.float64),
            lm.ids,
        )
    local = pose.local_map
    if ternary_maps and local is not None:
        local = LocalMap(ternary_logodds(local.logodds), local.resolution)
    if landmarks is lm and local is pose.local_map:
        return pose
    return Pose(pose.uid, pose.time, pose.region, pose.estimate, landmarks, local, pose.merged_from)
