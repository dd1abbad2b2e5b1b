"""
VMAS scenarios (PyTorch-vectorized multi-agent simulation, https://github.com/proroklab/VectorizedMultiAgentSimulator)
as an SB3 ``VecEnv`` with the joint spaces that :class:`~sb3_macb.MADDPG` trains on. Needs the ``vmas`` extra
(``pip install "sb3_macb[vmas]"``; VMAS brings the old ``gym`` package with it).

    from sb3_macb import MADDPG
    from sb3_macb.envs.vmas_env import make_vmas_env

    env = make_vmas_env("navigation", n_envs=1, max_steps=100, seed=0, n_agents=3)
    model = MADDPG("MlpPolicy", env, seed=0).learn(10_000)
"""

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv, VecMonitor

from sb3_macb.envs.batched import BatchedVecEnv
from sb3_macb.envs.joint_env import AgentLayout

TEAM_REWARDS = ("sum", "mean")


class VmasVecEnv(BatchedVecEnv):
    """
    One VMAS environment of ``n_envs`` parallel copies as an SB3 ``VecEnv``: the joint observation (each agent's,
    concatenated in VMAS's agent order), the joint continuous action (split back per agent), the team reward (sum or
    mean of the agents' rewards) and, in each env's info, ``agent_rewards`` (every agent's own reward),
    ``TimeLimit.truncated`` (the episode reached ``max_steps`` without ending) and, when an episode ends,
    ``terminal_observation``; that env is then reset, as SB3's VecEnvs do. The joint spaces and ``agent_layout``
    are what :func:`~sb3_macb.make_joint_env` gives a PettingZoo env, so MADDPG, MACB and packs (one env per run)
    work unchanged.

    VMAS draws its random numbers (initial positions) from one generator of its own, shared by all VMAS envs of
    the process: a seed makes a run reproducible, but the runs of a pack are not each equal to their solo run as
    they are on the package's own tasks.

    :param env: A VMAS ``Environment`` made with ``continuous_actions=True`` and ``terminated_truncated=True``.
    :param team_reward: The scalar reward: ``"sum"`` of the agents' rewards (as :func:`~sb3_macb.make_joint_env`)
        or their ``"mean"``.
    """

    def __init__(self, env: Any, team_reward: str = "sum"):
        if team_reward not in TEAM_REWARDS:
            raise ValueError(f"team_reward must be one of {TEAM_REWARDS}, got {team_reward!r}")
        if not env.continuous_actions or not env.terminated_truncated:
            raise ValueError("VmasVecEnv needs a VMAS env made with continuous_actions=True and terminated_truncated=True")
        self.env = env
        self.team_reward = team_reward
        agents = [agent.name for agent in env.agents]
        obs_spaces, action_spaces = list(env.observation_space.spaces), list(env.action_space.spaces)
        if any(len(space.shape) != 1 for space in [*obs_spaces, *action_spaces]):
            raise ValueError("VmasVecEnv takes scenarios whose observations and actions are flat vectors")
        self.agent_layout = AgentLayout(
            tuple(agents), tuple(int(s.shape[0]) for s in obs_spaces), tuple(int(s.shape[0]) for s in action_spaces)
        )
        low = np.concatenate([np.asarray(s.low, dtype=np.float32) for s in action_spaces])
        high = np.concatenate([np.asarray(s.high, dtype=np.float32) for s in action_spaces])
        obs_space = spaces.Box(-np.inf, np.inf, (self.agent_layout.obs_dim,), dtype=np.float32)
        self.render_mode = None
        super().__init__(env.num_envs, obs_space, spaces.Box(low, high, dtype=np.float32))
        self._splits = np.cumsum(self.agent_layout.action_dims)[:-1]
        self._actions = None

    def _joint(self, per_agent: Sequence[Any]) -> np.ndarray:
        return np.concatenate([o.detach().cpu().numpy() for o in per_agent], axis=-1).astype(np.float32)

    def reset(self) -> np.ndarray:
        seeds = [s for s in self._seeds if s is not None]
        if seeds:  # (VMAS seeds its one generator, not each env)
            self.env.seed(seeds[0])
        self._reset_seeds()
        self._reset_options()
        return self._joint(self.env.reset())

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        import torch as th

        actions = self._joint_actions()
        per_agent = [th.as_tensor(a, device=self.env.device) for a in np.split(actions, self._splits, axis=1)]
        observations, rewards, terminated, truncated, _ = self.env.step(per_agent)
        obs = self._joint(observations)
        agent_rewards = np.stack([r.detach().cpu().numpy() for r in rewards], axis=1).astype(np.float32)
        team = agent_rewards.sum(axis=1) if self.team_reward == "sum" else agent_rewards.mean(axis=1)
        terminated = terminated.detach().cpu().numpy().astype(bool)
        truncated = truncated.detach().cpu().numpy().astype(bool) & ~terminated
        dones = terminated | truncated
        infos: list[dict[str, Any]] = []
        for i in range(self.num_envs):
            info: dict[str, Any] = {"agent_rewards": agent_rewards[i], "TimeLimit.truncated": bool(truncated[i])}
            if dones[i]:
                info["terminal_observation"] = obs[i].copy()
                obs[i] = self._joint([o[i] for o in self.env.reset_at(i)])
            infos.append(info)
        return obs, team.astype(np.float32), dones, infos


def make_vmas_env(
    scenario: str,
    n_envs: int = 1,
    max_steps: int = 100,
    seed: int | None = None,
    team_reward: str = "sum",
    monitor: bool = True,
    **scenario_kwargs: Any,
) -> VecEnv:
    """
    A VMAS scenario as an SB3 ``VecEnv`` of ``n_envs`` parallel copies on the CPU (see :class:`VmasVecEnv`), with
    SB3's ``VecMonitor`` (episode returns and lengths). For a pack of ``K`` runs, ``n_envs = K``.

    :param scenario: A VMAS scenario name (e.g. ``"navigation"``, ``"balance"``, ``"discovery"``).
    :param n_envs: Parallel copies.
    :param max_steps: Steps after which an episode is cut (a truncation: bootstrapped).
    :param seed: Seed of VMAS's generator.
    :param team_reward: ``"sum"`` or ``"mean"`` of the agents' rewards.
    :param monitor: Wrap with ``VecMonitor``.
    :param scenario_kwargs: The scenario's own options (e.g. ``n_agents=3``).
    """
    try:
        import vmas
    except ImportError:
        raise ImportError('VMAS is not installed: pip install "sb3_macb[vmas]"') from None
    if n_envs < 1 or max_steps < 1:
        raise ValueError(f"n_envs and max_steps must be >= 1, got {n_envs} and {max_steps}")
    env = vmas.make_env(
        scenario,
        num_envs=n_envs,
        device="cpu",
        continuous_actions=True,
        seed=seed,
        max_steps=max_steps,
        terminated_truncated=True,
        **scenario_kwargs,
    )
    vec_env = VmasVecEnv(env, team_reward=team_reward)
    return VecMonitor(vec_env) if monitor else vec_env
