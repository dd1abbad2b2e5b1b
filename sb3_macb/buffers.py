"""Replay buffers of sb3_macb: per-agent rewards, and (in ``exploration``) MACB's count bonus added at sampling."""

from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from stable_baselines3.common.vec_env import VecNormalize

from sb3_macb.exploration.macb import MACB


class MultiAgentReplayBuffer(ReplayBuffer):
    """
    SB3's ``ReplayBuffer`` that also stores every agent's own reward (``info["agent_rewards"]`` of the joint env).

    ``sample()`` returns SB3's ``ReplayBufferSamples`` whose ``rewards`` has shape ``(batch_size, n_agents)``:
    column ``i`` is agent ``i``'s reward, which its critic learns from. The team reward (sum) stays in
    ``self.rewards`` as in SB3.

    :param buffer_size: Max number of elements in the buffer.
    :param observation_space: Joint observation space.
    :param action_space: Joint action space.
    :param device: PyTorch device.
    :param n_envs: Number of parallel environments.
    :param optimize_memory_usage: SB3's memory efficient variant (see ``ReplayBuffer``).
    :param handle_timeout_termination: Bootstrap at time-limit ends (``TimeLimit.truncated``).
    :param n_agents: Number of agents (set by MADDPG from the env).
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        n_agents: int = 1,
    ):
        super().__init__(
            buffer_size,
            observation_space,
            action_space,
            device=device,
            n_envs=n_envs,
            optimize_memory_usage=optimize_memory_usage,
            handle_timeout_termination=handle_timeout_termination,
        )
        self.n_agents = n_agents
        self.agent_rewards = np.zeros((self.buffer_size, self.n_envs, n_agents), dtype=np.float32)

    def add(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        pos = self.pos
        try:
            self.agent_rewards[pos] = [info["agent_rewards"] for info in infos]
        except KeyError as exc:
            raise KeyError(
                "info['agent_rewards'] is missing: the env must be a joint multi-agent env (sb3_macb.make_joint_env)"
            ) from exc
        super().add(obs, next_obs, action, reward, done, infos)

    def _sample_env_indices(self, n: int) -> np.ndarray | int:
        return 0 if self.n_envs == 1 else np.random.randint(0, high=self.n_envs, size=(n,))

    def _get_samples(self, batch_inds: np.ndarray, env: VecNormalize | None = None) -> ReplayBufferSamples:
        env_indices = self._sample_env_indices(len(batch_inds))
        return self._samples_at(batch_inds, env_indices, self.agent_rewards[batch_inds, env_indices], env)

    def _samples_at(
        self,
        batch_inds: np.ndarray,
        env_indices: np.ndarray | int,
        agent_rewards: np.ndarray,
        env: VecNormalize | None = None,
    ) -> ReplayBufferSamples:
        if self.optimize_memory_usage:
            next_obs = self.observations[(batch_inds + 1) % self.buffer_size, env_indices, :]
        else:
            next_obs = self.next_observations[batch_inds, env_indices, :]
        dones = self.dones[batch_inds, env_indices] * (1 - self.timeouts[batch_inds, env_indices])
        data = (
            self._normalize_obs(self.observations[batch_inds, env_indices, :], env),
            self.actions[batch_inds, env_indices, :],
            self._normalize_obs(next_obs, env),
            dones.reshape(-1, 1),
            self._normalize_reward(agent_rewards, env),
        )
        return ReplayBufferSamples(*tuple(map(self.to_torch, data)))


class MACBReplayBuffer(MultiAgentReplayBuffer):
    """
    Multi-agent replay buffer with MACB's count-based bonus.

    ``add()`` hashes the transition's observation and (stored, scaled) action, counts the code in the MACB table
    and stores the code's key beside the transition. ``sample()`` returns the stored per-agent rewards plus
    ``beta / sqrt(n)``, ``n`` being the key's current count (>= 1, since it was counted when added). Stored rewards
    never change and sampling never changes a count.

    :param buffer_size: Max number of elements in the buffer.
    :param observation_space: Joint observation space.
    :param action_space: Joint action space.
    :param device: PyTorch device.
    :param n_envs: Number of parallel environments.
    :param optimize_memory_usage: SB3's memory efficient variant (see ``ReplayBuffer``).
    :param handle_timeout_termination: Bootstrap at time-limit ends (``TimeLimit.truncated``).
    :param n_agents: Number of agents (set by MADDPG from the env).
    :param exploration: The MACB object holding the hash functions and count tables (set by MADDPG).
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        n_agents: int = 1,
        exploration: "MACB | None" = None,
    ):
        if exploration is None or not exploration.is_setup:
            raise ValueError("MACBReplayBuffer needs a set-up MACB object (MADDPG passes model.exploration)")
        super().__init__(
            buffer_size,
            observation_space,
            action_space,
            device=device,
            n_envs=n_envs,
            optimize_memory_usage=optimize_memory_usage,
            handle_timeout_termination=handle_timeout_termination,
            n_agents=n_agents,
        )
        self.exploration: MACB | None = exploration
        self.hash_keys = np.zeros((self.buffer_size, self.n_envs, exploration.n_tables), dtype=np.uint64)
        self.bonus_sum = 0.0
        self.bonus_n = 0

    def add(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        assert self.exploration is not None, "MACBReplayBuffer has no MACB attached"
        keys = self.exploration.keys(
            np.asarray(obs).reshape(self.n_envs, -1), np.asarray(action).reshape(self.n_envs, self.action_dim)
        )
        pos = self.pos
        super().add(obs, next_obs, action, reward, done, infos)
        self.hash_keys[pos] = keys
        self.exploration.count(keys)

    def _get_samples(self, batch_inds: np.ndarray, env: VecNormalize | None = None) -> ReplayBufferSamples:
        assert self.exploration is not None, "MACBReplayBuffer has no MACB attached"
        env_indices = self._sample_env_indices(len(batch_inds))
        bonus = self.exploration.bonus(self.hash_keys[batch_inds, env_indices])  # (batch, 1 or n_agents)
        self.bonus_sum += float(bonus.sum()) / bonus.shape[1]
        self.bonus_n += len(bonus)
        rewards = self.agent_rewards[batch_inds, env_indices] + bonus
        return self._samples_at(batch_inds, env_indices, rewards, env)

    def pop_mean_bonus(self) -> float | None:
        """Mean bonus of the transitions sampled since the last call (None if none were sampled)."""
        if self.bonus_n == 0:
            return None
        mean = self.bonus_sum / self.bonus_n
        self.bonus_sum, self.bonus_n = 0.0, 0
        return mean

    def __getstate__(self) -> dict[str, Any]:
        # The count tables belong to the model (saved with it); MADDPG re-attaches them on load_replay_buffer
        state = self.__dict__.copy()
        state["exploration"] = None
        return state
