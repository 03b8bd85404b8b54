"""Team patrolling by potential fields (thesis 002, chapter 3; ``docs/patrol.md``).

A team of robots keeps a known territory watched with no central planner: every place
pulls each robot with a force growing with how long the place has gone unseen and
falling with the length of the path to it. One module per concept:

- :mod:`.territory` -- where robots can be (free cells, the robot's radius kept clear);
- :mod:`.fog` -- time since each place was last seen, and the metrics built on it;
- :mod:`.paths` -- path lengths and first steps (the wave; straight lines in open space);
- :mod:`.forces` -- the force families f x g and the direction a robot chooses;
- :mod:`.robots` -- holonomic robots moving with the thesis's collision rule;
- :mod:`.network` -- who hears whom (full, limited, none), relayed along chains;
- :mod:`.policies` -- the potential field and the literature's baselines;
- :mod:`.simulation` -- the step loop and what a run measured.
"""

from .fog import Fog
from .forces import FORCE_F, FORCE_G, Force, choose_direction, parse_force
from .network import NETWORKS, components
from .paths import straight_paths, wave
from .policies import POLICIES
from .robots import Holonomic
from .simulation import PatrolConfig, PatrolResult, read_starts, run_patrol
from .territory import Territory

__all__ = [
    "FORCE_F",
    "FORCE_G",
    "NETWORKS",
    "POLICIES",
    "Fog",
    "Force",
    "Holonomic",
    "PatrolConfig",
    "PatrolResult",
    "Territory",
    "choose_direction",
    "components",
    "parse_force",
    "read_starts",
    "run_patrol",
    "straight_paths",
    "wave",
]
