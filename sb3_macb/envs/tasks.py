"""
The paper's two tasks, built on mpe2's particle world (its physics, seeding and rendering are reused):

- 2-Agent Navigation: two agents must cover two landmarks (sparse reward, collisions penalised; or success-only);
- Communicative Navigation: a static speaker tells a listener which of three landmarks to reach (or of more, in a
  larger arena);
- Sparse Spread: mpe2's simple_spread (N agents must cover N landmarks) with a success-only team reward.

Actions are continuous: movement is a 2-D force command in [-1, 1] (force = 5 * action), communication a 3-D
vector in [0, 1]. Every agent's info carries, per step, ``success`` (the success condition holds now),
``is_success`` (it has held at some step of the episode; so at the episode's end it is the episode's success)
and, for navigation, ``collisions`` (agent pairs overlapping now) and ``episode_collisions``.
"""

from typing import Any, cast

import numpy as np
from gymnasium import spaces
from gymnasium.utils import EzPickle
from mpe2._mpe_utils.core import Agent, Landmark, World
from mpe2._mpe_utils.scenario import BaseScenario
from mpe2._mpe_utils.simple_env import SimpleEnv
from pettingzoo import ParallelEnv

from sb3_macb.envs.task_constants import (
    COMMUNICATION,
    CONTACT_FORCE,
    CONTACT_MARGIN,
    DAMPING,
    DT,
    FORCE_SCALE,
    MAX_CYCLES,
    NAVIGATION,
    SPREAD_AGENT_SIZE,
    SPREAD_COVER_RADIUS,
    SPREAD_LANDMARK_SIZE,
    check_communication_settings,
    check_navigation_settings,
    goal_colors,
)


class TaskScenario(BaseScenario):
    """A scenario with one shared reward and per-step success and collision statistics."""

    def __init__(self, terminate_on_success: bool = False):
        self.terminate_on_success = terminate_on_success

    def shared_reward(self, world: World) -> float:
        raise NotImplementedError

    def success(self, world: World) -> bool:
        raise NotImplementedError

    def collisions(self, world: World) -> int:
        """Number of agent pairs overlapping now."""
        return 0

    def reward(self, agent: Agent, world: World) -> float:
        return self.shared_reward(world)

    def is_terminal(self, world: World) -> bool:
        return self.terminate_on_success and self.success(world)

    @staticmethod
    def _new_world(dim_c: int) -> World:
        """An empty collaborative world with the tasks' physics (:mod:`sb3_macb.envs.task_constants`)."""
        world = World()
        world.dim_c = dim_c
        world.collaborative = True
        world.dt, world.damping = DT, DAMPING
        world.contact_force, world.contact_margin = CONTACT_FORCE, CONTACT_MARGIN
        return world

    @staticmethod
    def _add_landmarks(world: World, n: int, size: float) -> None:
        world.landmarks = [Landmark() for _ in range(n)]
        for i, landmark in enumerate(world.landmarks):
            landmark.name = f"landmark {i}"
            landmark.collide = False
            landmark.movable = False
            landmark.size = size

    @staticmethod
    def _place_randomly(world: World, np_random: Any, half_width: float = 1.0) -> None:
        """Every entity uniformly in [-half_width, half_width]^2, at rest, silent."""
        for entity in world.entities:
            entity.state.p_pos = np_random.uniform(-half_width, +half_width, world.dim_p)
            entity.state.p_vel = np.zeros(world.dim_p)
        for agent in world.agents:
            agent.state.c = np.zeros(world.dim_c)


def _overlapping_pairs(agents: list[Agent]) -> int:
    count = 0
    for i, a in enumerate(agents):
        for b in agents[i + 1 :]:
            if np.linalg.norm(a.state.p_pos - b.state.p_pos) < a.size + b.size:
                count += 1
    return count


