"""The simulated follower: the pybullet NAO, its gait and world, and the studies run on it."""
