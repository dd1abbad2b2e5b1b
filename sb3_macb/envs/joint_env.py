"""A PettingZoo parallel environment seen by Stable-Baselines3 as one gymnasium environment."""

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from pettingzoo.utils.env import AECEnv, ParallelEnv


@dataclass(frozen=True)
class AgentLayout:
    """
    How the joint observation and joint action vectors are split between agents.

    Plain data (names and sizes), so it is pickled with a saved model and compared at load time.

    :param agents: Agent names, in ``possible_agents`` order.
    :param obs_dims: Size of each agent's (flattened) observation.
    :param action_dims: Size of each agent's action (for a ``Discrete(n)`` agent: n, its one-hot action).
    :param discrete: Whether each agent's action space is ``Discrete`` (empty: every agent is continuous).
    """

    agents: tuple[str, ...]
    obs_dims: tuple[int, ...]
    action_dims: tuple[int, ...]
    discrete: tuple[bool, ...] = ()

    def __post_init__(self) -> None:
        if not (len(self.agents) == len(self.obs_dims) == len(self.action_dims)) or len(self.agents) == 0:
            raise ValueError(f"Invalid agent layout: {self}")
        if self.discrete and len(self.discrete) != len(self.agents):
            raise ValueError(f"Invalid agent layout (one discrete flag per agent): {self}")

    @property
    def discrete_agents(self) -> tuple[bool, ...]:
        """For each agent, whether its actions are discrete (layouts saved before discrete actions have none)."""
        flags = self.__dict__.get("discrete") or ()
        return tuple(bool(f) for f in flags) if flags else (False,) * len(self.agents)

    @property
    def discrete_action_mask(self) -> np.ndarray:
        """(action_dim,) bool: the joint action's entries that belong to discrete agents' one-hot actions."""
        mask = np.zeros(self.action_dim, dtype=bool)
        for sl, flag in zip(self.action_slices, self.discrete_agents):
            mask[sl] = flag
        return mask

    @property
    def n_agents(self) -> int:
        return len(self.agents)

    @property
    def obs_dim(self) -> int:
        return int(sum(self.obs_dims))

    @property
    def action_dim(self) -> int:
        return int(sum(self.action_dims))

    @staticmethod
    def _slices(dims: tuple[int, ...]) -> list[slice]:
        ends = np.cumsum(dims)
        return [slice(int(end - dim), int(end)) for dim, end in zip(dims, ends)]

    @property
    def obs_slices(self) -> list[slice]:
        """Slice of each agent's observation inside the joint observation."""
        return self._slices(self.obs_dims)

    @property
    def action_slices(self) -> list[slice]:
        """Slice of each agent's action inside the joint action."""
        return self._slices(self.action_dims)


def is_pettingzoo_env(env: Any) -> bool:
    """Whether ``env`` is a PettingZoo parallel or AEC environment (possibly wrapped)."""
    return isinstance(env, (ParallelEnv, AECEnv)) or (hasattr(env, "possible_agents") and hasattr(env, "observation_space"))