class CoveringScenario(TaskScenario):
    """
    Agents that collide and must cover landmarks: the world, the random start, the landmarks' nearest-agent
    distances, the collision count and each agent's observation (velocity, position, every landmark and every other
    agent relative to it). Subclasses set ``n_agents``, ``n_landmarks``, ``agent_size`` and ``landmark_size``.
    """

    n_agents: int
    n_landmarks: int
    agent_size: float
    landmark_size: float

    def make_world(self) -> World:
        world = self._new_world(dim_c=2)
        world.agents = [Agent() for _ in range(self.n_agents)]
        for i, agent in enumerate(world.agents):
            agent.name = f"agent_{i}"
            agent.collide = True
            agent.silent = True
            agent.size = self.agent_size
        self._add_landmarks(world, self.n_landmarks, self.landmark_size)
        return world

    def reset_world(self, world: World, np_random: Any) -> None:
        for agent in world.agents:
            agent.color = np.array([0.35, 0.35, 0.85])
        for landmark in world.landmarks:
            landmark.color = np.array([0.25, 0.25, 0.25])
        self._place_randomly(world, np_random)

    def _nearest_distances(self, world: World) -> np.ndarray:
        agents = np.array([a.state.p_pos for a in world.agents])
        landmarks = np.array([lm.state.p_pos for lm in world.landmarks])
        return np.linalg.norm(landmarks[:, None, :] - agents[None, :, :], axis=-1).min(axis=1)

    def collisions(self, world: World) -> int:
        return _overlapping_pairs(world.agents)

    def observation(self, agent: Agent, world: World) -> np.ndarray:
        landmarks = [lm.state.p_pos - agent.state.p_pos for lm in world.landmarks]
        others = [other.state.p_pos - agent.state.p_pos for other in world.agents if other is not agent]
        return np.concatenate([agent.state.p_vel, agent.state.p_pos, *landmarks, *others]).astype(np.float32)


class TwoAgentNavigationScenario(CoveringScenario):
    """
    Two agents, two landmarks, all of size 0.125. Success: every landmark has an agent within ``success_radius``.
    Shared reward: ``"sparse"`` (the paper's): each landmark whose nearest agent is farther than ``reward_radius``
    costs -1 and each colliding agent costs -1 (with ``collision_penalty``), the sum divided by 2 and by the number
    of agents, and every agent receives the sum over agents: range [-1.5, 0]. ``"success"``: 0 on success, else -1
    (``reward_radius`` and ``collision_penalty`` play no part; collisions are still counted in the infos).
    """

    n_agents = 2
    n_landmarks = NAVIGATION.n_landmarks
    size = agent_size = landmark_size = NAVIGATION.size

    def __init__(
        self,
        reward_radius: float = NAVIGATION.reward_radius,
        success_radius: float = NAVIGATION.success_radius,
        collision_penalty: bool = True,
        terminate_on_success: bool = False,
        reward: str = "sparse",
    ):
        super().__init__(terminate_on_success)
        check_navigation_settings(reward)
        self.reward_type = reward
        self.reward_radius = reward_radius
        self.success_radius = success_radius
        self.collision_penalty = collision_penalty

    def shared_reward(self, world: World) -> float:
        if self.reward_type == "success":
            return 0.0 if self.success(world) else -1.0
        n_agents = len(world.agents)
        uncovered = int(np.sum(self._nearest_distances(world) > self.reward_radius))
        # every agent pays for every uncovered landmark, and each agent in a collision pays for it
        per_agent_total = n_agents * uncovered
        if self.collision_penalty:
            per_agent_total += 2 * _overlapping_pairs(world.agents)
        return -per_agent_total / 2.0 / n_agents

    def success(self, world: World) -> bool:
        return bool(np.all(self._nearest_distances(world) <= self.success_radius))


