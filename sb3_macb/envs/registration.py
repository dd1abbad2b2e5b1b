"""
Gymnasium ids for the paper's tasks and Sparse Spread, building the joint env directly (for ``gym.make`` and rl_zoo3).

The tasks give every agent the same shared reward, so the joint env's scalar reward is that shared reward
(``team_reward="mean"``), not the number of agents times it; each critic still learns from its agent's reward.
"""

from typing import Any

import gymnasium as gym

from sb3_macb.envs.joint_env import JointEnv, make_joint_env

ENV_IDS = ("sb3_macb/TwoAgentNavigation-v0", "sb3_macb/CommunicativeNavigation-v0", "sb3_macb/SparseSpread-v0")


def make_two_agent_navigation(**kwargs: Any) -> JointEnv:
    from sb3_macb.envs import two_agent_navigation_v0

    return make_joint_env(two_agent_navigation_v0.parallel_env(**kwargs), team_reward="mean")


def make_communicative_navigation(**kwargs: Any) -> JointEnv:
    from sb3_macb.envs import communicative_navigation_v0

    return make_joint_env(communicative_navigation_v0.parallel_env(**kwargs), team_reward="mean")


def make_sparse_spread(**kwargs: Any) -> JointEnv:
    from sb3_macb.envs import sparse_spread_v0

    return make_joint_env(sparse_spread_v0.parallel_env(**kwargs), team_reward="mean")


def register_envs() -> None:
    """Register the tasks' gymnasium ids (idempotent). Keyword arguments of ``gym.make`` pass through."""
    entry_points = {
        "sb3_macb/TwoAgentNavigation-v0": make_two_agent_navigation,
        "sb3_macb/CommunicativeNavigation-v0": make_communicative_navigation,
        "sb3_macb/SparseSpread-v0": make_sparse_spread,
    }
    for env_id, entry_point in entry_points.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=entry_point, disable_env_checker=True)
