"""Data association between a robot's new pose and its stored poses (thesis 002,
l.1525-1648): descriptor voting, odometry bounds, then RANSAC per candidate.

The three stages, cheapest first:

1. **Voting.** One k-d tree (:class:`scipy.spatial.cKDTree`) holds the descriptors of
   every stored pose's landmarks. Each landmark of the new pose looks up its
   ``n_neighbours`` nearest descriptors within ``d_vote``; each neighbour votes for its
   pose, one vote per new landmark and pose. Poses with ``min_votes`` votes stay. The
   thesis uses FLANN's randomized trees; an exact tree gives the same votes, only slower
   on very large stores.
2. **Odometry bounds.** A :class:`Prior` per candidate (optional) says where odometry
   puts the new pose in the candidate's frame and how far the truth can be from there.
   Candidates that cannot share a landmark under the bound are skipped; a RANSAC
   transform outside the bound is rejected.
3. **RANSAC.** Putative matches are each new landmark's ``m_max`` nearest candidate
   descriptors within ``d_threshold``. A draw takes 3 matches with no landmark in common,
   fits a planar rigid transform (rotation about z, translation in x, y), counts one-to-one
   inliers (3-D error <= ``e0``) and, above ``t_inl`` inliers, refits on them until the
   count stops growing. The best draw (most inliers, then least error E) is the closure if
   it has ``n_min`` inliers; the draws with ``n_min`` inliers give its covariance.
4. **Refit and checks.** The closure's inliers are refitted by Gauss-Newton with each
   landmark's stereo covariance (:func:`stereo_covariance`: depth error grows with the
   square of the distance), which gives the transform and the covariance of the fit.
   A transform outside the odometry bound, or less certain than ``max_sigma_xy`` /
   ``max_sigma_theta``, is refused. Equal weights let a few far landmarks, whose depth
   is off by decimetres, turn a closure by degrees: on random buildings such closures
   were the only wrong ones, 0.3-0.9 m off with the right landmarks matched.

Descriptor distances are Euclidean on the uint8 values, with descriptors scaled like
SIFT's (unit vector x 512, clipped to 255): unrelated descriptors are then about 450-550
apart and two views of one landmark well under 200, hence the defaults of 250 for
``d_vote`` and ``d_threshold`` (the thesis gives no values).

The transform of a closure is that of the new pose (b) in the candidate's frame (a), as
:mod:`sonarmap.team.records` defines: ``p_a = R(theta) p_b + (x, y)``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from sonarmap.errors import ConfigError, InputError
from sonarmap.team.records import ClosureEdge, Pose

__all__ = [
    "AssociationParams",
    "AssociationStats",
    "DescriptorIndex",
    "Prior",
    "associate",
    "estimate_planar",
    "stereo_covariance",
]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

#: Smallest pair weight r_i r_j: a pair of landmarks with reliability 0 still counts a
#: little, so a weighted fit on them stays defined.
_W_MIN = 1e-3
#: Refits per draw at most; the inlier count grows strictly, so this only guards time.
_MAX_REFITS = 20


@dataclass(frozen=True)
class AssociationParams:
    """Parameters of :func:`associate`; the thesis names them but gives no values, so
    every default below is our choice.

    Parameters
    ----------
    n_neighbours : int
        Nearest stored descriptors each new landmark looks up when voting (8).
    d_vote : float
        Largest descriptor distance of a vote (250, Euclidean on uint8 values).
    min_votes : int
        Votes a stored pose needs to stay a candidate (6; below ``n_min`` so voting does
        not reject what RANSAC could accept).
    m_max : int
        Candidate landmarks each new landmark is matched to at most (3).
    d_threshold : float
        Largest descriptor distance of a putative match (250).
    e0 : float
        Largest 3-D error (m) of an inlier pair (0.15: three sigma of the difference of
        two stereo points with 2 cm noise per axis).
    t_inl : int
        Above this many inliers a draw refits on its inliers (5).
    n_min : int
        Inliers a closure needs (8).
    iterations : int
        RANSAC draws per candidate at most (200).
    min_iterations : int
        Draws made before an early exit is allowed (20), so the covariance has samples.
    early_exit_share : float
        Stop drawing once the best draw's inliers are this share of the new landmarks
        that have a putative match (0.8).
    camera_range : float
        Farthest (m) a landmark is seen. Two poses farther than twice this apart cannot
        share a landmark (8.0).
    min_sigma_xy : float
        Standard deviation (m) added to x and y of every closure covariance (0.01), so it
        is positive definite even when all draws agree.
    min_sigma_theta : float
        Standard deviation (rad) added to theta likewise (0.002).
    focal, baseline, sigma_pixel : float
        The stereo camera as the robot knows it from calibration: focal length (500
        px), baseline (0.12 m) and the pixel noise assumed (0.5 px; the simulator draws
        0.3, so the model is conservative, not the truth). They give every landmark's
        covariance (depth error grows with the square of the distance), which weighs the
        final refit of a closure and gives its covariance.
    sigma_point : float
        Standard deviation (m) added to x and y of every landmark's stereo covariance
        (0.02, as in ``e0``): a keypoint is not exactly the same surface point in two
        views, and near points would otherwise be trusted to a millimetre sideways.
    max_sigma_xy : float
        A closure whose refitted position (of the new pose in the candidate's frame) has
        a standard deviation above this along its worst direction is refused (inf: none).
    max_sigma_theta : float
        Likewise for the heading, rad (inf: none).
    inlier_sigmas : float
        N > 0 (default 3): an inlier pair is within ``e0`` in 3-D, or its horizontal
        error is within N standard deviations of the two landmarks' stereo covariances
        (:func:`stereo_covariance` plus ``sigma_point``) and its heights differ by at
        most ``e0``, so that far landmarks seen again from elsewhere count (a revisit
        sees a place from farther or askew, where the stereo depth error exceeds
        ``e0``). 0: within ``e0`` only.
    seed : int
        Seed of the draws (0). Each candidate draws from its own stream, seeded by
        ``(seed, candidate uid, new uid)``, so a result does not depend on the other
        stored poses.
    """

    n_neighbours: int = 8
    d_vote: float = 250.0
    min_votes: int = 6
    m_max: int = 3
    d_threshold: float = 250.0
    e0: float = 0.15
    t_inl: int = 5
    n_min: int = 8
    iterations: int = 200
    min_iterations: int = 20
    early_exit_share: float = 0.8
    camera_range: float = 8.0
    min_sigma_xy: float = 0.01
    min_sigma_theta: float = 0.002
    focal: float = 500.0
    baseline: float = 0.12
    sigma_pixel: float = 0.5
    sigma_point: float = 0.02
    max_sigma_xy: float = math.inf
    max_sigma_theta: float = math.inf
    inlier_sigmas: float = 3.0
    seed: int = 0

    def __post_init__(self) -> None:
        counts = {
            "n_neighbours": (self.n_neighbours, 1),
            "min_votes": (self.min_votes, 1),
            "m_max": (self.m_max, 1),
            "t_inl": (self.t_inl, 3),
            "n_min": (self.n_min, 3),
            "iterations": (self.iterations, 1),
            "min_iterations": (self.min_iterations, 1),
            "seed": (self.seed, 0),
        }
        for name, (value, low) in counts.items():
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ConfigError(f"AssociationParams.{name}: an integer >= {low}, got {value!r}")
        for name in (
            "d_vote",
            "d_threshold",
            "e0",
            "camera_range",
            "min_sigma_xy",
            "min_sigma_theta",
            "focal",
            "baseline",
            "sigma_pixel",
            "sigma_point",
        ):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ConfigError(f"AssociationParams.{name}: a finite number > 0, got {value!r}")
        sig = self.inlier_sigmas
        if not (isinstance(sig, int | float) and math.isfinite(sig) and sig >= 0):
            raise ConfigError(f"AssociationParams.inlier_sigmas: a finite number >= 0, got {sig!r}")
        for name in ("max_sigma_xy", "max_sigma_theta"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and value > 0):
                raise ConfigError(f"AssociationParams.{name}: a number > 0 or inf, got {value!r}")
        share = self.early_exit_share
        if not (isinstance(share, int | float) and 0 < share <= 1):
            raise ConfigError(f"AssociationParams.early_exit_share: in (0, 1], got {share!r}")


@dataclass(frozen=True)
class Prior:
    """What odometry says about the new pose in one candidate's frame.

    Attributes
    ----------
    transform : tuple of float
        Predicted ``(x, y, theta)`` of the new pose in the candidate's frame.
    max_distance : float
        Hard bound (m): the true position is at most this far from the predicted one.
        With ``transform=(0, 0, 0)`` it bounds the distance between the two poses, as
        :class:`~sonarmap.team.records.OdometryEdge` does (top speed x elapsed time).
    max_turn : float
        Hard bound (rad) on the heading's difference from the predicted one (pi: none).
    """

    transform: tuple[float, float, float]
    max_distance: float
    max_turn: float = math.pi


@dataclass
class AssociationStats:
    """What each stage of :func:`associate` kept: poses, and landmark matches.

    Matches are counted as each stage sees them: for voting and bounds, the
    (new landmark, stored landmark) neighbour pairs within ``d_vote``; for RANSAC, the
    putative matches (``m_max``, ``d_threshold``) and then the inliers.

    Attributes
    ----------
    candidates : int
        Stored poses offered (the new pose itself excluded).
    after_votes, after_bounds, after_ransac, accepted : int
        Poses kept by voting, by the odometry pre-check, by RANSAC (``n_min`` inliers)
        and by the checks of the refitted transform (odometry bound and certainty: the
        closures).
    vote_matches, vote_matches_kept, vote_matches_after_bounds : int
        Neighbour pairs of all candidates, of those kept by voting, of those kept by the
        pre-check.
    putative_matches : int
        RANSAC's putative matches over the poses it ran on.
    ransac_matches : int
        Inliers of the poses RANSAC accepted.
    inlier_matches : int
        Inliers of the closures.
    kept : dict of str to tuple of int
        The UIDs each stage kept (``"votes"``, ``"bounds"``, ``"ransac"``,
        ``"accepted"``), so a caller that knows the truth can say whom a stage removed.
    """

    candidates: int = 0
    after_votes: int = 0
    after_bounds: int = 0
    after_ransac: int = 0
    accepted: int = 0
    vote_matches: int = 0
    vote_matches_kept: int = 0
    vote_matches_after_bounds: int = 0
    putative_matches: int = 0
    ransac_matches: int = 0
    inlier_matches: int = 0
    kept: dict[str, tuple[int, ...]] = field(default_factory=dict)

    def removed(self) -> dict[str, tuple[int, int]]:
        """Per stage, ``(poses removed, matches removed)``.

        The ``"ransac"`` stage's matches are the putative matches that were not inliers
        of an accepted pose.
        """
        return {
            "votes": (
                self.candidates - self.after_votes,
                self.vote_matches - self.vote_matches_kept,
            ),
            "bounds": (
                self.after_votes - self.after_bounds,
                self.vote_matches_kept - self.vote_matches_after_bounds,
            ),
            "ransac": (
                self.after_bounds - self.after_ransac,
                self.putative_matches - self.ransac_matches,
            ),
            "bounds_check": (
                self.after_ransac - self.accepted,
                self.ransac_matches - self.inlier_matches,
            ),
        }


# --- the planar transform ------------------------------------------------------------


def _fit(a: F64, b: F64, w: F64) -> F64:
    # Weighted 2-D Kabsch in closed form: the rotation maximising sum w (a' . R b')
    # over centred points is atan2 of the weighted cross and dot sums.
    sw = w.sum()
    ca = (w @ a[:, :2]) / sw
    cb = (w @ b[:, :2]) / sw
    A = a[:, :2] - ca
    B = b[:, :2] - cb
    dot = float(w @ (A[:, 0] * B[:, 0] + A[:, 1] * B[:, 1]))
    cross = float(w @ (B[:, 0] * A[:, 1] - B[:, 1] * A[:, 0]))
    theta = math.atan2(cross, dot)
    c, s = math.cos(theta), math.sin(theta)
    tx = ca[0] - (c * cb[0] - s * cb[1])
    ty = ca[1] - (s * cb[0] + c * cb[1])
    return np.array([tx, ty, theta])


def _apply(T: F64, b: F64) -> F64:
    """Points b (n, 3) moved by the planar transform T; z unchanged."""
    c, s = math.cos(T[2]), math.sin(T[2])
    out = b.copy()
    out[:, 0] = c * b[:, 0] - s * b[:, 1] + T[0]
    out[:, 1] = s * b[:, 0] + c * b[:, 1] + T[1]
    return out


def estimate_planar(a: npt.ArrayLike, b: npt.ArrayLike, w: npt.ArrayLike | None = None) -> F64:
    """The planar rigid transform that maps points ``b`` onto points ``a``.

    Weighted least squares on x and y (a robot on the floor turns only about z); z is
    ignored, callers check it agrees.

    Parameters
    ----------
    a, b : array_like (n, 2) or (n, 3)
        Corresponding points, metres; n >= 2.
    w : array_like (n,), optional
        Non-negative weights, not all zero; equal by default.

    Returns
    -------
    ndarray (3,)
        ``(x, y, theta)`` with ``a ~ R(theta) b + (x, y)``.

    Examples
    --------
    >>> b = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0]])
    >>> a = b @ np.array([[0.0, 1.0], [-1.0, 0.0]]) + [3.0, 4.0]
    >>> np.round(estimate_planar(a, b), 6).tolist()
    [3.0, 4.0, 1.570796]
    """
    A = np.asarray(a, dtype=np.float64)
    B = np.asarray(b, dtype=np.float64)
    if A.ndim != 2 or A.shape[1] not in (2, 3) or A.shape != B.shape:
        raise InputError(
            f"estimate_planar: a and b must be equal (n, 2) or (n, 3) arrays, "
            f"got {A.shape} and {B.shape}"
        )
    if len(A) < 2:
        raise InputError(f"estimate_planar: at least 2 point pairs needed, got {len(A)}")
    if not (np.isfinite(A).all() and np.isfinite(B).all()):
        raise InputError("estimate_planar: points must be finite")
    W = np.ones(len(A)) if w is None else np.asarray(w, dtype=np.float64)
    if W.shape != (len(A),) or not np.isfinite(W).all() or (W < 0).any() or W.sum() <= 0:
        raise InputError(f"estimate_planar: w must be {len(A)} finite weights >= 0, not all zero")
    return _fit(A, B, W)


def stereo_covariance(points: npt.ArrayLike, focal: float, baseline: float, sigma: float) -> F64:
    """Covariances of the horizontal coordinates of stereo points, in their pose's frame.

    Points triangulated as in :func:`sonarmap.team.world.observe` (``X = f B / d``,
    ``Y = -X u_l / f``) from pixel coordinates ``u_l``, ``u_r`` of noise ``sigma`` each;
    first-order propagation through the triangulation.

    Parameters
    ----------
    points : array_like (n, 2) or (n, 3)
        X forward, Y left, metres, in the frame of the left camera (the robot's origin).
    focal, baseline, sigma : float
        Focal length (px), baseline (m), pixel noise (px).

    Returns
    -------
    ndarray (n, 2, 2)
        Covariance of (X, Y) per point.

    Examples
    --------
    >>> c = stereo_covariance([[2.0, 0.0]], 500.0, 0.12, 0.3)
    >>> round(float(np.sqrt(c[0, 0, 0])), 4)  # depth sigma at 2 m: 2.8 cm
    0.0283
    """
    p = np.asarray(points, dtype=np.float64)
    X = np.maximum(p[:, 0], 1e-3)
    Y = p[:, 1]
    fb = focal * baseline
    # Rows d(X, Y), columns d(u_l, u_r); with u_l / f = -Y / X.
    J = np.empty((len(p), 2, 2))
    J[:, 0, 0] = -X * X / fb
    J[:, 0, 1] = X * X / fb
    J[:, 1, 0] = -X * Y / fb - X / focal
    J[:, 1, 1] = X * Y / fb
    return np.asarray(sigma**2 * J @ J.transpose(0, 2, 1), dtype=np.float64)


def _point_covariance(points: F64, params: AssociationParams) -> F64:
    cov = stereo_covariance(points, params.focal, params.baseline, params.sigma_pixel)
    return np.asarray(cov + params.sigma_point**2 * np.eye(2), dtype=np.float64)


#: Gauss-Newton steps of the final refit; it starts at RANSAC's answer, so few suffice.
_REFINE_STEPS = 5


def _refine(a: F64, b: F64, ca: F64, cb: F64, w: F64, T: F64) -> tuple[F64, F64]:
    """Refit T on inlier pairs weighted by their stereo covariances (and reliabilities),
    and the covariance of (x, y, theta) as written.

    The covariance is the inverse information of the weighted fit, scaled up by the
    residuals' chi-square per degree of freedom when that exceeds 1: the model's noise
    is a floor, and disagreement it does not explain widens the result.
    """
    T = T.astype(np.float64).copy()
    rel = w / w.mean()
    H = np.eye(3)
    chi2 = 0.0
    for _ in range(_REFINE_STEPS):
        c, s = math.cos(T[2]), math.sin(T[2])
        R = np.array([[c, -s], [s, c]])
        S = ca + R @ cb @ R.T
        W = np.linalg.inv(S) * rel[:, None, None]
        r = a[:, :2] - (b[:, :2] @ R.T + T[:2])
        J = np.zeros((len(a), 2, 3))
        J[:, 0, 0] = 1.0
        J[:, 1, 1] = 1.0
        J[:, 0, 2] = -s * b[:, 0] - c * b[:, 1]
        J[:, 1, 2] = c * b[:, 0] - s * b[:, 1]
        JtW = J.transpose(0, 2, 1) @ W
        H = (JtW @ J).sum(axis=0)
        g = (JtW @ r[:, :, None]).sum(axis=0)[:, 0]
        chi2 = float(np.einsum("ni,nij,nj->", r, W, r))
        step = np.linalg.solve(H, g)
        T += step
        if np.abs(step).max() < 1e-9:
            break
    dof = max(2 * len(a) - 3, 1)
    cov = np.linalg.inv(H) * max(1.0, chi2 / dof)
    return T, np.asarray(0.5 * (cov + cov.T), dtype=np.float64)


# --- the descriptor index (voting) ---------------------------------------------------


class DescriptorIndex:
    """One k-d tree over the descriptors of all landmarks of some poses, for voting.

    Build it once for a store and pass it to :func:`associate` while the store does not
    change; :func:`associate` builds one itself when none is given.

    Parameters
    ----------
    poses : sequence of Pose
        Distinct UIDs; all descriptors of one length.
    """

    def __init__(self, poses: Sequence[Pose]) -> None:
        self.uids: tuple[int, ...] = tuple(p.uid for p in poses)
        if len(set(self.uids)) != len(self.uids):
            raise InputError("DescriptorIndex: stored poses have duplicate UIDs")
        dims = {p.landmarks.descriptors.shape[1] for p in poses if len(p.landmarks)}
        if len(dims) > 1:
            raise InputError(f"DescriptorIndex: descriptors of lengths {sorted(dims)} mixed")
        self.dim: int | None = dims.pop() if dims else None
        counts = np.array([len(p.landmarks) for p in poses], dtype=np.int64)
        self.owner: I64 = np.repeat(np.arange(len(poses), dtype=np.int64), counts)
        if self.dim is None:
            self._tree: cKDTree | None = None
            return
        desc = np.concatenate([p.landmarks.descriptors for p in poses if len(p.landmarks)]).astype(
            np.float32
        )
        self._tree = cKDTree(desc)

    def votes(
        self, descriptors: npt.NDArray[np.uint8], *, n_neighbours: int = 8, d_vote: float = 250.0
    ) -> tuple[I64, I64]:
        """Votes and neighbour pairs per indexed pose.

        Parameters
        ----------
        descriptors : ndarray (m, d) uint8
            The new pose's descriptors.
        n_neighbours : int
            Neighbours looked up per descriptor (8).
        d_vote : float
            Largest descriptor distance of a neighbour (250).

        Returns
        -------
        votes, pairs : ndarray (len(uids),) int64
            Per pose, the new landmarks with at least one neighbour in it, and the
            neighbour pairs in it.
        """
        n_poses = len(self.uids)
        none = np.zeros(n_poses, dtype=np.int64)
        if self._tree is None or len(descriptors) == 0:
            return none, none.copy()
        if descriptors.shape[1] != self.dim:
            raise InputError(
                f"DescriptorIndex.votes: descriptors of length {descriptors.shape[1]}, "
                f"the index holds length {self.dim}"
            )
        k = min(n_neighbours, self._tree.n)
        _, idx = self._tree.query(
            descriptors.astype(np.float32),
            k=k,
            distance_upper_bound=np.nextafter(d_vote, np.inf),
        )
        idx = np.asarray(idx).reshape(len(descriptors), k)
        rows, cols = np.nonzero(idx < self._tree.n)
        owners = self.owner[idx[rows, cols]]
        pairs = np.bincount(owners, minlength=n_poses).astype(np.int64)
        # One vote per (new landmark, pose): a landmark whose neighbours all sit in one
        # pose must not outvote landmarks spread over the store.
        voters = np.unique(rows.astype(np.int64) * n_poses + owners)
        votes = np.bincount(voters % n_poses, minlength=n_poses).astype(np.int64)
        return votes, pairs


# --- RANSAC --------------------------------------------------------------------------


@dataclass
class _Draw:
    transform: F64
    inliers: I64  # indices into the putative matches
    error: float


@dataclass
class _Matches:
    """Putative matches of one candidate: index pairs and the matched points."""

    old: I64
    new: I64
    a: F64  # candidate's points
    b: F64  # new pose's points
    w: F64  # r_i r_j
    n_new: int = field(default=0)  # distinct new landmarks with a match
    #: Stereo covariances (n, 2, 2) of a's and b's points (``inlier_sigmas`` > 0 only).
    ca: F64 | None = None
    cb: F64 | None = None
    sigmas: float = 0.0


def _putative(cand: Pose, new: Pose, params: AssociationParams) -> _Matches:
    lo, ln = cand.landmarks, new.landmarks
    empty = np.zeros(0, dtype=np.int64)
    if len(lo) == 0 or len(ln) == 0:
        z = np.zeros((0, 3))
        return _Matches(empty, empty, z, z, np.zeros(0))
    tree = cKDTree(lo.descriptors.astype(np.float32))
    k = min(params.m_max, len(lo))
    _, idx = tree.query(
        ln.descriptors.astype(np.float32),
        k=k,
        distance_upper_bound=np.nextafter(params.d_threshold, np.inf),
    )
    idx = np.asarray(idx).reshape(len(ln), k)
    rows, cols = np.nonzero(idx < len(lo))
    old = idx[rows, cols].astype(np.int64)
    new_i = rows.astype(np.int64)
    w = np.maximum(
        lo.reliability[old].astype(np.float64) * ln.reliability[new_i].astype(np.float64), _W_MIN
    )
    a = lo.points[old].astype(np.float64)
    b = ln.points[new_i].astype(np.float64)
    m = _Matches(old, new_i, a, b, w, len(np.unique(new_i)))
    if params.inlier_sigmas > 0:
        m.ca, m.cb = _point_covariance(a, params), _point_covariance(b, params)
        m.sigmas = params.inlier_sigmas
    return m


def _inliers(m: _Matches, T: F64, e0: float) -> tuple[I64, F64]:
    """One-to-one inliers of T (best error first) and their errors."""
    diff = m.a - _apply(T, m.b)
    err = np.linalg.norm(diff, axis=1)
    ok = err <= e0
    if m.ca is not None and m.cb is not None:
        # Far landmarks' depth is known to decimetres: within the sigmas of the two
        # stereo covariances (b's turned into a's frame) counts too, heights within e0.
        c, s = math.cos(T[2]), math.sin(T[2])
        R = np.array([[c, -s], [s, c]])
        S = m.ca + R @ m.cb @ R.T
        d2 = np.einsum("ni,nij,nj->n", diff[:, :2], np.linalg.inv(S), diff[:, :2])
        ok |= (d2 <= m.sigmas**2) & (np.abs(diff[:, 2]) <= e0)
    cand = np.flatnonzero(ok)
    cand = cand[np.argsort(err[cand], kind="stable")]
    # Keep the best match of each old landmark, then of each new one: every landmark is
    # then used once, as the count of inliers assumes.
    _, first = np.unique(m.old[cand], return_index=True)
    cand = cand[np.sort(first)]
    _, first = np.unique(m.new[cand], return_index=True)
    cand = cand[np.sort(first)].astype(np.int64)
    return cand, err[cand]


def _sample(m: _Matches, rng: np.random.Generator, e0: float) -> I64 | None:
    """Three matches with no landmark in common whose pairwise distances agree."""
    s = rng.choice(len(m.old), size=3, replace=False)
    if len(np.unique(m.old[s])) < 3 or len(np.unique(m.new[s])) < 3:
        return None
    da = np.linalg.norm(m.a[s] - m.a[np.roll(s, 1)], axis=1)
    db = np.linalg.norm(m.b[s] - m.b[np.roll(s, 1)], axis=1)
    # A rigid motion keeps distances: most wrong triples fail here before any fit, and a
    # triple of nearly coincident points would leave the rotation undetermined.
    if np.abs(da - db).max() > 2 * e0 or db.max() < 2 * e0:
        return None
    return s.astype(np.int64)


def _draw(m: _Matches, s: I64, params: AssociationParams) -> _Draw | None:
    T = _fit(m.a[s], m.b[s], m.w[s])
    if np.linalg.norm(m.a[s] - _apply(T, m.b[s]), axis=1).max() > params.e0:
        return None
    inl, err = _inliers(m, T, params.e0)
    for _ in range(_MAX_REFITS):
        if len(inl) <= params.t_inl:
            break
        T2 = _fit(m.a[inl], m.b[inl], m.w[inl])
        inl2, err2 = _inliers(m, T2, params.e0)
        if len(inl2) < len(inl):
            break
        grew = len(inl2) > len(inl)
        T, inl, err = T2, inl2, err2
        if not grew:
            break
    error = float(m.w[inl] @ err**2) / max(len(inl), 1)
    return _Draw(T, inl, error)


def _ransac(
    m: _Matches, params: AssociationParams, rng: np.random.Generator
) -> tuple[_Draw | None, list[_Draw]]:
    """The best draw and every draw with ``n_min`` inliers."""
    best: _Draw | None = None
    good: list[_Draw] = []
    if len(m.old) < 3:
        return None, good
    for it in range(params.iterations):
        s = _sample(m, rng, params.e0)
        d = None if s is None else _draw(m, s, params)
        if d is None:
            continue
        if len(d.inliers) >= params.n_min:
            good.append(d)
        if best is None or (len(d.inliers), -d.error) > (len(best.inliers), -best.error):
            best = d
        if (
            it + 1 >= params.min_iterations
            and len(best.inliers) >= params.early_exit_share * m.n_new
        ):
            break
    return best, good


def _certain(cov: F64, params: AssociationParams) -> bool:
    """True when the fit's covariance is within the closure's limits."""
    worst_xy = float(np.linalg.eigvalsh(cov[:2, :2])[-1])
    return worst_xy <= params.max_sigma_xy**2 and cov[2, 2] <= params.max_sigma_theta**2


def _covariance(best: _Draw, good: list[_Draw], fit: F64, params: AssociationParams) -> F64:
    """Spread of the good draws about the best (weights 1/E), plus the refit's
    covariance ``fit``, plus the floor."""
    T = np.array([d.transform for d in good])
    w = 1.0 / np.maximum([d.error for d in good], 1e-12)
    w /= w.sum()
    dev = T - best.transform
    dev[:, 2] = np.remainder(dev[:, 2] + math.pi, 2 * math.pi) - math.pi
    spread = (dev * w[:, None]).T @ dev
    floor = np.diag([params.min_sigma_xy**2, params.min_sigma_xy**2, params.min_sigma_theta**2])
    cov = spread + fit + floor
    return np.asarray(0.5 * (cov + cov.T), dtype=np.float64)


# --- bounds --------------------------------------------------------------------------


def _check_prior(uid: int, prior: Prior) -> None:
    tf = prior.transform
    if len(tf) != 3 or not all(math.isfinite(float(v)) for v in tf):
        raise InputError(f"prior of pose {uid}: transform must be 3 finite numbers, got {tf!r}")
    if not (math.isfinite(prior.max_distance) and prior.max_distance >= 0):
        raise InputError(
            f"prior of pose {uid}: max_distance must be >= 0, got {prior.max_distance}"
        )
    if not (prior.max_turn >= 0):
        raise InputError(f"prior of pose {uid}: max_turn must be >= 0, got {prior.max_turn}")


def _out_of_view(prior: Prior, camera_range: float) -> bool:
    """True when the bound keeps the poses too far apart to share a landmark."""
    nearest = math.hypot(prior.transform[0], prior.transform[1]) - prior.max_distance
    return nearest > 2 * camera_range


def _contradicts(prior: Prior, T: F64) -> bool:
    off = math.hypot(T[0] - prior.transform[0], T[1] - prior.transform[1])
    turn = abs(math.remainder(float(T[2]) - prior.transform[2], 2 * math.pi))
    return off > prior.max_distance or turn > prior.max_turn


# --- the front end -------------------------------------------------------------------


def _check_pose(p: Pose, dim: int | None, what: str) -> None:
    lm = p.landmarks
    if len(lm) and not np.isfinite(lm.points).all():
        raise InputError(f"{what} pose {p.uid}: landmark points must be finite")
    if dim is not None and len(lm) and lm.descriptors.shape[1] != dim:
        raise InputError(
            f"{what} pose {p.uid}: descriptors of length {lm.descriptors.shape[1]}, expected {dim}"
        )


def associate(
    new: Pose,
    stored: Sequence[Pose],
    priors: Mapping[int, Prior] | None = None,
    params: AssociationParams | None = None,
    *,
    index: DescriptorIndex | None = None,
) -> tuple[list[ClosureEdge], AssociationStats]:
    """Loop closures between a new pose and stored poses.

    Parameters
    ----------
    new : Pose
        The new pose (own or received).
    stored : sequence of Pose
        The candidates, distinct UIDs. A pose with the new pose's UID is skipped.
    priors : mapping of UID to Prior, optional
        Odometry bounds per candidate; candidates without one are not bounded, and
        priors of UIDs not in ``stored`` are ignored.
    params : AssociationParams, optional
        Defaults when omitted.
    index : DescriptorIndex, optional
        An index built from exactly ``stored`` (same UIDs, same order), to reuse.

    Returns
    -------
    closures : list of ClosureEdge
        One per accepted candidate, in ``stored`` order: ``a`` the candidate, ``b`` the
        new pose, ``transform`` of b in a's frame refitted on the best draw's inliers
        with their stereo covariances, ``covariance`` of its (x, y, theta) in b's frame
        (as records keep them), ``inliers``,
        ``error`` E and ``matches`` (index in a's landmarks, index in b's), by b's index.
    stats : AssociationStats
        What each stage removed.

    Notes
    -----
    E = sum over inlier pairs of w(r_i, r_j) d^2 / N_inl with w = r_i r_j: reading the
    reliabilities as independent probabilities that a landmark is real and still in
    place, the product is the probability that the pair is, so a pair with a doubtful
    landmark costs less when it disagrees, as the thesis asks. The same weights weigh the
    refits. E ranks draws with equal inlier counts and, as 1/E, weighs the draws whose
    spread about the best transform forms the covariance. Draws that converge on the
    same inliers agree exactly, so the covariance also adds the refit's covariance (the
    inverse information of the stereo-weighted fit, scaled up when the residuals exceed
    the model) and a floor (``min_sigma_xy``, ``min_sigma_theta``) so that gtsam can
    always use it. The thesis's "mean" transform is replaced by the refit of the best
    draw's inliers, which is the one its matches describe. The certainty limits apply
    to the refit's covariance alone: the draws' spread measures RANSAC's search as much
    as the data.
    """
    params = AssociationParams() if params is None else params
    priors = {} if priors is None else priors
    stats = AssociationStats()
    if index is None:
        index = DescriptorIndex(stored)
    elif index.uids != tuple(p.uid for p in stored):
        raise InputError("associate: index was not built from these stored poses")
    dim = index.dim
    _check_pose(new, dim, "new")
    for p in stored:
        _check_pose(p, dim, "stored")
    for uid, given in priors.items():
        _check_prior(uid, given)

    offered = [i for i, p in enumerate(stored) if p.uid != new.uid]
    stats.candidates = len(offered)
    votes, pairs = index.votes(
        new.landmarks.descriptors, n_neighbours=params.n_neighbours, d_vote=params.d_vote
    )
    stats.vote_matches = int(pairs[offered].sum())
    kept = [i for i in offered if votes[i] >= params.min_votes]
    stats.after_votes = len(kept)
    stats.vote_matches_kept = int(pairs[kept].sum())
    in_view = [
        i
        for i in kept
        if stored[i].uid not in priors
        or not _out_of_view(priors[stored[i].uid], params.camera_range)
    ]
    stats.after_bounds = len(in_view)
    stats.vote_matches_after_bounds = int(pairs[in_view].sum())
    stats.kept["votes"] = tuple(stored[i].uid for i in kept)
    stats.kept["bounds"] = tuple(stored[i].uid for i in in_view)
    after_ransac: list[int] = []

    closures: list[ClosureEdge] = []
    for i in in_view:
        cand = stored[i]
        m = _putative(cand, new, params)
        stats.putative_matches += len(m.old)
        rng = np.random.default_rng([params.seed, cand.uid, new.uid])
        best, good = _ransac(m, params, rng)
        if best is None or len(best.inliers) < params.n_min:
            continue
        stats.after_ransac += 1
        stats.ransac_matches += len(best.inliers)
        after_ransac.append(cand.uid)
        inl = best.inliers
        ca, cb = (_point_covariance(p, params) for p in (m.a[inl], m.b[inl]))
        T, fit_cov = _refine(m.a[inl], m.b[inl], ca, cb, m.w[inl], best.transform)
        prior = priors.get(cand.uid)
        if prior is not None and _contradicts(prior, T):
            continue
        if not _certain(fit_cov, params):
            continue
        stats.accepted += 1
        stats.inlier_matches += len(best.inliers)
        order = best.inliers[np.argsort(m.new[best.inliers], kind="stable")]
        x, y, t = (float(v) for v in T)
        # Estimated with x, y in a's frame; records keep covariances in the frame of
        # the relative pose's end, b (gtsam's Pose2 tangent space): rotate by R(-t).
        c, s = math.cos(t), math.sin(t)
        turn = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
        cov = turn @ _covariance(best, good, fit_cov, params) @ turn.T
        closures.append(
            ClosureEdge(
                a=cand.uid,
                b=new.uid,
                transform=(x, y, t),
                covariance=tuple(float(v) for v in cov.ravel()),
                inliers=len(best.inliers),
                error=best.error,
                matches=tuple((int(m.old[k]), int(m.new[k])) for k in order),
            )
        )
    stats.kept["ransac"] = tuple(after_ransac)
    stats.kept["accepted"] = tuple(c.a for c in closures)
    return closures, stats
