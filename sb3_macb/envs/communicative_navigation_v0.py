"""
Communicative Navigation, the paper's partially observed task, in mpe2's style.

    from sb3_macb.envs import communicative_navigation_v0
    env = communicative_navigation_v0.parallel_env(reward="sparse")

A static speaker (``speaker_0``, observation 3: the goal's colour; action 3: a message in [0, 1]) guides a silent
listener (``listener_0``, observation 2 + 2 * n_landmarks + 3: velocity, the landmarks relative to it, the message;
action: a 2-D force command in [-1, 1]) to the goal landmark. The paper's task has three landmarks (observation 11).
"""

from typing import Any

from sb3_macb.envs.task_constants import COMMUNICATION, MAX_CYCLES
from sb3_macb.envs.tasks import CommunicativeNavigationScenario, TaskParallelEnv, to_aec

NAME = "communicative_navigation_v0"


def parallel_env(
    max_cycles: int = MAX_CYCLES,
    reward: str = "sparse",
    reward_radius: float = COMMUNICATION.reward_radius,
    success_radius: float = COMMUNICATION.success_radius,
    terminate_on_success: bool = False,
    render_mode: str | None = None,
    n_landmarks: int = COMMUNICATION.n_landmarks,
    half_width: float = 1.0,
) -> TaskParallelEnv:
    """
    :param max_cycles: Steps per episode.
    :param reward: ``"sparse"`` (0 within ``reward_radius`` of the goal, else -1) or ``"distance"`` (minus the
        squared distance to the goal).
    :param reward_radius: Radius of the sparse reward.
    :param success_radius: The episode succeeds when the listener comes within this distance of the goal.
    :param terminate_on_success: End the episode on success (the paper's episodes run on).
    :param render_mode: None, ``"rgb_array"`` or ``"human"``.
    :param n_landmarks: Number of landmarks (the paper's 3; more for a harder task).
    :param half_width: Every entity starts uniformly in [-half_width, half_width]^2 (the paper's 1).
    :return: The parallel environment (``env()`` gives the AEC version).
    """
    scenario = CommunicativeNavigationScenario(
        reward, reward_radius, success_radius, terminate_on_success, n_landmarks, half_width
    )
    return TaskParallelEnv(scenario, max_cycles=max_cycles, render_mode=render_mode, name=NAME)


def env(**kwargs: Any) -> Any:
    """The AEC version of :func:`parallel_env` (same arguments)."""
    return to_aec(parallel_env(**kwargs))
