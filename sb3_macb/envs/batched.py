"""The SB3 ``VecEnv`` methods shared by the package's batched envs, whose envs are rows of one object."""

from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv

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
