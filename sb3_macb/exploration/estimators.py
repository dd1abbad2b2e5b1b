"""The exploration estimators MADDPG takes, built from objects or from configuration dicts."""

import inspect
from typing import Any

from sb3_macb.exploration.macb import MACB
from sb3_macb.exploration.rnd import RND

ESTIMATORS = {"macb": MACB, "rnd": RND}


def make_exploration(config: "MACB | RND | dict[str, Any] | None") -> "MACB | RND | None":
    """
    An estimator from an estimator, None, or a dict of its arguments (e.g. from YAML) whose optional ``estimator``
    key names it: ``"macb"`` (the default) or ``"rnd"``.
    """
    if config is None or isinstance(config, (MACB, RND)):
        return config
    if not isinstance(config, dict):
        raise TypeError(
            f"exploration must be an MACB, an RND, a dict of their arguments, or None; got {type(config).__name__}"
        )
    settings = dict(config)
    name = settings.pop("estimator", "macb")
    if name not in ESTIMATORS:
        raise ValueError(f"exploration estimator must be one of {sorted(ESTIMATORS)}, got {name!r}")
    if name == "macb":
        return MACB.from_config(settings)
    known = set(inspect.signature(RND.__init__).parameters) - {"self"}
    unknown = sorted(set(settings) - known)
    if unknown:
        raise ValueError(f"Unknown RND option(s) {unknown}; known options are {sorted(known)}")
    return RND(**settings)
