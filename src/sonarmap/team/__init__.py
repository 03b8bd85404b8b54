"""Team mapping (thesis 002, chapter 2): each robot's bounded long-term store of poses,
landmarks and local sonar maps, data association, and the robot's global map.

One module per concept: :mod:`.records` (poses, landmarks, edges and their msgpack
encoding), :mod:`.regions` (the prior map cut into rooms and corridors), :mod:`.world`
(the simulated mission: landmarks, route, odometry, observations), :mod:`.association`
(descriptor voting, odometry bounds, RANSAC), :mod:`.store` (time stamps, reliability,
pose and region compression, merging), :mod:`.globalmap` (pose-graph optimisation, the
fused occupancy map, alignment to the prior map).
"""
