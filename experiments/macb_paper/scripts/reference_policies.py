"""
Scripted listeners for Communicative Navigation that set reference levels for the learned ones.

Two of them ignore the speaker's message, so whatever they reach is reachable without communication:

- :class:`RandomLandmarkListener` goes to one landmark chosen at random each episode;
- :class:`LandmarkTourListener` visits the landmarks one after another, nearest first.

:class:`GoalListener` reads the goal from the speaker's observation (an oracle: the most a listener that
understood the message could do with this controller). All three steer with the same proportional-derivative
controller on the listener's own observation, and follow SB3's ``predict`` interface, so ``evaluate_policy`` and
:class:`~sb3_macb.callbacks.MultiAgentEvalCallback` evaluate them like models. ``scripts/reference_levels.py``
measures their success rates.
"""

from typing import Any

import numpy as np

# joint observation of Communicative Navigation: speaker (goal colour, 3) then listener (velocity 2,
# the three landmarks relative to the listener 6, the message 3)
_COLOUR = slice(0, 3)
_VELOCITY = slice(3, 5)
_LANDMARKS = slice(5, 11)
_COLOURS = np.array([[0.65, 0.15, 0.15], [0.15, 0.65, 0.15], [0.15, 0.15, 0.65]])


class _ScriptedListener:
    """
    Base: steer the listener to a target landmark with ``u = clip(gain * offset - damping * velocity)``.

    :param gain: Proportional gain on the offset to the target.
    :param damping: Derivative gain on the listener's velocity.
    :param seed: Seed of the random choices.
    """

    def __init__(self, gain: float = 3.0, damping: float = 1.0, seed: int | None = None):
        self.gain = gain
        self.damping = damping
        self.rng = np.random.default_rng(seed)
        self.targets: np.ndarray | None = None

    def _choose(self, obs: np.ndarray, starting: np.ndarray) -> None:
        raise NotImplementedError

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        """Joint actions (speaker: silence; listener: towards its target) for a batch of joint observations."""
        obs = np.asarray(observation, dtype=np.float64).reshape(-1, 14)
        n = len(obs)
        if self.targets is None or len(self.targets) != n:
            self.targets = np.zeros(n, dtype=np.int64)
            episode_start = np.ones(n, dtype=bool)
        starting = np.ones(n, dtype=bool) if episode_start is None else np.asarray(episode_start, dtype=bool)
        self._choose(obs, starting)
        landmarks = obs[:, _LANDMARKS].reshape(n, 3, 2)
        offset = landmarks[np.arange(n), self.targets]
        move = np.clip(self.gain * offset - self.damping * obs[:, _VELOCITY], -1.0, 1.0)
        return np.concatenate([np.zeros((n, 3)), move], axis=1).astype(np.float32), None


class RandomLandmarkListener(_ScriptedListener):
    """Goes to a landmark drawn uniformly at each episode's start, ignoring the message."""

    def _choose(self, obs: np.ndarray, starting: np.ndarray) -> None:
        assert self.targets is not None
        self.targets[starting] = self.rng.integers(0, 3, size=int(starting.sum()))


class LandmarkTourListener(_ScriptedListener):
    """
    Visits the landmarks nearest first, moving on once within ``reach`` of the current one, ignoring the message.

    :param reach: Distance at which a landmark counts as visited (the success radius is 0.15).
    :param gain: Proportional gain on the offset to the target.
    :param damping: Derivative gain on the listener's velocity.
    :param seed: Unused (the tour is deterministic); kept for a common signature.

    The defaults are the best of a small grid (reach 0.05-0.14, gain 3-8, damping 0.5-2) for its any-step success,
    so that the level it sets is the strongest we found without communication.
    """

    def __init__(self, reach: float = 0.14, gain: float = 8.0, damping: float = 1.5, seed: int | None = None):
        super().__init__(gain=gain, damping=damping, seed=seed)
        self.reach = reach
        self.visited: np.ndarray | None = None

    def _choose(self, obs: np.ndarray, starting: np.ndarray) -> None:
        assert self.targets is not None
        n = len(obs)
        if self.visited is None or len(self.visited) != n:
            self.visited = np.zeros((n, 3), dtype=bool)
        self.visited[starting] = False
        distances = np.linalg.norm(obs[:, _LANDMARKS].reshape(n, 3, 2), axis=-1)
        reached = distances[np.arange(n), self.targets] <= self.reach
        self.visited[np.arange(n)[reached & ~starting], self.targets[reached & ~starting]] = True
        self.visited[self.visited.all(axis=1)] = False  # all seen: tour again
        for i in np.flatnonzero(starting | reached):
            candidates = np.where(self.visited[i], np.inf, distances[i])
            self.targets[i] = int(np.argmin(candidates))


class GoalListener(_ScriptedListener):
    """An oracle: reads the goal's colour from the speaker's observation and goes there."""

    def _choose(self, obs: np.ndarray, starting: np.ndarray) -> None:
        self.targets = np.argmin(np.abs(obs[:, None, _COLOUR] - _COLOURS[None]).sum(axis=-1), axis=1)
