"""Rigs: sonars mounted on a robot, read from and written to YAML.

A rig file looks like::

    sensor: maxsonar-ez1          # a preset, a mapping (sensors.sensor_from_dict) or a .yaml file
    sonars:
      - {name: left, x: 0.0, y: 0.15, yaw_deg: 90}
      - {name: right, x: 0.0, y: -0.15, yaw_deg: -90}

``x`` forward and ``y`` left of the robot's reference point in metres, ``yaw_deg``
counter-clockwise from the robot's heading.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from .checks import finite_number
from .errors import ConfigError, InputError, quote
from .files import dump_yaml, read_yaml
from .sensors import SensorModel, get_sensor, sensor_from_dict

__all__ = ["RIG_PRESETS", "SIX_BEARINGS", "Mount", "Rig", "get_rig", "load_rig", "save_rig"]


@dataclass(frozen=True)
class Mount:
    """One sonar on the robot: name and pose in the robot frame (metres, degrees)."""

    name: str
    x: float
    y: float
    yaw_deg: float


@dataclass(frozen=True)
class Rig:
    """Sonars of one model mounted on a robot.

    Parameters
    ----------
    sensor : SensorModel
        The model every sonar of the rig shares.
    mounts : tuple of Mount
        Unique names.
    """

    sensor: SensorModel
    mounts: tuple[Mount, ...]

    def __post_init__(self) -> None:
        if not self.mounts:
            raise ConfigError("a rig needs at least one sonar")
        names = [m.name for m in self.mounts]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise ConfigError(f"duplicate sonar name(s) in rig: {sorted(dup)}")

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(m.name for m in self.mounts)

    def index(self, name: str) -> int:
        """Position of a sonar in :attr:`mounts` by name."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ConfigError(
                f"unknown sensor '{name}'; the rig has {', '.join(self.names)}"
            ) from None

    def sensor_poses(
        self, x: npt.ArrayLike, y: npt.ArrayLike, theta: npt.ArrayLike
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """World poses of every sonar for robot poses.

        Parameters
        ----------
        x, y, theta : array_like, shape (N,)
            Robot poses (metres, radians).

        Returns
        -------
        sx, sy, stheta : ndarray, shape (N, M)
            Pose of sonar ``j`` at robot pose ``i`` in ``[i, j]``; ``stheta`` wrapped to (-pi, pi].
        """
        rx = np.asarray(x, dtype=np.float64)[:, None]
        ry = np.asarray(y, dtype=np.float64)[:, None]
        rt = np.asarray(theta, dtype=np.float64)[:, None]
        mx = np.array([m.x for m in self.mounts])[None, :]
        my = np.array([m.y for m in self.mounts])[None, :]
        myaw = np.radians([m.yaw_deg for m in self.mounts])[None, :]
        c, s = np.cos(rt), np.sin(rt)
        sx = rx + c * mx - s * my
        sy = ry + s * mx + c * my
        st = np.angle(np.exp(1j * (rt + myaw)))
        return sx, sy, st

    def to_dict(self) -> dict[str, Any]:
        return {
            "sensor": self.sensor.to_dict(),
            "sonars": [
                {"name": m.name, "x": m.x, "y": m.y, "yaw_deg": m.yaw_deg} for m in self.mounts
            ],
        }


def rig_from_dict(d: Any, where: str = "rig", base_dir: Path | None = None) -> Rig:
    """A rig from a parsed YAML mapping (keys ``sensor`` and ``sonars``).

    ``sensor`` is a preset name, a sensor mapping, or the path of a sensor YAML file
    (relative to ``base_dir``).
    """
    if not isinstance(d, Mapping):
        raise ConfigError(f"{where}: expected a mapping with keys 'sensor' and 'sonars'")
    for key in ("sensor", "sonars"):
        if key not in d:
            raise ConfigError(f"{where}: missing key '{key}'")
    unknown = set(d) - {"sensor", "sonars"}
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {sorted(unknown)}; valid: sensor, sonars")
    spec = d["sensor"]
    if isinstance(spec, str) and spec.endswith((".yaml", ".yml")):
        from .sensors import load_sensor

        sensor = load_sensor((base_dir or Path(".")) / spec)
    else:
        sensor = sensor_from_dict(spec, f"{where}.sensor")
    sonars = d["sonars"]
    if not isinstance(sonars, list) or not sonars:
        raise ConfigError(f"{where}.sonars: expected a non-empty list")
    mounts = []
    for i, s in enumerate(sonars):
        w = f"{where}.sonars[{i}]"
        if not isinstance(s, Mapping):
            raise ConfigError(f"{w}: expected a mapping with name, x, y, yaw_deg")
        for key in ("name", "x", "y", "yaw_deg"):
            if key not in s:
                raise ConfigError(f"{w}: missing key '{key}'")
        name = s["name"]
        if isinstance(name, bool) or not isinstance(name, str | int):
            raise ConfigError(f"{w}.name: expected a name, got {quote(name)}")
        name = str(name)
        # Readings name their sonar in a CSV field, read stripped of spaces.
        if not name or name != name.strip() or "\n" in name:
            raise ConfigError(
                f"{w}.name: {quote(name)} is empty or has spaces at an end or a line break"
            )
        yaw = finite_number(s["yaw_deg"], f"{w}.yaw_deg")
        if not -360.0 <= yaw <= 360.0:
            # A mounting turns at most a full turn either way; more is a slip of the pen.
            raise ConfigError(f"{w}.yaw_deg: must be within [-360, 360] degrees, got {yaw:g}")
        mounts.append(
            Mount(
                name=name,
                x=finite_number(s["x"], f"{w}.x"),
                y=finite_number(s["y"], f"{w}.y"),
                yaw_deg=yaw,
            )
        )
    return Rig(sensor=sensor, mounts=tuple(mounts))


def load_rig(path: str | Path) -> Rig:
    """Read a rig from a YAML file, or a preset when ``path`` names one."""
    p = Path(path)
    if str(path) in RIG_PRESETS and not p.exists():
        return get_rig(str(path))
    data = read_yaml(p, "rig file")
    try:
        return rig_from_dict(data, base_dir=p.parent)
    except ConfigError as err:
        raise InputError(str(err), path=p) from err


def save_rig(rig: Rig, path: str | Path) -> None:
    """Write a rig as YAML (atomically)."""
    from .files import atomic_write_text

    atomic_write_text(Path(path), dump_yaml(rig.to_dict()))


def _paper_synthetic() -> Rig:
    # Thesis 000, fig. 4.1 (left): three sonars on each side; the middle one looks
    # perpendicular to the side, the outer two are turned 30 degrees from it.
    mounts = []
    for side, sign in (("left", 1.0), ("right", -1.0)):
        for tag, dx, turn in (("front", 0.1, -30.0), ("mid", 0.0, 0.0), ("rear", -0.1, 30.0)):
            mounts.append(Mount(f"{side}_{tag}", dx, sign * 0.15, sign * (90.0 + turn)))
    return Rig(sensor=get_sensor("maxsonar-ez1"), mounts=tuple(mounts))


def _paper_real() -> Rig:
    # Thesis 000, fig. 4.1 (right): four sonars at the front, the outer two turned
    # 45 degrees away from the inner two.
    return Rig(
        sensor=get_sensor("maxsonar-ez1"),
        mounts=(
            Mount("outer_left", 0.12, 0.12, 45.0),
            Mount("inner_left", 0.15, 0.04, 0.0),
            Mount("inner_right", 0.15, -0.04, 0.0),
            Mount("outer_right", 0.12, -0.12, -45.0),
        ),
    )


def _pioneer_front() -> Rig:
    # Pioneer 2/3 front sonar array (MobileRobots operations manual): eight Polaroid
    # transducers at +-90, +-50, +-30, +-10 degrees; positions in metres from the robot
    # centre as listed for the P3-DX.
    spec = [
        (0.069, 0.136, 90.0),
        (0.114, 0.119, 50.0),
        (0.148, 0.078, 30.0),
        (0.166, 0.027, 10.0),
        (0.166, -0.027, -10.0),
        (0.148, -0.078, -30.0),
        (0.114, -0.119, -50.0),
        (0.069, -0.136, -90.0),
    ]
    mounts = tuple(Mount(f"s{i}", x, y, yaw) for i, (x, y, yaw) in enumerate(spec))
    return Rig(sensor=get_sensor("polaroid-6500"), mounts=mounts)


def _ring16() -> Rig:
    # A uniform ring of 16 sonars, 0.2 m from the centre, every 22.5 degrees.
    mounts = []
    for i in range(16):
        a = 2 * math.pi * i / 16
        mounts.append(Mount(f"s{i:02d}", 0.2 * math.cos(a), 0.2 * math.sin(a), math.degrees(a)))
    return Rig(sensor=get_sensor("polaroid-6500"), mounts=tuple(mounts))


#: Names and bearings (degrees) of the six-sonar rigs: front, +-45 degrees, sides, back.
SIX_BEARINGS = (
    ("front", 0.0),
    ("front_left", 45.0),
    ("front_right", -45.0),
    ("left", 90.0),
    ("right", -90.0),
    ("back", 180.0),
)


def _six(sensor: str) -> Rig:
    # A hobby robot's six sonars 0.15 m from its centre, each looking out from it.
    mounts = []
    for name, yaw in SIX_BEARINGS:
        a = math.radians(yaw)
        mounts.append(Mount(name, 0.15 * math.cos(a), 0.15 * math.sin(a), yaw))
    return Rig(sensor=get_sensor(sensor), mounts=tuple(mounts))


def _ez1_six() -> Rig:
    return _six("maxsonar-ez1")


def _hcsr04_six() -> Rig:
    return _six("hc-sr04")


RIG_PRESETS: Mapping[str, Callable[[], Rig]] = {
    "paper-synthetic": _paper_synthetic,
    "paper-real": _paper_real,
    "pioneer-front": _pioneer_front,
    "ring16": _ring16,
    "ez1-six": _ez1_six,
    "hcsr04-six": _hcsr04_six,
}


def get_rig(name: str) -> Rig:
    """A preset rig by name: ``paper-synthetic``, ``paper-real``, ``pioneer-front``,
    ``ring16`` (16 Polaroid sonars), ``ez1-six`` (six MaxSonar EZ1s at :data:`SIX_BEARINGS`)
    or ``hcsr04-six`` (six HC-SR04s there)."""
    try:
        return RIG_PRESETS[name]()
    except KeyError:
        raise ConfigError(f"unknown rig preset '{name}'; valid: {', '.join(RIG_PRESETS)}") from None
