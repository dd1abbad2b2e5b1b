"""
The constants of the paper's two tasks, in one place: both implementations (:mod:`sb3_macb.envs.tasks` on mpe2's
world and the vectorized :mod:`sb3_macb.envs.vec_tasks`) read them from here.
"""

from dataclasses import dataclass

import numpy as np

# MPE's particle physics (mpe2's World defaults, set explicitly on the worlds of sb3_macb.envs.tasks)
FORCE_SCALE = 5.0  # an agent's movement action u in [-1, 1] gives the force 5 * u (MPE's default sensitivity)
DT = 0.1  # integration step
DAMPING = 0.25  # velocity damping per step
CONTACT_FORCE = 1e2  # soft contact between colliding entities
CONTACT_MARGIN = 1e-3
MAX_CYCLES = 20  # steps per episode

# Communicative Navigation: the landmarks' colours (red, green, blue), which are also what the speaker observes
GOAL_COLORS = np.array([[0.65, 0.15, 0.15], [0.15, 0.65, 0.15], [0.15, 0.15, 0.65]])


@dataclass(frozen=True)
class TaskConstants:
    """
    The geometry of one task.

    :param size: Radius of every agent and landmark.
    :param n_landmarks: Number of landmarks.
    :param reward_radius: Default radius of the sparse reward.
    :param success_radius: Default success radius.
    """

    size: float
    n_landmarks: int
    reward_radius: float
    success_radius: float


NAVIGATION = TaskConstants(size=0.125, n_landmarks=2, reward_radius=0.125, success_radius=0.25)
COMMUNICATION = TaskConstants(size=0.075, n_landmarks=3, reward_radius=0.15, success_radius=0.15)

# Sparse Spread (mpe2's simple_spread with a sparse team reward): agents of size 0.15 that collide, landmarks of
# mpe2's default size 0.05, a landmark covered when an agent is within 0.1 (mpe2's capture radius), 25 steps
SPREAD_AGENT_SIZE = 0.15
SPREAD_LANDMARK_SIZE = 0.05
SPREAD_COVER_RADIUS = 0.1
SPREAD_MAX_CYCLES = 25
