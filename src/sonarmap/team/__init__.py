"""Team mapping (thesis 002, chapter 2): each robot's bounded long-term store of poses,
landmarks and local sonar maps, the exchange of patches between robots, and each
robot's global map. The design and the choices where the thesis is silent are in
``docs/team.md``.

One module per concept, from the ground up:

- records and their encoding: :mod:`.records`; the prior map's regions: :mod:`.regions`;
  a prior that is not the truth (doorways, furniture, scale): :mod:`.prior`;
  the simulated world (landmarks, routes, odometry): :mod:`.world`;
- one robot: the store (:mod:`.store`), association (:mod:`.association`), the pose
  graph and global map (:mod:`.globalmap`), its settings (:mod:`.config`), the robot on
  its mission (:mod:`.mission`), fed by the world simulator of its sensors
  (:mod:`.sensing`) and watched by its evaluator (:mod:`.evaluation`, :mod:`.scoring`);
- the exchange: the wire format (:mod:`.wire`), the outgoing-pose policy
  (:mod:`.outgoing`, :mod:`.anchors`, :mod:`.quantise`), the protocols
  (:mod:`.exchange`) and the naive baseline (:mod:`.naive`), over a transport
  (:mod:`.transport`) and a simulated network (:mod:`.network`);
- the team: the one lock-step clock (:mod:`.lockstep`), the simulated team
  (:mod:`.simulation`) and the ZeroMQ node (:mod:`.node`, :mod:`.link`,
  :mod:`.launcher`), the central bound (:mod:`.central`), the summary
  (:mod:`.summary`), the files a run writes (:mod:`.outputs`) and the animations
  (:mod:`.animation`); routes from the patroller: :mod:`.patrolling`.
"""
