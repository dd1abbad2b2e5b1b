"""How an exploration bonus enters the update: its running offset (and scale) taken out before it joins the reward."""

from typing import Any

import numpy as np
import torch as th

NORMALIZE_MODES = (None, "center", "zscore")


class BonusNormalizer:
    """
    Running statistics of an exploration bonus, per bonus column (one per count table), and the bonus with its
    running mean subtracted (``"center"``) or also divided by its running standard deviation (``"zscore"``).

    The estimator: exponential moving averages of each column's minibatch mean and mean square, taken once per
    sampled minibatch with weight ``rate`` (the first minibatch sets them), in float64 and in the form
    ``m += rate * (x - m)``, so that a constant bonus leaves them exactly at that constant and ``"center"`` makes it
    exactly zero. A moving average rather than the mean over all of training because a count bonus drifts down as
    counts grow: the mean over everything lags behind the current bonus, and the lag is itself a reward offset that
    changes slowly. With the default rate the average spans about 100 minibatches (1e4 transitions at batch 100).

    :param mode: ``"center"`` or ``"zscore"``.
    :param rate: Weight of each new minibatch in the moving averages, in (0, 1].
    :param std_floor: ``"zscore"`` divides by ``max(std, std_floor)``, so that a bonus that hardly varies is not
        blown up into noise (in the units of the bonus before normalisation).
    """

    def __init__(self, mode: str, rate: float = 0.01, std_floor: float = 0.01):
        if mode not in NORMALIZE_MODES or mode is None:
            raise ValueError(f"normalize must be one of {NORMALIZE_MODES}, got {mode!r}")
        if not (isinstance(rate, (int, float)) and not isinstance(rate, bool) and 0 < rate <= 1):
            raise ValueError(f"normalize_rate must be a number in (0, 1], got {rate!r}")
        if not (
            isinstance(std_floor, (int, float))
            and not isinstance(std_floor, bool)
            and std_floor > 0
            and np.isfinite(std_floor)
        ):
            raise ValueError(f"std_floor must be a number > 0, got {std_floor!r}")
        self.mode = mode
        self.rate = float(rate)
        self.std_floor = float(std_floor)
        self.mean: np.ndarray | None = None  # (columns,) float64
        self.mean_square: np.ndarray | None = None
        self.updates = 0

    def update(self, bonus: np.ndarray) -> None:
        """Take one minibatch's bonuses into the moving averages. :param bonus: (batch, columns)."""
        batch_mean = bonus.mean(axis=0, dtype=np.float64)
        batch_square = np.square(bonus, dtype=np.float64).mean(axis=0)
        if self.mean is None or self.mean_square is None or self.mean.shape != batch_mean.shape:
            self.mean, self.mean_square = batch_mean, batch_square
        else:
            self.mean += self.rate * (batch_mean - self.mean)
            self.mean_square += self.rate * (batch_square - self.mean_square)
        self.updates += 1

    @property
    def std(self) -> np.ndarray:
        """The running standard deviation of each column (0 before the first minibatch)."""
        if self.mean is None or self.mean_square is None:
            return np.zeros(0)
        return np.sqrt(np.maximum(self.mean_square - np.square(self.mean), 0.0))

    def __call__(self, bonus: np.ndarray, training: bool = True) -> np.ndarray:
        """
        The normalised bonus (float64).

        :param bonus: (batch, columns) bonuses as the estimator gives them.
        :param training: Take this minibatch into the statistics first (what a sampled minibatch does); False reads
            the current statistics only (for diagnostics). Before any minibatch was taken in, the bonus is returned
            centred on its own mean.
        """
        bonus = np.asarray(bonus, dtype=np.float64)
        if training:
            self.update(bonus)
        mean = self.mean if self.mean is not None else bonus.mean(axis=0)
        centred = bonus - mean
        if self.mode == "center":
            return centred
        return centred / np.maximum(self.std if self.mean is not None else bonus.std(axis=0), self.std_floor)

    def state_dict(self) -> dict[str, th.Tensor]:
        """The running statistics as tensors (empty ones before the first minibatch)."""
        empty = np.zeros(0)
        return {
            "mean": th.from_numpy(np.array(self.mean if self.mean is not None else empty, dtype=np.float64)),
            "mean_square": th.from_numpy(
                np.array(self.mean_square if self.mean_square is not None else empty, dtype=np.float64)
            ),
            "updates": th.tensor(self.updates, dtype=th.int64),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore what :meth:`state_dict` returned."""
        mean = state["mean"].cpu().numpy().astype(np.float64)
        square = state["mean_square"].cpu().numpy().astype(np.float64)
        self.mean, self.mean_square = (mean, square) if mean.size else (None, None)
        self.updates = int(state["updates"])
