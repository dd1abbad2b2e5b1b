"""
2-Agent Navigation (sparse reward, or success-only), the paper's fully observed task, in mpe2's style.

    from sb3_macb.envs import two_agent_navigation_v0
    env = two_agent_navigation_v0.parallel_env(max_cycles=20)

Two agents (``agent_0``, ``agent_1``) must cover two landmarks. Observation (10 per agent): own velocity, own
position, both landmarks and the other agent relative to it. Action: a 2-D force command in [-1, 1].
"""

from typing import Any

from sb3_macb.envs.task_constants import MAX_CYCLES, NAVIGATION
from sb3_macb.envs.tasks import TaskParallelEnv, TwoAgentNavigationScenario, to_aec

NAME = "two_agent_navigation_v0"


def parallel_env(
    max_cycles: int = MAX_CYCLES,
    reward_radius: float = NAVIGATION.reward_radius,
    success_radius: float = NAVIGATION.success_radius,
    collision_penalty: bool = True,
    terminate_on_success: bool = False,
    render_mode: str | None = None,
    reward: str = "sparse",
) -> TaskParallelEnv:
    """
    :param max_cycles: Steps per episode.
    :param reward_radius: A landmark counts as covered for the reward when an agent is within this distance.
    :param success_radius: The episode succeeds when every landmark has an agent within this distance.
    :param collision_penalty: Whether colliding agents are penalised.
    :param terminate_on_success: End the episode on success (the paper's episodes run on).
    :param render_mode: None, ``"rgb_array"`` or ``"human"``.
    :param reward: ``"sparse"`` (the paper's: uncovered landmarks and collisions cost) or ``"success"`` (0 when
        every landmark has an agent within ``success_radius``, else -1).
    :return: The parallel environment (``env()`` gives the AEC version).
    """
    scenario = TwoAgentNavigationScenario(reward_radius, success_radius, collision_penalty, terminate_on_success, reward)
    return TaskParallelEnv(scenario, max_cycles=max_cycles, render_mode=render_mode, name=NAME)


def env(**kwargs: Any) -> Any:
    """The AEC version of :func:`parallel_env` (same arguments)."""
    return to_aec(parallel_env(**kwargs))
