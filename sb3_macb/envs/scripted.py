"""
Scripted reference policies of the vectorized tasks, read from the env's state: they show that a task can be
solved in its episode length and give the success level that a learned policy is compared with.

    from sb3_macb.envs.scripted import scripted_actions
    from sb3_macb.envs.vec_tasks import make_task_vec_env
    venv = make_task_vec_env("sb3_macb/SparseSpread-v0", 100, {"n_agents": 3})
    venv.reset()
    obs, rewards, dones, infos = venv.step(scripted_actions(venv))
"""

from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from sb3_macb.envs.vec_spread import SpreadVecEnv
from sb3_macb.envs.vec_tasks import TaskVecEnv


def _steer(positions: np.ndarray, velocities: np.ndarray, targets: np.ndarray, gain: float, damping: float) -> np.ndarray:
    """A proportional-derivative force toward each target, clipped to the action bounds."""
    return np.clip(gain * (targets - positions) - damping * velocities, -1.0, 1.0)


def covering_targets(agents: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """
    Send each agent to a landmark so that the total distance is smallest (the assignment problem, solved per env).

    :param agents: Agent positions, shape (n_envs, n_agents, 2).
    :param landmarks: Landmark positions, shape (n_envs, n_landmarks, 2), with n_landmarks == n_agents.
    :return: Each agent's target, shape (n_envs, n_agents, 2).
    """
    distances = np.linalg.norm(agents[:, :, None, :] - landmarks[:, None, :, :], axis=-1)  # (envs, agent, landmark)
    targets = np.empty_like(agents)
    for i, cost in enumerate(distances):
        rows, columns = linear_sum_assignment(cost)
        targets[i, rows] = landmarks[i, columns]
    return targets


def scripted_actions(venv: Any, gain: float = 10.0, damping: float = 5.0) -> np.ndarray:
    """
    Joint actions of the reference policy for the env's current state.

    - Sparse Spread and 2-Agent Navigation: the agents go to the landmarks of :func:`covering_targets` with a
      proportional-derivative force. The agents' contact is ignored, so this fails mostly where two landmarks lie
      closer than two agents can sit.
    - Communicative Navigation: the listener goes to the goal the same way; the speaker's message (zero) is not
      needed, because the policy reads the goal from the state.

    :param venv: A :class:`~sb3_macb.envs.vec_spread.SpreadVecEnv` or :class:`~sb3_macb.envs.vec_tasks.TaskVecEnv`,
        or a ``VecEnvWrapper`` around one.
    :param gain: Force per unit of distance to the target.
    :param damping: Force per unit of velocity, against it.
    :return: Joint actions, shape (n_envs, action_dim).
    """
    env = venv.unwrapped
    if isinstance(env, SpreadVecEnv) or (isinstance(env, TaskVecEnv) and env.task == "navigation"):
        n = env.agent_layout.n_agents
        agents = env.pos[:, :n]
        actions = _steer(agents, env.vel, covering_targets(agents, env.pos[:, n:]), gain, damping)
        return actions.reshape(env.num_envs, 2 * n).astype(np.float32)
    if isinstance(env, TaskVecEnv):
        goal = env.pos[np.arange(env.num_envs), 2 + env.goal]
        listener = _steer(env.pos[:, 1], env.vel[:, 1], goal, gain, damping)
        return np.concatenate([np.zeros((env.num_envs, 3)), listener], axis=1).astype(np.float32)
    raise TypeError(f"scripted_actions needs a SpreadVecEnv or a TaskVecEnv, got {type(env).__name__}")