class CommunicativeNavigationScenario(TaskScenario):
    """
    A static speaker sees the goal landmark's colour and sends a 3-D message; a silent listener sees its velocity,
    the landmarks relative to it and the message, and must reach the goal. All entities have size 0.075 and do not
    collide. Shared reward: ``"sparse"``: 0 within ``reward_radius`` of the goal, else -1; ``"distance"``: minus
    the squared distance to the goal. Success: the listener within ``success_radius`` of the goal. The paper's task
    has three landmarks in [-1, 1]^2; ``n_landmarks`` and ``half_width`` give a harder one (colours from
    :func:`~sb3_macb.envs.task_constants.goal_colors`).
    """

    size = COMMUNICATION.size

    def __init__(
        self,
        reward: str = "sparse",
        reward_radius: float = COMMUNICATION.reward_radius,
        success_radius: float = COMMUNICATION.success_radius,
        terminate_on_success: bool = False,
        n_landmarks: int = COMMUNICATION.n_landmarks,
        half_width: float = 1.0,
    ):
        super().__init__(terminate_on_success)
        check_communication_settings(reward, n_landmarks, half_width)
        self.n_landmarks = int(n_landmarks)
        self.half_width = float(half_width)
        self.colors = tuple(goal_colors(self.n_landmarks))
        self.reward_type = reward
        self.reward_radius = reward_radius
        self.success_radius = success_radius
        self.goal: Landmark | None = None

    def make_world(self) -> World:
        world = self._new_world(dim_c=3)
        world.agents = [Agent(), Agent()]
        speaker, listener = world.agents
        speaker.name, listener.name = "speaker_0", "listener_0"
        speaker.movable = False
        listener.silent = True
        for agent in world.agents:
            agent.collide = False
            agent.size = self.size
        self._add_landmarks(world, self.n_landmarks, self.size)
        return world

    def reset_world(self, world: World, np_random: Any) -> None:
        self.goal = world.landmarks[int(np_random.integers(len(world.landmarks)))]
        for landmark, color in zip(world.landmarks, self.colors):
            landmark.color = color.copy()
        for agent in world.agents:
            agent.color = np.array([0.25, 0.25, 0.25])
        world.agents[1].color = self.goal.color + 0.45
        self._place_randomly(world, np_random, self.half_width)

    def _goal_distance(self, world: World) -> float:
        assert self.goal is not None
        return float(np.linalg.norm(world.agents[1].state.p_pos - self.goal.state.p_pos))

    def shared_reward(self, world: World) -> float:
        distance = self._goal_distance(world)
        if self.reward_type == "sparse":
            return 0.0 if distance <= self.reward_radius else -1.0
        return -(distance**2)

    def success(self, world: World) -> bool:
        return self._goal_distance(world) <= self.success_radius

    def observation(self, agent: Agent, world: World) -> np.ndarray:
        speaker, listener = world.agents
        if agent is speaker:
            assert self.goal is not None
            return self.goal.color.astype(np.float32)
        landmarks = [lm.state.p_pos - listener.state.p_pos for lm in world.landmarks]
        return np.concatenate([listener.state.p_vel, *landmarks, speaker.state.c]).astype(np.float32)


class SparseSpreadScenario(CoveringScenario):
    """
    mpe2's simple_spread with a sparse team reward: ``n_agents`` agents (size 0.15, colliding softly) and as many
    landmarks (size 0.05). Shared reward: 0 when every landmark has an agent within ``cover_radius``, else -1
    (collisions are counted in the infos, not penalized). Success: every landmark covered. An agent observes its
    velocity and position, every landmark and every other agent relative to it (mpe2's observation without the
    silent agents' zero messages).

    :param n_agents: Number of agents and of landmarks (at least 2).
    :param cover_radius: A landmark is covered when an agent is within this distance of it.
    :param terminate_on_success: End the episode on success.
    """

    def __init__(self, n_agents: int = 3, cover_radius: float = SPREAD_COVER_RADIUS, terminate_on_success: bool = False):
        super().__init__(terminate_on_success)
        if int(n_agents) != n_agents or n_agents < 2:
            raise ValueError(f"n_agents must be an integer >= 2, got {n_agents!r}")
        if not cover_radius > 0:
            raise ValueError(f"cover_radius must be > 0, got {cover_radius!r}")
        self.n_agents = self.n_landmarks = int(n_agents)
        self.agent_size, self.landmark_size = SPREAD_AGENT_SIZE, SPREAD_LANDMARK_SIZE
        self.cover_radius = float(cover_radius)

    def shared_reward(self, world: World) -> float:
        return 0.0 if self.success(world) else -1.0

    def success(self, world: World) -> bool:
        return bool(np.all(self._nearest_distances(world) <= self.cover_radius))


class TaskEnv(SimpleEnv, EzPickle):
    """
    mpe2's ``SimpleEnv`` with the paper's continuous action spaces and per-step success and collision infos.

    :param scenario: The task's scenario.
    :param max_cycles: Steps per episode.
    :param render_mode: None, ``"rgb_array"`` or ``"human"``.
    :param name: The environment's name in ``metadata``.
    """

    def __init__(self, scenario: TaskScenario, max_cycles: int = MAX_CYCLES, render_mode: str | None = None, name: str = ""):
        EzPickle.__init__(self, scenario=scenario, max_cycles=max_cycles, render_mode=render_mode, name=name)
        if max_cycles < 1:
            raise ValueError(f"max_cycles must be >= 1, got {max_cycles}")
        world = scenario.make_world()
        super().__init__(
            scenario=scenario,
            world=world,
            max_cycles=max_cycles,
            render_mode=render_mode,
            continuous_actions=True,
            dynamic_rescaling=True,
        )
        self.metadata: dict[str, Any] = {**self.metadata, "name": name}
        for agent in self.world.agents:
            if agent.movable:
                space = spaces.Box(-1.0, 1.0, (self.world.dim_p,), dtype=np.float32)
            else:
                space = spaces.Box(0.0, 1.0, (self.world.dim_c,), dtype=np.float32)
            self.action_spaces[agent.name] = space
        self._success_ever = False
        self._episode_collisions = 0

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> None:
        super().reset(seed=seed, options=options)
        self._success_ever = False
        self._episode_collisions = 0

    def _execute_world_step(self) -> None:
        world = self.world
        for agent, action in zip(world.agents, self.current_actions):
            action = np.asarray(action, dtype=np.float64)
            if agent.movable:
                agent.action.u = FORCE_SCALE * action[: world.dim_p]
            else:
                agent.action.u = np.zeros(world.dim_p)
            agent.action.c = np.zeros(world.dim_c) if agent.silent else action[-world.dim_c :].copy()
        world.step()
        scenario: TaskScenario = self.scenario
        reward = float(scenario.shared_reward(world))
        success = scenario.success(world)
        collisions = scenario.collisions(world)
        self._success_ever = self._success_ever or success
        self._episode_collisions += collisions
        info = {
            "success": success,
            "is_success": self._success_ever,
            "collisions": collisions,
            "episode_collisions": self._episode_collisions,
        }
        for agent in world.agents:
            self.rewards[agent.name] = reward
            self.infos[agent.name] = dict(info)


