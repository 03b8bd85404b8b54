"""The world simulator of one robot's mission: what its odometry, sonars and stereo
camera give along its route through the simulated world, and the truth behind them.

The robot (:class:`~.mission.RobotAgent`) sees only :meth:`RobotSensing.odometry`,
:meth:`RobotSensing.readings_up_to` and :meth:`RobotSensing.landmarks_at`, and its start
as it believes it (:attr:`RobotSensing.start_believed`: the true start off by the
mission's ``start_error``); the truth (:attr:`RobotSensing.route`,
:meth:`RobotSensing.true_pose`, :attr:`RobotSensing.a_true`) is for the evaluator
(:mod:`.evaluation`) and the central bound.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import numpy.typing as npt

from ..io.rosmap import OccupancyMap
from ..readings import Readings
from ..rig import get_rig
from .config import MissionConfig
from .records import Landmarks, compose, invert
from .world import (
    ODOMETRY_NOISE,
    ROUTE_SEED_STEP,
    World,
    observe,
    odometry,
    patrol_route,
    sonar_readings,
)

__all__ = ["RobotSensing"]

F64 = npt.NDArray[np.float64]


class RobotSensing:
    """One robot's sensors along its route (see the module's notes).

    Parameters
    ----------
    plan : OccupancyMap
        The floor the robot drives.
    config : MissionConfig
        The mission (duration, rig, mapping range, start error, seed).
    world : World
        The landmarks.
    robot : int
        The robot's id: its seeds are ``config.seed + ROUTE_SEED_STEP robot``
        (:data:`~.world.ROUTE_SEED_STEP`) and the next three.
    route : ndarray (T, 4), optional
        ``t, x, y, theta``; replaces the patrol route drawn from the seed.
    odometry_noise : mapping of str to float, optional
        :func:`~.world.odometry`'s noise keywords; :data:`~.world.ODOMETRY_NOISE` unless
        given.

    Attributes
    ----------
    route : ndarray (T, 4)
        The true route, cut to the mission's duration.
    odo : ndarray (T, 4)
        The odometry's ``t, x, y, theta`` at each route step.
    rig : Rig
    readings : Readings
        The sonar readings up to ``mapping_range``, in the world frame (truth).
    step_of : ndarray of int
        The route step each reading was taken at.
    mounts : ndarray (N, 3)
        Each reading's sonar pose on the robot.
    start_believed : ndarray (3,)
        The robot's start as it believes it.
    a_true : ndarray (3,)
        The true transform from the robot's frame to the plan's.
    """

    def __init__(
        self,
        plan: OccupancyMap,
        config: MissionConfig,
        world: World,
        robot: int,
        route: F64 | None = None,
        *,
        odometry_noise: Mapping[str, float] | None = None,
    ) -> None:
        cfg = config
        self.world = world
        self.seed = seed = cfg.seed + ROUTE_SEED_STEP * robot
        true = patrol_route(plan, cfg.duration, seed=seed) if route is None else route
        true = np.asarray(true, dtype=np.float64)
        true = true[true[:, 0] <= true[0, 0] + cfg.duration]
        self.route = true
        noise = ODOMETRY_NOISE if odometry_noise is None else odometry_noise
        odo, _ = odometry(true, seed=seed + 1, **noise)
        self.odo = odo
        self.rig = get_rig(cfg.rig)
        readings = sonar_readings(plan, true, rig=self.rig, seed=seed + 2)
        readings = readings.take(np.flatnonzero(readings.range <= cfg.mapping_range))
        self.readings = readings
        self.step_of = np.clip(np.searchsorted(true[:, 0], readings.t), 0, len(true) - 1)
        # Each reading's sonar pose on the robot: invert(true robot pose) (+) world sonar pose.
        self.mounts = compose(
            invert(true[self.step_of, 1:4]),
            np.column_stack([readings.x, readings.y, readings.theta]),
        )
        # The robot's start as it believes it: the true one off by start_error.
        rng = np.random.default_rng(seed + 3)
        off = np.array([*rng.normal(0, cfg.start_error[0], 2), rng.normal(0, cfg.start_error[1])])
        start_true = true[0, 1:4]
        self.start_believed = start_true + off
        # Prior frame = A_true (+) robot frame.
        self.a_true = compose(start_true, invert(self.start_believed))

    @property
    def steps(self) -> int:
        """Route steps of the mission."""
        return len(self.route)

    def odometry(self) -> F64:
        """The odometry's ``t, x, y, theta`` at every route step (T, 4)."""
        return self.odo

    def readings_up_to(self, after: int, k: int) -> tuple[Readings, F64, npt.NDArray[np.intp]]:
        """The sonar readings taken after route step ``after`` up to step ``k``, as the
        robot has them: the readings (their world poses left to the caller to replace),
        each one's sonar pose on the robot, and the step it was taken at."""
        mine = np.flatnonzero((self.step_of > after) & (self.step_of <= k))
        return self.readings.take(mine), self.mounts[mine], self.step_of[mine]

    def landmarks_at(self, k: int) -> Landmarks:
        """What the stereo camera sees at route step ``k``."""
        return observe(self.world, self.route[k, 1:4], float(self.route[k, 0]), seed=self.seed)

    def true_pose(self, k: int) -> F64:
        """The true pose (x, y, theta) at route step ``k`` (a copy)."""
        return np.asarray(self.route[k, 1:4], dtype=np.float64).copy()
