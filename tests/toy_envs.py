"""Small PettingZoo parallel environments for the tests."""

import functools
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv


class Rendezvous(ParallelEnv):
    """
    Two agents on a line must both reach the origin (cooperative, shared reward -(p0^2 + p1^2)).

    The agents differ on purpose: ``a`` observes its position (1 value) and acts in [-1, 1] (1 value); ``b``
    observes its position and a constant (2 values) and acts in [-0.5, 0.5]^2, moving by twice its first
    component. ``is_success`` is reported at every step (both agents within 0.1 of the origin).

    Switches for error tests: ``nan_obs_step``, ``nan_reward_step``, ``disappear_step`` (agent ``b`` ends its
    episode alone), ``drop_agent_step`` (agent ``b`` is missing from the returned dicts), ``dict_obs``,
    ``multi_discrete`` (agent ``a`` has a MultiDiscrete action space). With ``discrete``, agent ``a`` chooses among
    Discrete(3) moves (-1, 0, +1 times 0.2) and ``b`` stays continuous (a mixed env).
    """

    metadata = {"render_modes": [], "name": "rendezvous_v0"}

    def __init__(
        self,
        max_steps: int = 10,
        nan_obs_step: int | None = None,
        nan_reward_step: int | None = None,
        disappear_step: int | None = None,
        drop_agent_step: int | None = None,
        discrete: bool = False,
        dict_obs: bool = False,
        terminate_on_success: bool = False,
        multi_discrete: bool = False,
    ):
        self.multi_discrete = multi_discrete
        self.possible_agents = ["a", "b"]
        self.agents: list[str] = []
        self.max_steps = max_steps
        self.nan_obs_step = nan_obs_step
        self.nan_reward_step = nan_reward_step
        self.disappear_step = disappear_step
        self.drop_agent_step = drop_agent_step
        self.discrete = discrete
        self.dict_obs = dict_obs
        self.terminate_on_success = terminate_on_success
        self.pos = np.zeros(2)
        self.t = 0
        self.rng = np.random.default_rng()

    @functools.cache  # noqa: B019 (a few envs per test: the cache keeping them alive is harmless)
    def observation_space(self, agent: str) -> spaces.Space:
        if self.dict_obs:
            return spaces.Dict({"pos": spaces.Box(-2, 2, (1,), np.float32)})
        return spaces.Box(-2, 2, (1,) if agent == "a" else (2,), np.float32)

    @functools.cache  # noqa: B019 (a few envs per test: the cache keeping them alive is harmless)
    def action_space(self, agent: str) -> spaces.Space:
        if self.multi_discrete and agent == "a":
            return spaces.MultiDiscrete([3, 2])
        if self.discrete and agent == "a":
            return spaces.Discrete(3)
        if agent == "a":
            return spaces.Box(-1, 1, (1,), np.float32)
        return spaces.Box(-0.5, 0.5, (2,), np.float32)

    def _obs(self) -> dict[str, Any]:
        nan = self.nan_obs_step is not None and self.t >= self.nan_obs_step
        pa = np.nan if nan else self.pos[0]
        return {
            "a": np.array([pa], dtype=np.float32),
            "b": np.array([self.pos[1], 0.5], dtype=np.float32),
        }

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self.agents = list(self.possible_agents)
        self.pos = self.rng.uniform(-1, 1, size=2)
        self.t = 0
        return self._obs(), {agent: {} for agent in self.agents}

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        self.t += 1
        if self.discrete:
            assert isinstance(actions["a"], (int, np.integer)), actions["a"]  # the env receives an int
            move_a = float(actions["a"]) - 1.0
        else:
            move_a = float(np.asarray(actions["a"]).ravel()[0])
        self.pos[0] = np.clip(self.pos[0] + 0.2 * move_a, -2, 2)
        self.pos[1] = np.clip(self.pos[1] + 0.4 * float(np.asarray(actions["b"]).ravel()[0]), -2, 2)
        reward = -float(np.sum(self.pos**2))
        if self.nan_reward_step is not None and self.t >= self.nan_reward_step:
            reward = float("nan")
        success = bool(np.all(np.abs(self.pos) < 0.1))
        terminated = self.terminate_on_success and success
        truncated = self.t >= self.max_steps and not terminated
        obs = self._obs()
        rewards = {agent: reward for agent in self.agents}
        terms = {agent: terminated for agent in self.agents}
        truncs = {agent: truncated for agent in self.agents}
        infos = {agent: {"is_success": success} for agent in self.agents}
        if self.disappear_step is not None and self.t >= self.disappear_step:
            terms["b"] = True
        if self.drop_agent_step is not None and self.t >= self.drop_agent_step:
            for d in (obs, rewards, terms, truncs, infos):
                d.pop("b")
        if terminated or truncated:
            self.agents = []
        return obs, rewards, terms, truncs, infos
