"""
The ``evaluations.npz`` format of sb3_macb, in one place: what the evaluation callback writes and what the plots,
the sweep and the result scripts read.

One entry per evaluation in every array: SB3's ``timesteps`` (per run), ``results`` (returns, one per episode) and
``ep_lengths``; then ``successes`` (any-step success per episode, the paper's metric), ``final_successes`` (the
success condition at the episode's last step), ``episodes`` (training episodes completed), ``agent_returns``,
``collisions``, ``num_codes`` and ``count1_fraction`` (MACB's table), ``training_collisions`` (accumulated).
"""

import glob
import json
import os
from typing import Any

import numpy as np

from sb3_macb.common.atomic import atomic_write

FILE_NAME = "evaluations.npz"
TIMESTEPS, RESULTS, EP_LENGTHS = "timesteps", "results", "ep_lengths"
SUCCESSES, FINAL_SUCCESSES = "successes", "final_successes"
EPISODES, AGENT_RETURNS, COLLISIONS = "episodes", "agent_returns", "collisions"
NUM_CODES, COUNT1_FRACTION, TRAINING_COLLISIONS = "num_codes", "count1_fraction", "training_collisions"
FIELDS = (
    TIMESTEPS, RESULTS, EP_LENGTHS, SUCCESSES, FINAL_SUCCESSES, EPISODES, AGENT_RETURNS, COLLISIONS, NUM_CODES,
    COUNT1_FRACTION, TRAINING_COLLISIONS,
)  # fmt: skip
SUCCESS_METRICS = {SUCCESSES: "any-step success", FINAL_SUCCESSES: "final-step success"}


def save(path: str, record: dict[str, list]) -> None:
    """
    Write one run's records: compressed (``np.load`` reads it like SB3's file, at a fraction of the size for long
    runs) and atomically (a temporary file renamed over ``path``). ``successes`` and ``final_successes`` are written
    only where every evaluation reported them.

    :param path: The file.
    :param record: Lists keyed by :data:`FIELDS`, one entry per evaluation.
    """
    arrays: dict[str, Any] = {TIMESTEPS: record[TIMESTEPS], RESULTS: record[RESULTS], EP_LENGTHS: record[EP_LENGTHS]}
    for name in (SUCCESSES, FINAL_SUCCESSES):
        if all(record[name]):
            arrays[name] = record[name]
    arrays.update({name: record[name] for name in (EPISODES, COLLISIONS, NUM_CODES, COUNT1_FRACTION, TRAINING_COLLISIONS)})
    arrays[AGENT_RETURNS] = np.array(record[AGENT_RETURNS])
    with atomic_write(path) as file:
        np.savez_compressed(file, **arrays)


def load(path: str, max_episodes: int | None = None) -> dict[str, np.ndarray]:
    """
    One run's arrays (a file, or a folder holding ``evaluations.npz``), cut at ``max_episodes`` training episodes if
    given (a run's first N episodes are the run it would have been with that budget).
    """
    if os.path.isdir(path):
        path = os.path.join(path, FILE_NAME)
    with np.load(path) as data:
        arrays = {name: data[name] for name in data.files}
    if max_episodes is not None:
        keep = episodes(arrays) <= max_episodes
        arrays = {name: (a[keep] if a.ndim and len(a) == len(keep) else a) for name, a in arrays.items()}
    return arrays


def is_complete(run_folder: str) -> bool:
    """Whether the run in ``run_folder`` ran to its end: its ``run.json`` says ``complete`` (runs filed by
    ``experiments/macb_paper/scripts/reproduce.py``; a run in progress has evaluations up to its last checkpoint and
    no such mark)."""
    path = os.path.join(run_folder, "run.json")
    if not os.path.isfile(path):
        return False
    with open(path) as file:
        return bool(json.load(file).get("complete", False))


def load_group(folder: str, max_episodes: int | None = None, complete_only: bool = False) -> list[dict[str, np.ndarray]]:
    """Every run below ``folder`` (one ``evaluations.npz`` per seed, at any depth), in path order; with
    ``complete_only``, only the runs that :func:`is_complete` says ran to their end."""
    paths = sorted(glob.glob(os.path.join(folder, "**", FILE_NAME), recursive=True))
    if complete_only:
        paths = [path for path in paths if is_complete(os.path.dirname(path))]
    if not paths:
        raise FileNotFoundError(f"No {'complete run' if complete_only else FILE_NAME} below {folder}")
    return [load(path, max_episodes) for path in paths]


def episodes(run: dict[str, np.ndarray]) -> np.ndarray:
    """Training episodes completed at each evaluation (from the step counts for files without them: 20 steps each)."""
    return run[EPISODES] if EPISODES in run else run[TIMESTEPS] / 20


def rate(run: dict[str, np.ndarray], metric: str = SUCCESSES) -> np.ndarray:
    """The success rate of each evaluation (mean over its episodes)."""
    return run[metric].mean(axis=1)


def final_level(run: dict[str, np.ndarray], metric: str = SUCCESSES, window: int = 200) -> float:
    """The mean success rate over the last ``window`` evaluations."""
    return float(run[metric][-window:].mean())


HEADS = ("partial", "nan", "drop")


def moving_average(values: np.ndarray, window: int, head: str = "partial") -> np.ndarray:
    """
    Trailing moving average: point ``i`` is the mean of ``values[i - window + 1 : i + 1]``. The first ``window - 1``
    points have fewer values behind them; ``head`` says what they become:

    - ``"partial"``: the mean of the values there are (same length as ``values``; what the plots show);
    - ``"nan"``: NaN (same length);
    - ``"drop"``: left out, so the result is ``window - 1`` shorter and starts at the first full window (numpy's
      ``convolve(..., mode="valid")``; empty when there are fewer than ``window`` values).

    :param values: One value per evaluation.
    :param window: Values per mean, >= 1 (1: the values themselves).
    :param head: ``"partial"``, ``"nan"`` or ``"drop"``.
    """
    if head not in HEADS:
        raise ValueError(f"head must be one of {HEADS}, got {head!r}")
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    values = np.asarray(values, dtype=float)
    full = np.convolve(values, np.ones(window) / window, mode="valid") if len(values) >= window else np.empty(0)
    if head == "drop":
        return full
    first = np.cumsum(values[: window - 1]) / np.arange(1, min(window, len(values) + 1))
    return np.concatenate([first if head == "partial" else np.full(len(first), np.nan), full])


def episodes_to(successes: np.ndarray, run_episodes: np.ndarray, threshold: float, window: int) -> tuple[float, bool]:
    """
    Training episodes until the success rate, averaged over ``window`` consecutive evaluations, first reaches
    ``threshold``; ``(last episode, False)`` if it never does (the run is censored there).
    """
    moving = moving_average(successes.mean(axis=1), window, head="drop")
    # a mean exactly at the threshold counts as reaching it: 1,800 of 2,000 is 0.9 even where the sum rounds below
    hits = np.flatnonzero(moving >= threshold - 1e-9)
    if len(hits):
        return float(run_episodes[hits[0] + window - 1]), True
    return float(run_episodes[-1]), False


def km_median(times: list[float], reached: list[bool]) -> float | None:
    """
    Kaplan-Meier median of the episodes to a threshold: runs that did not reach it are censored at their last
    episode. None when the estimated survival never falls to one half (fewer than half of the runs reached it).
    """
    order = np.argsort(times, kind="stable")
    at_risk, survival = len(times), 1.0
    for i in order:
        if reached[i]:
            survival *= 1.0 - 1.0 / at_risk
            if survival <= 0.5:
                return float(times[i])
        at_risk -= 1
    return None