class JointEnv(gym.Env):
    """
    A PettingZoo ``ParallelEnv`` with continuous (``Box``) or ``Discrete`` actions, seen as one gymnasium env.

    - observation: every agent's observation flattened and concatenated, in ``possible_agents`` order;
    - action: every agent's action concatenated, each agent keeping its own bounds; a ``Discrete(n)`` agent's action
      is n entries in [0, 1] (a one-hot vector, or any scores) and the env receives their argmax as an int;
    - reward: the sum of the agents' rewards (or their mean, with ``team_reward="mean"``: for tasks where every
      agent receives the same shared reward, the mean is that reward, not N times it); the per-agent rewards are in
      ``info["agent_rewards"]``
      (a float32 array in agent order), and each agent's own info dict in ``info["agent_infos"]``;
    - ``terminated`` and ``truncated`` are kept apart, so that time-limit ends bootstrap;
    - ``info["is_success"]`` is passed on where the agents' infos carry one (true when every agent that reports
      one reports success).

    All agents must live for the whole episode (the centralized critic needs every agent's observation and
    action at every step). The agent layout is ``self.agent_layout``.

    :param env: PettingZoo ``ParallelEnv`` (an ``AECEnv`` is converted with ``aec_to_parallel``).
    :param check_finite: Raise an error when an observation or a reward is NaN or infinite.
    :param team_reward: How the scalar reward combines the agents' rewards: ``"sum"`` or ``"mean"``.
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, env: ParallelEnv | AECEnv, check_finite: bool = True, team_reward: str = "sum"):
        super().__init__()
        if team_reward not in ("sum", "mean"):
            raise ValueError(f"team_reward must be 'sum' or 'mean', got {team_reward!r}")
        self.team_reward = team_reward
        if isinstance(env, AECEnv):
            from pettingzoo.utils.conversions import aec_to_parallel

            env = aec_to_parallel(env)
        if not is_pettingzoo_env(env):
            raise TypeError(f"make_joint_env expects a PettingZoo ParallelEnv or AECEnv, got {type(env).__name__}")
        self.par_env = env
        self.check_finite = check_finite
        agents = tuple(env.possible_agents)
        if len(agents) == 0:
            raise ValueError("The PettingZoo environment has no agents (possible_agents is empty)")

        obs_spaces, act_spaces, discrete = [], [], []
        for agent in agents:
            obs_space, act_space = env.observation_space(agent), env.action_space(agent)
            if isinstance(act_space, spaces.Discrete):
                if act_space.start != 0:
                    raise TypeError(f"Agent '{agent}' has {act_space} with start={act_space.start}; sb3_macb needs start=0")
                act_space = spaces.Box(0.0, 1.0, (int(act_space.n),), dtype=np.float32)  # one-hot, argmax to the env
                discrete.append(True)
            elif isinstance(act_space, spaces.Box):
                discrete.append(False)
            else:
                raise TypeError(
                    f"Agent '{agent}' has a {type(act_space).__name__} action space; sb3_macb (MADDPG) supports Box and "
                    "Discrete action spaces (for MultiDiscrete, split the agent's choices or flatten them into one Discrete)."
                )
            if not isinstance(obs_space, spaces.Box):
                raise TypeError(
                    f"Agent '{agent}' has a {type(obs_space).__name__} observation space; sb3_macb needs Box observation "
                    "spaces (flatten or preprocess the observation first, e.g. with a SuperSuit wrapper)."
                )
            if not (np.all(np.isfinite(act_space.low)) and np.all(np.isfinite(act_space.high))):
                raise ValueError(f"Agent '{agent}' has an unbounded action space {act_space}; MADDPG needs finite bounds.")
            obs_spaces.append(obs_space)
            act_spaces.append(act_space)

        self.agent_layout = AgentLayout(
            agents=agents,
            obs_dims=tuple(int(np.prod(s.shape)) for s in obs_spaces),
            action_dims=tuple(int(np.prod(s.shape)) for s in act_spaces),
            discrete=tuple(discrete) if any(discrete) else (),
        )
        self._obs_shapes = [s.shape for s in obs_spaces]
        self._act_shapes = [s.shape for s in act_spaces]
        self.observation_space = spaces.Box(
            low=np.concatenate([s.low.ravel() for s in obs_spaces]).astype(np.float32),
            high=np.concatenate([s.high.ravel() for s in obs_spaces]).astype(np.float32),
            dtype=np.float32,
        )
        self.action_space = spaces.Box(
            low=np.concatenate([s.low.ravel() for s in act_spaces]).astype(np.float32),
            high=np.concatenate([s.high.ravel() for s in act_spaces]).astype(np.float32),
            dtype=np.float32,
        )
        self.render_mode = getattr(env, "render_mode", None)
        self.metadata = dict(getattr(env, "metadata", {}) or {})
        self._action_slices = self.agent_layout.action_slices

    def _joint_obs(self, observations: dict[str, Any]) -> np.ndarray:
        missing = [agent for agent in self.agent_layout.agents if agent not in observations]
        if missing:
            raise RuntimeError(
                f"Agent(s) {missing} disappeared mid-episode (no observation returned). sb3_macb needs every agent "
                "alive for the whole episode; end the episode for all agents at once instead."
            )
        obs = np.concatenate([np.asarray(observations[agent], dtype=np.float32).ravel() for agent in self.agent_layout.agents])
        if self.check_finite and not np.all(np.isfinite(obs)):
            bad = [
                agent
                for agent in self.agent_layout.agents
                if not np.all(np.isfinite(np.asarray(observations[agent], dtype=np.float32)))
            ]
            raise ValueError(f"NaN or infinite value in the observation of agent(s) {bad}")
        return obs

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        observations, infos = self.par_env.reset(seed=seed, options=options)
        return self._joint_obs(observations), {"agent_infos": infos}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        agents = self.agent_layout.agents
        action = np.asarray(action, dtype=np.float32).reshape(-1)
        if action.shape[0] != self.agent_layout.action_dim:
            raise ValueError(f"Expected a joint action of size {self.agent_layout.action_dim}, got {action.shape[0]}")
        actions = {
            agent: int(np.argmax(action[sl])) if flag else action[sl].reshape(shape)
            for agent, sl, shape, flag in zip(agents, self._action_slices, self._act_shapes, self.agent_layout.discrete_agents)
        }
        observations, rewards, terminations, truncations, infos = self.par_env.step(actions)

        obs = self._joint_obs(observations)
        missing = [agent for agent in agents if agent not in rewards]
        if missing:
            raise RuntimeError(f"Agent(s) {missing} disappeared mid-episode (no reward returned).")
        agent_rewards = np.array([rewards[agent] for agent in agents], dtype=np.float32)
        if self.check_finite and not np.all(np.isfinite(agent_rewards)):
            bad = [agent for agent, r in zip(agents, agent_rewards) if not np.isfinite(r)]
            raise ValueError(f"NaN or infinite reward for agent(s) {bad}")
        terms = [bool(terminations.get(agent, False)) for agent in agents]
        truncs = [bool(truncations.get(agent, False)) for agent in agents]
        ended = [t or u for t, u in zip(terms, truncs)]
        if any(ended) and not all(ended):
            gone = [agent for agent, e in zip(agents, ended) if e]
            raise RuntimeError(
                f"Agent(s) {gone} ended their episode while others continue (agents that disappear mid-episode are "
                "not supported by sb3_macb: the centralized critic needs all agents at every step)."
            )
        terminated = any(terms)
        truncated = any(truncs) and not terminated

        info: dict[str, Any] = {"agent_rewards": agent_rewards, "agent_infos": infos}
        successes = [
            infos[agent]["is_success"]
            for agent in agents
            if isinstance(infos.get(agent), dict) and "is_success" in infos[agent]
        ]
        if successes:
            info["is_success"] = bool(all(successes))
        reward = float(agent_rewards.sum() if self.team_reward == "sum" else agent_rewards.mean())
        return obs, reward, terminated, truncated, info

    def render(self) -> Any:
        return self.par_env.render()

    def close(self) -> None:
        self.par_env.close()


def make_joint_env(env: ParallelEnv | AECEnv, check_finite: bool = True, team_reward: str = "sum") -> JointEnv:
    """
    Turn a PettingZoo environment into a single gymnasium environment usable by SB3 and MADDPG.

    :param env: PettingZoo ``ParallelEnv`` or ``AECEnv`` with ``Box`` observation spaces and ``Box`` or ``Discrete``
        action spaces.
    :param check_finite: Raise an error when an observation or a reward is NaN or infinite.
    :param team_reward: The scalar reward: ``"sum"`` of the agents' rewards, or their ``"mean"`` (for a shared reward).
    :return: The joint environment (see :class:`JointEnv`).
    """
    return JointEnv(env, check_finite=check_finite, team_reward=team_reward)
