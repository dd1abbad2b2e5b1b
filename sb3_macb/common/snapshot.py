"""
Snapshots of live objects (environments mid-episode) that restore to the same state.

Pickling a PettingZoo/MPE environment normally goes through ``gymnasium.utils.EzPickle``, which saves only the
constructor's arguments, so the unpickled env is a fresh one: its world, step counter and random generator are
lost. A snapshot saves such objects' attributes instead. Rendering handles (pygame surfaces and fonts, which
cannot be pickled and hold no simulation state) are left out and taken from a freshly built object on restore.
"""

import copy
import inspect
import io
import pickle
from typing import Any

from gymnasium.utils import EzPickle
from stable_baselines3.common.vec_env import VecEnvWrapper


def _is_render_handle(value: Any) -> bool:
    return type(value).__module__.split(".")[0] == "pygame"


def _restore(obj: Any, state: dict[str, Any]) -> None:
    dropped = state.pop("__snapshot_dropped__", ())
    obj.__dict__.update(state)
    if dropped:  # rendering handles: borrowed from a fresh object built with the same arguments
        # (copies of the arguments: building an env may reset objects it shares, such as a scenario)
        fresh = type(obj)(*copy.deepcopy(obj._ezpickle_args), **copy.deepcopy(obj._ezpickle_kwargs))
        for name in dropped:
            setattr(obj, name, getattr(fresh, name))


def _restore_vec_wrapper(obj: Any, state: dict[str, Any]) -> None:
    obj.__dict__.update(state)
    obj.class_attributes = dict(inspect.getmembers(obj.__class__))  # what VecEnvWrapper.__init__ computes


class _SnapshotPickler(pickle.Pickler):
    def reducer_override(self, obj: Any) -> Any:
        if isinstance(obj, VecEnvWrapper):  # its class_attributes (computed from the class) hold unpicklable proxies
            state = {name: value for name, value in obj.__dict__.items() if name != "class_attributes"}
            return (object.__new__, (type(obj),), state, None, None, _restore_vec_wrapper)
        if isinstance(obj, EzPickle) and not isinstance(obj, type):
            state = {name: value for name, value in obj.__dict__.items() if not _is_render_handle(value)}
            dropped = [name for name in obj.__dict__ if name not in state]
            if dropped:
                state["__snapshot_dropped__"] = dropped
            return (object.__new__, (type(obj),), state, None, None, _restore)
        return NotImplemented


def snapshot(obj: Any) -> bytes:
    """The state of ``obj`` (e.g. a VecEnv of PettingZoo-based envs) as bytes; :func:`restore` rebuilds it."""
    buffer = io.BytesIO()
    _SnapshotPickler(buffer, protocol=5).dump(obj)
    return buffer.getvalue()


def restore(data: bytes) -> Any:
    """The object saved by :func:`snapshot`, in the state it had then."""
    return pickle.loads(data)
