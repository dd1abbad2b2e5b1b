"""
The paper's two tasks as one vectorized SB3 ``VecEnv``: the particle physics of N copies in numpy arrays.

The paper's protocol steps ten evaluation episodes after every training episode, so evaluation steps ten
environments for each training step; stepping them one Python object at a time (mpe2's world, PettingZoo,
the joint env, SB3's DummyVecEnv) costs more than the networks do at small sizes. This VecEnv steps all copies
at once with the same physics (MPE's: force = 5 * u, dt 0.1, damping 0.25, soft contact forces between colliding
agents), observations, rewards, success and collision infos as :mod:`sb3_macb.envs.tasks` (the tests compare them
step by step), each copy resetting from its own random generator (seeded as gymnasium seeds an env). Infos carry
what the joint env's do (``agent_rewards``, ``agent_infos``, ``is_success``, ``TimeLimit.truncated``,
``terminal_observation``) and, with :func:`make_task_vec_env`'s ``VecMonitor``, ``episode``.

    from sb3_macb.envs.vec_tasks import make_task_vec_env
    venv = make_task_vec_env("sb3_macb/CommunicativeNavigation-v0", n_envs=10, env_kwargs={"reward": "sparse"})
"""

from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from stable_baselines3.common.vec_env import VecEnv, VecMonitor

from sb3_macb.envs.batched import ParticleVecEnv
from sb3_macb.envs.joint_env import AgentLayout
from sb3_macb.envs.task_constants import (
    COMMUNICATION,
    CONTACT_FORCE,
    CONTACT_MARGIN,
    DAMPING,
    DT,
    FORCE_SCALE,
    MAX_CYCLES,
    NAVIGATION,
    check_communication_settings,
    check_navigation_settings,
    goal_colors,
)
from sb3_macb.envs.vec_spread import SpreadVecEnv

TASK_IDS = ("sb3_macb/TwoAgentNavigation-v0", "sb3_macb/CommunicativeNavigation-v0")
SPREAD_ID = "sb3_macb/SparseSpread-v0"


