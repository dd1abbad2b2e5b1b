"""Replay buffers of sb3_macb: per-agent rewards, and (in ``exploration``) MACB's count bonus added at sampling."""

from typing import Any, NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from stable_baselines3.common.vec_env import VecNormalize

from sb3_macb.exploration.macb import MACB
from sb3_macb.exploration.rnd import RND


class RunSamples(NamedTuple):
    """One minibatch per run of a pack: every tensor has the runs on its first axis."""

    observations: th.Tensor  # (n_runs, batch, obs_dim)
    actions: th.Tensor  # (n_runs, batch, action_dim)
    next_observations: th.Tensor  # (n_runs, batch, obs_dim)
    dones: th.Tensor  # (n_runs, batch): 1 where the episode terminated (time-limit ends excluded)
    rewards: th.Tensor  # (n_runs, batch, n_agents): each agent's reward (plus MACB's bonus, unless separate)
    bonus: th.Tensor | None = None  # (n_runs, batch, n_agents): the bonus alone, when asked for separately


class MultiAgentReplayBuffer(ReplayBuffer):
    """
    SB3's ``ReplayBuffer`` that also stores every agent's own reward (``info["agent_rewards"]`` of the joint env).

    ``buffer_size`` is what each run holds: SB3 divides it by the number of envs, so a solo run with ``n_envs`` envs
    keeps ``buffer_size // n_envs`` rows per env; a pack of ``n_runs`` runs allocates ``n_runs * buffer_size``
    transitions, so that every run of the pack keeps exactly as many rows as it would alone.

    ``sample()`` returns SB3's ``ReplayBufferSamples`` whose ``rewards`` has shape ``(batch_size, n_agents)``:
    column ``i`` is agent ``i``'s reward, which its critic learns from. The team reward (sum) stays in
    ``self.rewards`` as in SB3.

    :param buffer_size: Max number of transitions of each run (of all its envs together, as in SB3).
    :param observation_space: Joint observation space.
    :param action_space: Joint action space.
    :param device: PyTorch device.
    :param n_envs: Number of parallel environments (of all runs).
    :param optimize_memory_usage: SB3's memory efficient variant (see ``ReplayBuffer``).
    :param handle_timeout_termination: Bootstrap at time-limit ends (``TimeLimit.truncated``).
    :param n_agents: Number of agents (set by MADDPG from the env).
    :param n_runs: Independent runs sharing the buffer (a pack): the envs are split between them in order, and
        :meth:`sample_runs` draws each run's minibatch from its own envs' columns only.
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
        n_runs: int = 1,
    ):
        if n_runs < 1 or n_envs % n_runs:
            raise ValueError(f"The {n_envs} envs cannot be split evenly between {n_runs} runs")
        if isinstance(buffer_size, bool) or not isinstance(buffer_size, (int, np.integer)) or buffer_size < 1:
            raise ValueError(f"buffer_size must be an integer >= 1, got {buffer_size!r}")
        super().__init__(
            int(buffer_size) * n_runs,  # SB3 keeps (n_runs * buffer_size) // n_envs = buffer_size // envs_per_run rows
            observation_space,
            action_space,
            device=device,
            n_envs=n_envs,
            optimize_memory_usage=optimize_memory_usage,
            handle_timeout_termination=handle_timeout_termination,
        )
        self.n_agents = n_agents
        self.n_runs = n_runs
        self.envs_per_run = n_envs // n_runs
        self.agent_rewards = np.zeros((self.buffer_size, self.n_envs, n_agents), dtype=np.float32)

    @property
    def buffer_size_per_run(self) -> int:
        """Transitions each run holds when full (rows per env times the run's envs)."""
        return self.buffer_size * self.envs_per_run

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

    def sample_runs(
        self, batch_size: int, rngs: list[np.random.Generator], env: VecNormalize | None = None, separate_bonus: bool = False
    ) -> RunSamples:
        """
        One minibatch of ``batch_size`` transitions per run, each drawn with the run's own generator from its own
        envs' columns, so that a run samples the same minibatches whether it is trained alone or in a pack.

        :param batch_size: Transitions per run.
        :param rngs: One generator per run.
        :param env: VecNormalize wrapper to normalize observations and rewards with, if any.
        :param separate_bonus: Return the exploration bonus in ``bonus`` instead of adding it to ``rewards``.
        """
        if len(rngs) != self.n_runs:
            raise ValueError(f"Expected one generator per run ({self.n_runs}), got {len(rngs)}")
        if self.optimize_memory_usage:
            raise NotImplementedError("sb3_macb's per-run sampling does not support optimize_memory_usage")
        upper = self.buffer_size if self.full else self.pos
        batch_inds = np.empty((self.n_runs, batch_size), dtype=np.int64)
        env_inds = np.empty((self.n_runs, batch_size), dtype=np.int64)
        for run, rng in enumerate(rngs):
            batch_inds[run] = rng.integers(0, upper, size=batch_size)
            first = run * self.envs_per_run
            env_inds[run] = first if self.envs_per_run == 1 else first + rng.integers(0, self.envs_per_run, size=batch_size)
        bonus = self._bonus(batch_inds, env_inds)
        rewards = self.agent_rewards[batch_inds, env_inds]
        if not separate_bonus:
            rewards = rewards + bonus
        dones = self.dones[batch_inds, env_inds] * (1 - self.timeouts[batch_inds, env_inds])
        data = (
            self._normalize_obs(self.observations[batch_inds, env_inds], env),
            self.actions[batch_inds, env_inds],
            self._normalize_obs(self.next_observations[batch_inds, env_inds], env),
            dones,
            self._normalize_reward(rewards, env),
        )
        samples = RunSamples(*tuple(map(self.to_torch, data)))
        if separate_bonus:
            shape = (self.n_runs, batch_size, self.n_agents)
            samples = samples._replace(bonus=self.to_torch(np.broadcast_to(bonus, shape).astype(np.float32)))
        return samples

    def _bonus(self, batch_inds: np.ndarray, env_inds: np.ndarray) -> np.ndarray | float:
        """Exploration bonus added to sampled rewards: none here (see :class:`MACBReplayBuffer`)."""
        return 0.0

    # --- checkpoints: the filled part of the arrays, not the whole preallocated buffer --------------------------

    _array_names: tuple[str, ...] = (
        "observations", "next_observations", "actions", "rewards", "dones", "timeouts", "agent_rewards"
    )  # fmt: skip

    def state_arrays(self) -> dict[str, np.ndarray]:
        """The stored transitions (the filled rows only) and the write position, for a checkpoint."""
        rows = self.buffer_size if self.full else self.pos
        arrays = {name: getattr(self, name)[:rows] for name in self._array_names if getattr(self, name) is not None}
        arrays["_position"] = np.array([self.pos, int(self.full), self.buffer_size, self.n_envs], dtype=np.int64)
        return arrays

    def load_state_arrays(self, arrays: Any) -> None:
        """Restore what :meth:`state_arrays` returned (into a buffer of the same size and number of envs)."""
        if "_position" not in arrays or np.shape(arrays["_position"]) != (4,):
            raise ValueError("the saved replay buffer has no '_position' array of 4 integers")
        pos, full, size, n_envs = (int(v) for v in arrays["_position"])
        if (size, n_envs) != (self.buffer_size, self.n_envs):
            raise ValueError(
                f"The saved replay buffer has size {size} with {n_envs} envs; "
                f"this one has {self.buffer_size} and {self.n_envs}"
            )
        if not (0 <= pos < size or (pos == size and not full)):
            raise ValueError(f"the saved replay buffer's write position {pos} lies outside its {size} rows")
        rows = size if full else pos
        for name in self._array_names:  # every array, whole: a missing or short one is an error, not zeros
            mine = getattr(self, name)
            if mine is None:
                continue
            if name not in arrays:
                raise ValueError(f"the saved replay buffer has no '{name}' array")
            saved = arrays[name]
            if saved.shape != (rows, *mine.shape[1:]):
                raise ValueError(
                    f"the saved replay buffer's '{name}' has shape {saved.shape}, expected {(rows, *mine.shape[1:])}"
                )
        for name in self._array_names:
            if getattr(self, name) is not None:
                getattr(self, name)[:rows] = arrays[name]
        self.pos, self.full = pos, bool(full)

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

    ``add()`` hashes the transition's observation and (stored, scaled) action, counts the code in its run's MACB
    table and stores the code's key beside the transition. Sampling returns the stored per-agent rewards plus
    ``beta / sqrt(n)``, ``n`` being the key's current count (>= 1, since it was counted when added). Stored rewards
    never change and sampling never changes a count. In a pack every run has its own MACB (or none).

    :param buffer_size: Max number of elements in the buffer.
    :param observation_space: Joint observation space.
    :param action_space: Joint action space.
    :param device: PyTorch device.
    :param n_envs: Number of parallel environments.
    :param optimize_memory_usage: SB3's memory efficient variant (see ``ReplayBuffer``).
    :param handle_timeout_termination: Bootstrap at time-limit ends (``TimeLimit.truncated``).
    :param n_agents: Number of agents (set by MADDPG from the env).
    :param n_runs: Independent runs sharing the buffer (set by MADDPG).
    :param exploration: The MACB object holding the hash functions and count tables (set by MADDPG), or a list
        of one MACB (or None) per run.
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
        n_runs: int = 1,
        exploration: "MACB | RND | list[MACB | RND | None] | None" = None,
    ):
        explorations = exploration if isinstance(exploration, list) else [exploration]
        if len(explorations) != n_runs or not any(e is not None for e in explorations):
            raise ValueError("MACBReplayBuffer needs one set-up MACB (or None) per run (MADDPG passes them)")
        if any(e is not None and not e.is_setup for e in explorations):
            raise ValueError("MACBReplayBuffer needs set-up MACB objects (MADDPG passes model.exploration)")
        super().__init__(
            buffer_size,
            observation_space,
            action_space,
            device=device,
            n_envs=n_envs,
            optimize_memory_usage=optimize_memory_usage,
            handle_timeout_termination=handle_timeout_termination,
            n_agents=n_agents,
            n_runs=n_runs,
        )
        self.explorations: list[MACB | RND | None] = explorations
        n_tables = max(e.n_tables for e in explorations if e is not None)
        self.hash_keys = np.zeros((self.buffer_size, self.n_envs, n_tables), dtype=np.uint64)
        self.bonus_sum = 0.0
        self.bonus_n = 0

    _array_names = (*MultiAgentReplayBuffer._array_names, "hash_keys")

    @property
    def exploration(self) -> "MACB | RND | None":
        """The MACB of a single run."""
        return self.explorations[0]

    @exploration.setter
    def exploration(self, value: "MACB | RND | list[MACB | RND | None] | None") -> None:
        self.explorations = value if isinstance(value, list) else [value]

    def add(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        if not self.explorations or len(self.explorations) != self.n_runs:
            raise RuntimeError("MACBReplayBuffer has no MACB attached (MADDPG attaches it)")
        obs = np.asarray(obs).reshape(self.n_envs, -1)
        action = np.asarray(action).reshape(self.n_envs, self.action_dim)
        pos = self.pos
        super().add(obs, next_obs, action, reward, done, infos)
        step = self.envs_per_run
        for run, exploration in enumerate(self.explorations):
            if exploration is None:
                continue
            envs = slice(run * step, (run + 1) * step)
            keys = exploration.keys(obs[envs], action[envs])
            self.hash_keys[pos, envs, : keys.shape[1]] = keys
            exploration.count(keys)

    def _bonus(self, batch_inds: np.ndarray, env_inds: np.ndarray) -> np.ndarray:
        """(n_runs, batch, n_agents) bonus from each run's current counts; 0 for runs without MACB."""
        n_runs, batch = batch_inds.shape
        bonus = np.zeros((n_runs, batch, self.n_agents), dtype=np.float32)
        for run, exploration in enumerate(self.explorations):
            if exploration is not None:
                keys = self.hash_keys[batch_inds[run], env_inds[run], : exploration.n_tables]
                if getattr(exploration, "uses_observations", False):  # (RND: the minibatch's observations)
                    rnd: Any = exploration
                    run_bonus = rnd.bonus(keys, observations=self.observations[batch_inds[run], env_inds[run]])
                else:
                    run_bonus = exploration.bonus(keys)  # (batch, 1): shared by all agents; (batch, n_agents): local
                bonus[run] = run_bonus
                self.bonus_sum += float(run_bonus.sum()) / exploration.n_tables
                self.bonus_n += batch
        return bonus

    def _get_samples(self, batch_inds: np.ndarray, env: VecNormalize | None = None) -> ReplayBufferSamples:
        if self.n_runs != 1:
            raise RuntimeError("A pack's buffer is sampled run by run (sample_runs)")
        env_indices = self._sample_env_indices(len(batch_inds))
        env_inds = np.broadcast_to(np.asarray(env_indices), batch_inds.shape)[None]
        rewards = self.agent_rewards[batch_inds, env_indices] + self._bonus(batch_inds[None], env_inds)[0]
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
        state["explorations"] = []
        return state
