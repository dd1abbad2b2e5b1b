"""The SB3 ``VecEnv`` methods shared by the package's batched envs, whose envs are rows of one object."""

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium.utils import seeding
from stable_baselines3.common.vec_env import VecEnv

from sb3_macb.common.private_apis import next_reset_seeds
from sb3_macb.envs.joint_env import AgentLayout


class BatchedVecEnv(VecEnv):
    """
    Base of a ``VecEnv`` that simulates all its envs as one batch (one object, not one env object per index): an
    attribute is the batch's for every index, there are no per-env methods or wrappers, nothing to close and no
    images. The joint actions given to ``step_async`` are checked by :meth:`_joint_actions`. Subclasses set
    ``agent_layout`` and implement ``reset`` and ``step_wait``.
    """

    agent_layout: AgentLayout
    _actions: np.ndarray | None = None

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def _joint_actions(self) -> np.ndarray:
        """The actions given to ``step_async`` as (num_envs, action_dim) float32; a wrong size or a NaN is an error."""
        assert self._actions is not None, "step_async was not called"
        actions = np.asarray(self._actions, dtype=np.float32).reshape(self.num_envs, -1)
        if actions.shape[1] != self.agent_layout.action_dim:
            raise ValueError(f"Expected joint actions of size {self.agent_layout.action_dim}, got {actions.shape[1]}")
        if not np.all(np.isfinite(actions)):
            raise ValueError("NaN or infinite value in the actions")
        return actions

    def close(self) -> None:
        pass

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        return [getattr(self, attr_name)] * len(list(self._get_indices(indices)))

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        setattr(self, attr_name, value)

    def env_method(self, method_name: str, *method_args: Any, indices: Any = None, **method_kwargs: Any) -> list[Any]:
        raise AttributeError(f"{type(self).__name__} has no per-env method {method_name!r}")

    def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
        return [False] * len(list(self._get_indices(indices)))

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None] * self.num_envs


class ParticleVecEnv(BatchedVecEnv):
    """
    Base of the package's vectorized particle tasks: each env is a row of numpy arrays that resets from its own
    random generator (seeded as gymnasium seeds an env), and episodes end on the time limit or, optionally, on
    success. Subclasses set ``rngs``, ``steps``, ``success_ever``, ``episode_collisions``, ``max_cycles`` and
    ``terminate_on_success``, implement ``_reset_env(i)`` and ``_observations(envs)``, and end ``step_wait`` with
    :meth:`_end_step`.
    """

    rngs: list[np.random.Generator]
    steps: np.ndarray
    success_ever: np.ndarray
    episode_collisions: np.ndarray
    max_cycles: int
    terminate_on_success: bool

    def _reset_env(self, i: int) -> None:
        raise NotImplementedError

    def _observations(self, envs: Any = slice(None)) -> np.ndarray:
        raise NotImplementedError

    def reset(self) -> np.ndarray:
        for i, seed in enumerate(next_reset_seeds(self)):
            if seed is not None:
                self.rngs[i] = seeding.np_random(seed)[0]
            self._reset_env(i)
        self._reset_seeds()
        self._reset_options()
        return self._observations()

    def _end_step(
        self, rewards: np.ndarray, success: np.ndarray, collisions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        """
        Count the step, end the episodes that are over (resetting those envs) and build what ``step_wait`` returns.

        :param rewards: The shared reward of each env, shape (num_envs,).
        :param success: Whether each env's task is solved now.
        :param collisions: The agent pairs overlapping now in each env.
        :return: Observations (of the new episode where one ended), rewards, dones and infos: ``agent_rewards``,
            ``agent_infos`` (``success``, ``is_success``, ``collisions``, ``episode_collisions``), ``is_success``
            (solved at some step of the episode), ``TimeLimit.truncated`` and, at an episode's end,
            ``terminal_observation``.
        """
        self.steps += 1
        self.success_ever |= success
        self.episode_collisions += collisions
        terminated = success & self.terminate_on_success
        truncated = (self.steps >= self.max_cycles) & ~terminated
        dones = terminated | truncated
        obs = self._observations()
        infos: list[dict[str, Any]] = []
        n_agents = self.agent_layout.n_agents
        for i in range(self.num_envs):
            agent_info = {
                "success": bool(success[i]),
                "is_success": bool(self.success_ever[i]),
                "collisions": int(collisions[i]),
                "episode_collisions": int(self.episode_collisions[i]),
            }
            info = {
                "agent_rewards": np.full(n_agents, rewards[i], dtype=np.float32),
                "agent_infos": {agent: agent_info for agent in self.agent_layout.agents},
                "is_success": bool(self.success_ever[i]),
                "TimeLimit.truncated": bool(truncated[i]),
            }
            if dones[i]:
                info["terminal_observation"] = obs[i].copy()  # (the row is overwritten by the reset below)
                self._reset_env(i)
            infos.append(info)
        if dones.any():
            obs[dones] = self._observations(dones)
        return obs, rewards.astype(np.float32), dones, infos