class TaskVecEnv(ParticleVecEnv):
    """
    ``n_envs`` copies of one of the paper's tasks, stepped together.

    :param task: ``"navigation"`` (2-Agent Navigation) or ``"communication"`` (Communicative Navigation).
    :param n_envs: Number of copies.
    :param max_cycles: Steps per episode.
    :param reward: 2-Agent Navigation: ``"sparse"`` (the paper's) or ``"success"``; Communicative Navigation:
        ``"sparse"`` or ``"distance"``.
    :param reward_radius: The sparse reward's radius (0.125 for navigation, 0.15 for communication when None).
    :param success_radius: The success radius (0.25 for navigation, 0.15 for communication when None).
    :param collision_penalty: Navigation: each colliding agent costs -1.
    :param terminate_on_success: End an episode on success.
    :param n_landmarks: Communicative Navigation: number of landmarks (the paper's 3).
    :param half_width: Communicative Navigation: entities start uniformly in [-half_width, half_width]^2.
    """

    def __init__(
        self,
        task: str,
        n_envs: int = 1,
        max_cycles: int = MAX_CYCLES,
        reward: str = "sparse",
        reward_radius: float | None = None,
        success_radius: float | None = None,
        collision_penalty: bool = True,
        terminate_on_success: bool = False,
        n_landmarks: int | None = None,
        half_width: float | None = None,
    ):
        if task not in ("navigation", "communication"):
            raise ValueError(f"task must be 'navigation' or 'communication', got {task!r}")
        nav = task == "navigation"
        if nav:
            check_navigation_settings(reward)
            for key, value in (("n_landmarks", n_landmarks), ("half_width", half_width)):
                if value is not None:
                    raise ValueError(f"{key} is a setting of Communicative Navigation, not of 2-Agent Navigation")
        n_landmarks = COMMUNICATION.n_landmarks if n_landmarks is None else n_landmarks
        half_width = 1.0 if half_width is None else half_width
        if not nav:
            check_communication_settings(reward, n_landmarks, half_width)
        if max_cycles < 1 or n_envs < 1:
            raise ValueError("max_cycles and n_envs must be >= 1")
        self.task = task
        self.max_cycles = max_cycles
        self.reward_type = reward
        self.collision_penalty = collision_penalty
        self.terminate_on_success = terminate_on_success
        constants = NAVIGATION if nav else COMMUNICATION
        self.reward_radius = constants.reward_radius if reward_radius is None else float(reward_radius)
        self.success_radius = constants.success_radius if success_radius is None else float(success_radius)
        self.size = constants.size
        if nav:
            self.agent_layout = AgentLayout(("agent_0", "agent_1"), (10, 10), (2, 2))
            self.n_landmarks, self.n_movers = NAVIGATION.n_landmarks, 2
            low, high = -np.ones(4, dtype=np.float32), np.ones(4, dtype=np.float32)
        else:
            self.n_landmarks, self.n_movers = int(n_landmarks), 1
            self.agent_layout = AgentLayout(("speaker_0", "listener_0"), (3, 2 + 2 * self.n_landmarks + 3), (3, 2))
            low = np.array([0, 0, 0, -1, -1], dtype=np.float32)
            high = np.ones(5, dtype=np.float32)
        obs_space = spaces.Box(-np.inf, np.inf, (self.agent_layout.obs_dim,), dtype=np.float32)
        self.render_mode = None
        super().__init__(n_envs, obs_space, spaces.Box(low, high, dtype=np.float32))
        self._low, self._high = low.astype(np.float64), high.astype(np.float64)
        self.half_width = float(half_width)
        self._colors = goal_colors(self.n_landmarks)
        n = n_envs
        self.rngs = [seeding.np_random()[0] for _ in range(n)]
        n_entities = 2 + self.n_landmarks  # agents first, then landmarks (mpe2's entity order)
        self.pos = np.zeros((n, n_entities, 2))
        self.vel = np.zeros((n, 2, 2))
        self.comm: np.ndarray = np.zeros((n, 3))  # the speaker's message (communication)
        self.goal = np.zeros(n, dtype=np.int64)
        self.steps = np.zeros(n, dtype=np.int64)
        self.success_ever = np.zeros(n, dtype=bool)
        self.episode_collisions = np.zeros(n, dtype=np.int64)
        self._actions = None

    # --- episodes ------------------------------------------------------------------------------------------------

    def _reset_env(self, i: int) -> None:
        rng = self.rngs[i]
        if self.task == "communication":
            self.goal[i] = int(rng.integers(self.n_landmarks))
        for entity in range(self.pos.shape[1]):  # one draw per entity, in mpe2's order
            self.pos[i, entity] = rng.uniform(-self.half_width, +self.half_width, 2)
        self.vel[i] = 0.0
        self.comm[i] = 0.0
        self.steps[i] = 0
        self.success_ever[i] = False
        self.episode_collisions[i] = 0

    def _observations(self, envs: Any = slice(None)) -> np.ndarray:
        pos, vel = self.pos[envs], self.vel[envs]
        if self.task == "navigation":
            parts = []
            for a, other in ((0, 1), (1, 0)):
                me = pos[:, a]
                parts += [vel[:, a], me, pos[:, 2] - me, pos[:, 3] - me, pos[:, other] - me]
            return np.concatenate(parts, axis=1).astype(np.float32)
        listener = pos[:, 1]
        landmarks = [pos[:, 2 + j] - listener for j in range(self.n_landmarks)]
        speaker_obs = self._colors[self.goal[envs]]
        return np.concatenate([speaker_obs, vel[:, 1], *landmarks, self.comm[envs]], axis=1).astype(np.float32)

    # --- stepping --------------------------------------------------------------------------------------------------

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        actions = np.clip(self._joint_actions().astype(np.float64), self._low, self._high)
        pos, vel = self.pos, self.vel
        if self.task == "navigation":
            force = FORCE_SCALE * actions.reshape(self.num_envs, 2, 2)
            delta = pos[:, 0] - pos[:, 1]
            dist = np.sqrt(np.sum(np.square(delta), axis=1, keepdims=True))
            penetration = np.logaddexp(0, -(dist - 2 * self.size) / CONTACT_MARGIN) * CONTACT_MARGIN
            contact = CONTACT_FORCE * delta / dist * penetration
            force[:, 0] = contact + force[:, 0]
            force[:, 1] = -contact + force[:, 1]
            movers = slice(0, 2)
        else:
            force = np.zeros((self.num_envs, 2, 2))
            force[:, 1] = FORCE_SCALE * actions[:, 3:5]
            self.comm = actions[:, 0:3] + 0.0
            movers = slice(1, 2)
        pos[:, movers] += vel[:, movers] * DT
        vel[:, movers] = vel[:, movers] * (1 - DAMPING)
        vel[:, movers] += force[:, movers] * DT  # (mass 1)

        rewards, success, collisions = self._evaluate()
        return self._end_step(rewards, success, collisions)

    def _evaluate(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Shared rewards, success now, agent pairs overlapping now."""
        pos = self.pos
        if self.task == "navigation":
            agents, landmarks = pos[:, :2], pos[:, 2:]
            nearest = np.linalg.norm(landmarks[:, :, None, :] - agents[:, None, :, :], axis=-1).min(axis=2)
            overlapping = (np.linalg.norm(agents[:, 0] - agents[:, 1], axis=-1) < 2 * self.size).astype(np.int64)
            success = np.all(nearest <= self.success_radius, axis=1)
            if self.reward_type == "success":
                return np.where(success, 0.0, -1.0), success, overlapping
            uncovered = np.sum(nearest > self.reward_radius, axis=1)
            total = 2 * uncovered + (2 * overlapping if self.collision_penalty else 0)
            return -total / 2.0 / 2, success, overlapping
        goal = pos[np.arange(self.num_envs), 2 + self.goal]
        distance = np.linalg.norm(pos[:, 1] - goal, axis=-1)
        if self.reward_type == "sparse":
            rewards = np.where(distance <= self.reward_radius, 0.0, -1.0)
        else:
            rewards = -(distance**2)
        return rewards, distance <= self.success_radius, np.zeros(self.num_envs, dtype=np.int64)


def make_task_vec_env(env_id: str, n_envs: int, env_kwargs: dict[str, Any] | None = None) -> VecEnv:
    """
    ``n_envs`` copies of a task id as one :class:`TaskVecEnv` (Sparse Spread: :class:`SpreadVecEnv`) with SB3's
    ``VecMonitor`` (episode returns and lengths in ``info["episode"]``); other env ids as SB3's ``make_vec_env`` builds them.

    :param env_id: A gymnasium id (the paper's two tasks and Sparse Spread are vectorized).
    :param n_envs: Number of envs.
    :param env_kwargs: Keyword arguments of the env (the tasks': ``max_cycles``, ``reward``, the radii, ...).
    """
    kwargs = dict(env_kwargs or {})
    if env_id in TASK_IDS and kwargs.get("render_mode") is None:
        kwargs.pop("render_mode", None)
        task = "navigation" if env_id == TASK_IDS[0] else "communication"
        return VecMonitor(TaskVecEnv(task, n_envs, **kwargs))
    if env_id == SPREAD_ID and kwargs.get("render_mode") is None:
        kwargs.pop("render_mode", None)
        return VecMonitor(SpreadVecEnv(n_envs, **kwargs))
    from stable_baselines3.common.env_util import make_vec_env

    return make_vec_env(env_id, n_envs=n_envs, env_kwargs=kwargs)
