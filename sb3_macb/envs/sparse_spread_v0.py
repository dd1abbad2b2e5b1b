"""
Sparse Spread, mpe2's simple_spread with a success-only team reward, in mpe2's style.

    from sb3_macb.envs import sparse_spread_v0
    env = sparse_spread_v0.parallel_env(n_agents=3)

``n_agents`` agents (``agent_0`` ...; observation 4 * n_agents + 2: velocity, position, every landmark and every
other agent relative to it; action: a 2-D force command in [-1, 1]) must cover as many landmarks at once. The
team reward is 0 on the steps where every landmark has an agent within ``cover_radius`` and -1 on every other
step, so a team that never covers them all sees one constant reward.
"""

from typing import Any

from sb3_macb.envs.task_constants import SPREAD_COVER_RADIUS, SPREAD_MAX_CYCLES
from sb3_macb.envs.tasks import SparseSpreadScenario, TaskParallelEnv, to_aec

NAME = "sparse_spread_v0"


def parallel_env(
    n_agents: int = 3,
    max_cycles: int = SPREAD_MAX_CYCLES,
    cover_radius: float = SPREAD_COVER_RADIUS,
    terminate_on_success: bool = False,
    render_mode: str | None = None,
) -> TaskParallelEnv:
    """
    :param n_agents: Number of agents and of landmarks.
    :param max_cycles: Steps per episode (25, as mpe2's simple_spread).
    :param cover_radius: A landmark is covered when an agent is within this distance (0.1, mpe2's capture radius).
    :param terminate_on_success: End the episode when every landmark is covered.
    :param render_mode: None, ``"rgb_array"`` or ``"human"``.
    :return: The parallel environment (``env()`` gives the AEC version).
    """
    scenario = SparseSpreadScenario(n_agents, cover_radius, terminate_on_success)
    return TaskParallelEnv(scenario, max_cycles=max_cycles, render_mode=render_mode, name=NAME)


def env(**kwargs: Any) -> Any:
    """The AEC version of :func:`parallel_env` (same arguments)."""
    return to_aec(parallel_env(**kwargs))