class TaskParallelEnv(ParallelEnv):
    """
    The task as a native PettingZoo ``ParallelEnv``: one call steps the world for all agents.

    It drives the :class:`TaskEnv` it holds (``self.task_env``: world, seeding, spaces, rendering) directly, without
    PettingZoo's AEC-to-parallel conversion, which costs several times the physics itself. Actions are clipped
    to their bounds, as mpe2's ``ClipOutOfBoundsWrapper`` does.

    :param scenario: The task's scenario.
    :param max_cycles: Steps per episode.
    :param render_mode: None, ``"rgb_array"`` or ``"human"``.
    :param name: The environment's name in ``metadata``.
    """

    def __init__(self, scenario: TaskScenario, max_cycles: int = MAX_CYCLES, render_mode: str | None = None, name: str = ""):
        self.task_env = TaskEnv(scenario, max_cycles=max_cycles, render_mode=render_mode, name=name)
        self.metadata = dict(self.task_env.metadata)
        self.render_mode = render_mode
        self.max_cycles = max_cycles
        self.possible_agents = list(self.task_env.possible_agents)
        self.agents: list[str] = []
        boxes = [cast(spaces.Box, self.action_space(a)) for a in self.possible_agents]  # (continuous agents)
        self._bounds = [(box.low, box.high) for box in boxes]
        self.steps = 0

    def observation_space(self, agent: str) -> spaces.Space:
        return self.task_env.observation_space(agent)

    def action_space(self, agent: str) -> spaces.Space:
        return self.task_env.action_space(agent)

    def _observations(self) -> dict[str, np.ndarray]:
        env = self.task_env
        return {agent.name: env.scenario.observation(agent, env.world).astype(np.float32) for agent in env.world.agents}

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict, dict]:
        self.task_env.reset(seed=seed, options=options)
        self.agents = self.possible_agents[:]
        self.steps = 0
        return self._observations(), {agent: {} for agent in self.agents}

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        if not self.agents:
            raise RuntimeError("step() called on an ended episode: call reset() first")
        missing = [agent for agent in self.agents if agent not in actions]
        if missing:
            raise KeyError(f"No action given for agent(s) {missing}")
        env = self.task_env
        env.current_actions = [
            np.clip(np.asarray(actions[agent], dtype=np.float64), low, high)
            for agent, (low, high) in zip(self.possible_agents, self._bounds)
        ]
        env._execute_world_step()
        self.steps += 1
        # a success that ends the episode is a termination even at the time limit (not bootstrapped), as in TaskVecEnv
        terminated = env.scenario.is_terminal(env.world)
        truncated = self.steps >= self.max_cycles and not terminated
        observations = self._observations()
        rewards = {agent: env.rewards[agent] for agent in self.agents}
        terminations = {agent: terminated for agent in self.agents}
        truncations = {agent: truncated for agent in self.agents}
        infos = {agent: env.infos[agent] for agent in self.agents}
        if terminated or truncated:
            self.agents = []
        if self.render_mode == "human":
            self.render()
        return observations, rewards, terminations, truncations, infos

    def render(self) -> Any:
        return self.task_env.render()

    def state(self) -> np.ndarray:
        return self.task_env.state()

    def close(self) -> None:
        self.task_env.close()


def to_aec(env: TaskParallelEnv) -> Any:
    """The AEC version of a task's parallel env (PettingZoo's conversion)."""
    from pettingzoo.utils.conversions import parallel_to_aec

    return parallel_to_aec(env)
