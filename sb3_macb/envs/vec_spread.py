"""
Sparse Spread as one vectorized SB3 ``VecEnv``: N copies of :mod:`sb3_macb.envs.sparse_spread_v0` stepped in
numpy arrays, with the same physics, observations, rewards and infos as the mpe2-based env (the tests compare
them step by step). :func:`sb3_macb.envs.scripted.scripted_actions` is its reference policy.

    from sb3_macb.envs.vec_tasks import make_task_vec_env
    venv = make_task_vec_env("sb3_macb/SparseSpread-v0", n_envs=10, env_kwargs={"n_agents": 6})
"""

import itertools
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding

from sb3_macb.envs.batched import ParticleVecEnv
from sb3_macb.envs.joint_env import AgentLayout
from sb3_macb.envs.task_constants import (
    CONTACT_FORCE,
    CONTACT_MARGIN,
    DAMPING,
    DT,
    FORCE_SCALE,
    SPREAD_AGENT_SIZE,
    SPREAD_COVER_RADIUS,
    SPREAD_MAX_CYCLES,
)


class SpreadVecEnv(ParticleVecEnv):
    """
    ``n_envs`` copies of Sparse Spread, stepped together.

    :param n_envs: Number of copies.
    :param n_agents: Number of agents and of landmarks (at least 2).
    :param max_cycles: Steps per episode.
    :param cover_radius: A landmark is covered when an agent is within this distance.
    :param terminate_on_success: End an episode when every landmark is covered.
    """

    def __init__(
        self,
        n_envs: int = 1,
        n_agents: int = 3,
        max_cycles: int = SPREAD_MAX_CYCLES,
        cover_radius: float = SPREAD_COVER_RADIUS,
        terminate_on_success: bool = False,
    ):
        if int(n_agents) != n_agents or n_agents < 2:
            raise ValueError(f"n_agents must be an integer >= 2, got {n_agents!r}")
        if max_cycles < 1 or n_envs < 1:
            raise ValueError("max_cycles and n_envs must be >= 1")
        if not cover_radius > 0:
            raise ValueError(f"cover_radius must be > 0, got {cover_radius!r}")
        n_agents = int(n_agents)
        self.n_agents = n_agents
        self.max_cycles = max_cycles
        self.cover_radius = float(cover_radius)
        self.terminate_on_success = terminate_on_success
        agents = tuple(f"agent_{i}" for i in range(n_agents))
        self.agent_layout = AgentLayout(agents, (4 * n_agents + 2,) * n_agents, (2,) * n_agents)
        obs_space = spaces.Box(-np.inf, np.inf, (self.agent_layout.obs_dim,), dtype=np.float32)
        action_space = spaces.Box(-1.0, 1.0, (2 * n_agents,), dtype=np.float32)
        self.render_mode = None
        super().__init__(n_envs, obs_space, action_space)
        self.rngs = [seeding.np_random()[0] for _ in range(n_envs)]
        self.pos = np.zeros((n_envs, 2 * n_agents, 2))  # agents first, then landmarks (mpe2's entity order)
        self.vel = np.zeros((n_envs, n_agents, 2))
        self.steps = np.zeros(n_envs, dtype=np.int64)
        self.success_ever = np.zeros(n_envs, dtype=bool)
        self.episode_collisions = np.zeros(n_envs, dtype=np.int64)
        self._pairs = list(itertools.combinations(range(n_agents), 2))  # mpe2's order of the contact forces

    def _reset_env(self, i: int) -> None:
        rng = self.rngs[i]
        for entity in range(self.pos.shape[1]):  # one draw per entity, in mpe2's order
            self.pos[i, entity] = rng.uniform(-1, +1, 2)
        self.vel[i] = 0.0
        self.steps[i] = 0
        self.success_ever[i] = False
        self.episode_collisions[i] = 0

    def _observations(self, envs: Any = slice(None)) -> np.ndarray:
        n = self.n_agents
        pos, vel = self.pos[envs], self.vel[envs]
        parts = []
        for a in range(n):
            me = pos[:, a]
            parts += [vel[:, a], me]
            parts += [pos[:, n + j] - me for j in range(n)]
            parts += [pos[:, b] - me for b in range(n) if b != a]
        return np.concatenate(parts, axis=1).astype(np.float32)

    def nearest_distances(self) -> np.ndarray:
        """Each landmark's distance to its nearest agent, shape (n_envs, n_agents)."""
        n = self.n_agents
        agents, landmarks = self.pos[:, :n], self.pos[:, n:]
        return np.linalg.norm(landmarks[:, :, None, :] - agents[:, None, :, :], axis=-1).min(axis=2)

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        n = self.n_agents
        actions = np.clip(self._joint_actions().astype(np.float64), -1.0, 1.0)
        pos, vel = self.pos, self.vel
        force = FORCE_SCALE * actions.reshape(self.num_envs, n, 2)
        overlapping = np.zeros(self.num_envs, dtype=np.int64)
        for a, b in self._pairs:
            delta = pos[:, a] - pos[:, b]
            dist = np.sqrt(np.sum(np.square(delta), axis=1, keepdims=True))
            penetration = np.logaddexp(0, -(dist - 2 * SPREAD_AGENT_SIZE) / CONTACT_MARGIN) * CONTACT_MARGIN
            contact = CONTACT_FORCE * delta / dist * penetration
            force[:, a] = contact + force[:, a]
            force[:, b] = -contact + force[:, b]
        pos[:, :n] += vel * DT
        vel *= 1 - DAMPING
        vel += force * DT  # (mass 1)
        for a, b in self._pairs:
            overlapping += np.linalg.norm(pos[:, a] - pos[:, b], axis=-1) < 2 * SPREAD_AGENT_SIZE

        success = np.all(self.nearest_distances() <= self.cover_radius, axis=1)
        return self._end_step(np.where(success, 0.0, -1.0), success, overlapping)
