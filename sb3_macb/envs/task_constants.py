"""
The constants and allowed settings of the package's tasks, in one place: both implementations (:mod:`sb3_macb.envs.tasks`
on mpe2's world and the vectorized :mod:`sb3_macb.envs.vec_tasks` and :mod:`sb3_macb.envs.vec_spread`) read them here.
"""

import colorsys
from dataclasses import dataclass
from typing import Any

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


def goal_colors(n_landmarks: int) -> np.ndarray:
    """
    The landmarks' colours of Communicative Navigation with ``n_landmarks`` landmarks: :data:`GOAL_COLORS` for the
    paper's three, otherwise ``n_landmarks`` hues evenly spaced on the colour circle at the same saturation and
    value (the paper's three are the hues 0, 1/3 and 2/3 of that circle).

    :param n_landmarks: Number of landmarks (at least 2).
    :return: Colours, shape (n_landmarks, 3).
    """
    if n_landmarks == len(GOAL_COLORS):
        return GOAL_COLORS.copy()
    value, saturation = 0.65, 1 - 0.15 / 0.65  # the paper's colours: hues 0, 1/3, 2/3 at this saturation and value
    return np.array([colorsys.hsv_to_rgb(j / n_landmarks, saturation, value) for j in range(n_landmarks)])


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


NAVIGATION_REWARDS = ("sparse", "success")
COMMUNICATION_REWARDS = ("sparse", "distance")

NAVIGATION = TaskConstants(size=0.125, n_landmarks=2, reward_radius=0.125, success_radius=0.25)
COMMUNICATION = TaskConstants(size=0.075, n_landmarks=3, reward_radius=0.15, success_radius=0.15)


def check_navigation_settings(reward: str) -> None:
    """Raise a ``ValueError`` naming the setting of 2-Agent Navigation that is not allowed."""
    if reward not in NAVIGATION_REWARDS:
        raise ValueError(f"reward must be one of {NAVIGATION_REWARDS} for 2-Agent Navigation, got {reward!r}")


def check_communication_settings(reward: str, n_landmarks: Any, half_width: Any) -> None:
    """Raise a ``ValueError`` naming the setting of Communicative Navigation that is not allowed."""
    if reward not in COMMUNICATION_REWARDS:
        raise ValueError(f"reward must be one of {COMMUNICATION_REWARDS} for Communicative Navigation, got {reward!r}")
    if isinstance(n_landmarks, bool) or not isinstance(n_landmarks, (int, np.integer)) or n_landmarks < 2:
        raise ValueError(f"n_landmarks must be an integer >= 2, got {n_landmarks!r}")
    if isinstance(half_width, bool) or not isinstance(half_width, (int, float)) or not half_width > 0:
        raise ValueError(f"half_width must be > 0, got {half_width!r}")


# Sparse Spread (mpe2's simple_spread with a sparse team reward): agents of size 0.15 that collide, landmarks of
# mpe2's default size 0.05, a landmark covered when an agent is within 0.1 (mpe2's capture radius), 25 steps
SPREAD_AGENT_SIZE = 0.15
SPREAD_LANDMARK_SIZE = 0.05
SPREAD_COVER_RADIUS = 0.1
SPREAD_MAX_CYCLES = 25
