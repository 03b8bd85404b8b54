"""Team patrolling by potential fields (thesis 002, chapter 3; ``docs/patrol.md``).

A team of robots keeps a known territory watched with no central planner: every place
pulls each robot with a force growing with how long the place has gone unseen and
falling with the length of the path to it. One module per concept:

- :mod:`.territory` -- where robots can be (free cells, the robot's radius kept clear);
- :mod:`.fog` -- time since each place was last seen, and the metrics built on it;
- :mod:`.paths` -- path lengths and first steps (the wave; straight lines in open space);
- :mod:`.finders`, :mod:`.regions`, :mod:`.marching` -- the static alternatives to the
  wave (offline regions with doors; fast marching);
- :mod:`.forces` -- the force families f x g and the direction a robot chooses;
- :mod:`.refine` -- direction refinement and weakening;
- :mod:`.robots` -- holonomic robots and cars, with the thesis's collision rule;
- :mod:`.network` -- who hears whom (full, limited, none), relayed along chains;
- :mod:`.semaphores` -- marked areas one robot (or one step's entrants) may hold;
- :mod:`.policies`, :mod:`.tour` -- the potential field and the literature's baselines;
- :mod:`.graph`, :mod:`.monitor` -- the patrol graph derived from the map, and the graph
  patrolling literature's metrics on it (visit intervals, cycles, interference);
- :mod:`.maps`, :mod:`.config` -- the built-in territories, the thesis's file formats;
- :mod:`.settings`, :mod:`.launch` -- a run's settings (:class:`PatrolConfig`), its starts
  and team;
- :mod:`.crowding`, :mod:`.goals`, :mod:`.steering` -- the cells a robot closes round the
  others, the place it goes for and how it heads there;
- :mod:`.simulation`, :mod:`.result` -- the step loop (:func:`run_patrol`) and what a run
  measured (:class:`PatrolResult`);
- :mod:`.experiments` -- the thesis's experiments, on Dask.
"""

from .fog import Fog
from .forces import FORCE_F, FORCE_G, Force, choose_direction, parse_force
from .graph import PatrolGraph
from .monitor import Monitor
from .network import NETWORKS, components
from .paths import straight_paths, wave
from .policies import POLICIES
from .robots import Car, Holonomic, Team
from .simulation import PatrolConfig, PatrolResult, run_patrol
from .starts import read_starts
from .territory import Territory

__all__ = [
    "FORCE_F",
    "FORCE_G",
    "NETWORKS",
    "POLICIES",
    "Car",
    "Fog",
    "Force",
    "Holonomic",
    "Monitor",
    "PatrolConfig",
    "PatrolGraph",
    "PatrolResult",
    "Team",
    "Territory",
    "choose_direction",
    "components",
    "parse_force",
    "read_starts",
    "run_patrol",
    "straight_paths",
    "wave",
]
