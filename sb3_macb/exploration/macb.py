"""MACB: Multi-Agent Count-Based exploration with SimHash (the paper's section 4 and Algorithm 1)."""

import inspect
from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th

from sb3_macb.envs.joint_env import AgentLayout
from sb3_macb.exploration.count_min import CountMinSketch
from sb3_macb.exploration.count_table import CountTable, fold_words
from sb3_macb.exploration.normalize import NORMALIZE_MODES, BonusNormalizer

SCOPES = ("joint", "local", "state")
TABLES = ("exact", "sketch")


class SimHash:
    """
    SimHash codes ``sign(A v)`` with ``A`` a (k, D) matrix of i.i.d. standard normal entries, folded to one 64-bit
    key per vector. (``A v = 0`` exactly, which happens only for ``v = 0``, is counted with the negative sign.)

    :param k: Number of bits of the code (its granularity).
    :param dim: Size D of the hashed vectors.
    :param rng: Generator for ``A``.
    :param decimals: Round the vectors to this many decimals before hashing (the paper's code used 2); None: no rounding.
    """

    def __init__(self, k: int, dim: int, rng: np.random.Generator, decimals: int | None = 2):
        self.k = k
        self.decimals = decimals
        self.matrix_t = rng.standard_normal((k, dim)).astype(np.float32).T.copy()  # (D, k): v @ A^T
        self._pad_bytes = (-((k + 7) // 8)) % 8

    def keys(self, vectors: np.ndarray) -> np.ndarray:
        """:param vectors: (n, D) array. :return: (n,) uint64 keys."""
        v = np.asarray(vectors, dtype=np.float32)
        if self.decimals is not None:
            v = np.round(v, self.decimals)
        packed = np.packbits(v @ self.matrix_t > 0, axis=1)
        if self._pad_bytes:
            packed = np.pad(packed, ((0, 0), (0, self._pad_bytes)))
        return fold_words(np.ascontiguousarray(packed).view(np.uint64))


class MACB:
    """
    Multi-Agent Count-Based exploration: SimHash codes of observations and actions are counted when a transition
    is collected, and ``beta / sqrt(n)`` is added to the rewards of every sampled minibatch (never stored).

    Pass it to MADDPG as ``exploration=MACB(...)`` (or a dict of these arguments). After training it holds the
    count tables: ``num_codes``, ``total_count`` and ``count1_fraction``.

    :param beta: Bonus coefficient (>= 0), or a schedule: a function of the progress remaining (1 at the start of
        ``learn``, 0 at its end) giving it, as SB3's learning-rate schedules are (e.g. ``rl_zoo3.utils.linear_schedule``).
    :param k: Length of the SimHash code in bits (>= 1).
    :param scope: What is counted. ``"joint"``: all agents' observations and actions in one table shared by all
        agents (the paper's MACB(s, x)); ``"local"``: one table per agent over its own observation and action,
        each agent's critic getting its own bonus (MACB(o_i, a_i)); ``"state"``: joint observations only.
    :param seed: Seed of the SimHash matrices; None: the model's seed.
    :param decimals: Round observations and actions to this many decimals before hashing (None: no rounding).
    :param counts: False gives the constant-bonus control: every sampled transition gets exactly ``beta``, nothing
        is hashed or counted. It separates what counting contributes from what a reward offset does.
    :param normalize: How the bonus enters the update. None: ``beta / sqrt(n)`` as the paper adds it. ``"center"``:
        ``beta * (u - m)`` with ``u = 1 / sqrt(n)`` and ``m`` its running mean over sampled minibatches, so that the
        bonus carries no reward offset (a constant bonus becomes exactly zero: plain MADDPG). ``"zscore"``: also
        divided by the running standard deviation (at least ``std_floor``). See
        :class:`~sb3_macb.exploration.normalize.BonusNormalizer` for the estimator.
    :param normalize_rate: Weight of each sampled minibatch in the running statistics, in (0, 1].
    :param std_floor: The smallest standard deviation ``"zscore"`` divides by (in units of ``1 / sqrt(n)``).
    :param table: ``"exact"``: a hash table that counts every code exactly and grows with them (16-32 bytes per
        code). ``"sketch"``: a count-min sketch (:class:`~sb3_macb.exploration.count_min.CountMinSketch`) of
        ``sketch_depth`` rows of about ``sketch_width`` counters, memory fixed in advance (4 bytes per counter);
        its counts are never below the true ones, so its bonus is never above the exact table's.
    :param sketch_depth: Rows of the sketch.
    :param sketch_width: Counters per row of the sketch (each row the next prime at or above it).
    """

    def __init__(
        self,
        beta: float | Callable[[float], float] = 0.8,
        k: int = 512,
        scope: str = "joint",
        seed: int | None = None,
        decimals: int | None = 2,
        counts: bool = True,
        normalize: str | None = None,
        normalize_rate: float = 0.01,
        std_floor: float = 0.01,
        table: str = "exact",
        sketch_depth: int = 4,
        sketch_width: int = 1_000_003,
    ):
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
            raise ValueError(f"MACB: k (the hash code length) must be an integer >= 1, got {k!r}")
        if callable(beta):
            for progress in (1.0, 0.0):
                value = beta(progress)
                if (
                    isinstance(value, bool)
                    or not isinstance(value, (int, float, np.integer, np.floating))
                    or not np.isfinite(value)
                    or value < 0
                ):
                    raise ValueError(
                        f"MACB: a beta schedule must give a finite number >= 0, gave {value!r} at progress {progress}"
                    )
        else:
            try:
                beta = float(beta)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"MACB: beta must be a number >= 0 or a schedule, got {beta!r}") from exc
            if not np.isfinite(beta) or beta < 0:
                raise ValueError(f"MACB: beta must be a finite number >= 0, got {beta!r}")
        if normalize not in NORMALIZE_MODES:
            raise ValueError(f"MACB: normalize must be one of {NORMALIZE_MODES}, got {normalize!r}")
        try:  # (the rate and floor are checked whatever the mode, so that a bad one is named at once)
            normalizer = BonusNormalizer(normalize or "center", normalize_rate, std_floor)
        except ValueError as exc:
            raise ValueError(f"MACB: {exc}") from None
        self.normalizer = normalizer if normalize is not None else None
        self.normalize = normalize
        self.normalize_rate = float(normalize_rate)
        self.std_floor = float(std_floor)
        self.progress_remaining = 1.0  # set by MADDPG before each round of updates
        if table not in TABLES:
            raise ValueError(f"MACB: table must be one of {TABLES}, got {table!r}")
        if table == "sketch":
            try:
                CountMinSketch(sketch_depth, 2)  # checks the depth; the width is checked below
            except ValueError as exc:
                raise ValueError(f"MACB: {exc}") from None
            if (
                isinstance(sketch_width, bool)
                or not isinstance(sketch_width, (int, np.integer))
                or not 2 <= sketch_width <= 1 << 28
            ):
                raise ValueError(f"MACB: sketch_width must be an integer in [2, 2**28], got {sketch_width!r}")
        self.table = table
        self.sketch_depth = int(sketch_depth)
        self.sketch_width = int(sketch_width)
        if scope not in SCOPES:
            raise ValueError(f"MACB: unknown scope {scope!r}; expected one of {SCOPES}")
        if decimals is not None and (not isinstance(decimals, (int, np.integer)) or decimals < 0):
            raise ValueError(f"MACB: decimals must be None or an integer >= 0, got {decimals!r}")
        self.beta = beta
        self.k = int(k)
        self.scope = scope
        self.seed = seed
        if not isinstance(counts, (bool, np.bool_)):
            raise ValueError(f"MACB: counts must be True or False, got {counts!r}")
        self.decimals = decimals
        self.counts = bool(counts)
        self.hashes: list[SimHash] = []
        self.tables: list[CountTable | CountMinSketch] = []
        self._layout: AgentLayout | None = None
        self._constant_total = 0  # transitions seen by the constant-bonus control

    @classmethod
    def from_config(cls, config: "MACB | dict[str, Any] | None") -> "MACB | None":
        """An MACB from an MACB, a dict of its arguments (e.g. from YAML), or None."""
        if config is None or isinstance(config, MACB):
            return config
        if not isinstance(config, dict):
            raise TypeError(f"exploration must be an MACB, a dict of MACB arguments, or None; got {type(config).__name__}")
        known = set(inspect.signature(cls.__init__).parameters) - {"self"}
        unknown = sorted(set(config) - known)
        if unknown:
            raise ValueError(f"Unknown MACB option(s) {unknown}; known options are {sorted(known)}")
        return cls(**config)

    def __repr__(self) -> str:
        extra = "" if self.counts else ", counts=False"
        if self.normalize is not None:
            extra += f", normalize={self.normalize!r}, normalize_rate={self.normalize_rate}, std_floor={self.std_floor}"
        if self.table != "exact":
            extra += f", table={self.table!r}, sketch_depth={self.sketch_depth}, sketch_width={self.sketch_width}"
        return f"MACB(beta={self.beta}, k={self.k}, scope={self.scope!r}, seed={self.seed}, decimals={self.decimals}{extra})"

    def __setstate__(self, state: dict[str, Any]) -> None:
        # MACBs pickled by sb3_macb < 0.10 predate normalisation and schedules
        defaults = {
            "normalize": None,
            "normalize_rate": 0.01,
            "std_floor": 0.01,
            "normalizer": None,
            "progress_remaining": 1.0,
            "table": "exact",
            "sketch_depth": 4,
            "sketch_width": 1_000_003,
        }
        self.__dict__.update({**defaults, **state})

    @property
    def current_beta(self) -> float:
        """beta now: the number, or the schedule's value at ``progress_remaining``."""
        return float(self.beta(self.progress_remaining)) if callable(self.beta) else self.beta

    # --- setup and state ---------------------------------------------------------------------------------------

    @property
    def is_setup(self) -> bool:
        return self._layout is not None and (bool(self.tables) or not self.counts)

    @property
    def n_tables(self) -> int:
        """Bonus columns: one per agent for ``scope="local"``, else one shared by all agents."""
        if self._layout is None:
            return 0
        return self._layout.n_agents if self.scope == "local" else 1

    def setup(self, layout: AgentLayout, seed: int | None = None) -> None:
        """
        Build the hash matrices and empty count tables for this agent layout (done by MADDPG).

        :param layout: The agents' observation and action sizes.
        :param seed: Seed used when ``self.seed`` is None (MADDPG passes its own seed).
        """
        if self.is_setup and self._layout == layout:
            return
        if self.seed is None:
            self.seed = int(seed) if seed is not None else int(np.random.SeedSequence().entropy) % (2**31)  # type: ignore[arg-type]
        rng = np.random.default_rng(self.seed)
        self._layout = layout
        if self.scope == "local":
            dims = [o + a for o, a in zip(layout.obs_dims, layout.action_dims)]
        elif self.scope == "joint":
            dims = [layout.obs_dim + layout.action_dim]
        else:
            dims = [layout.obs_dim]
        if not self.counts:
            dims = []  # the constant-bonus control hashes and counts nothing
        self.hashes = [SimHash(self.k, dim, rng, self.decimals) for dim in dims]
        self.tables = [self._new_table() for _ in dims]

    def _new_table(self) -> "CountTable | CountMinSketch":
        return CountMinSketch(self.sketch_depth, self.sketch_width) if self.table == "sketch" else CountTable()

    def _require_setup(self) -> None:
        if not self.is_setup:
            raise RuntimeError("This MACB is not attached to a model yet (pass it to MADDPG(exploration=...))")

    def keys(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """
        :param obs: (n, obs_dim) joint observations.
        :param actions: (n, action_dim) joint actions as stored in the buffer (scaled to [-1, 1], noise included).
        :return: (n, n_tables) uint64 keys.
        """
        self._require_setup()
        layout = self._layout
        assert layout is not None
        if not self.counts:
            return np.zeros((len(obs), self.n_tables), dtype=np.uint64)
        if self.scope == "joint":
            vectors = [np.concatenate([obs, actions], axis=1)]
        elif self.scope == "state":
            vectors = [obs]
        else:
            vectors = [
                np.concatenate([obs[:, o], actions[:, a]], axis=1) for o, a in zip(layout.obs_slices, layout.action_slices)
            ]
        return np.stack([h.keys(v) for h, v in zip(self.hashes, vectors)], axis=1)

    def count(self, keys: np.ndarray) -> None:
        """Count collected transitions. :param keys: (n, n_tables) from :meth:`keys`."""
        if not self.counts:
            self._constant_total += len(keys)
        for i, table in enumerate(self.tables):
            table.add(keys[:, i])

    def bonus(self, keys: np.ndarray, training: bool = True) -> np.ndarray:
        """
        The bonus of each key from the current counts (counting nothing): ``beta / sqrt(n)``, or with ``normalize``
        ``beta`` times the normalised ``1 / sqrt(n)``.

        :param keys: (n, n_tables) keys of counted transitions (one sampled minibatch).
        :param training: Take this minibatch into the normalisation statistics (what the replay buffer does when it
            samples for an update); False only reads them.
        :return: (n, n_tables) float32.
        """
        beta = self.current_beta
        if self.counts:
            counts = np.stack([table.lookup(keys[:, i]) for i, table in enumerate(self.tables)], axis=1)
            if np.any(counts == 0):
                raise RuntimeError(
                    "MACB: a sampled transition's hash code is not in the count table. The replay buffer and the count "
                    "table do not belong together (was the buffer loaded from a different model or MACB setting?)"
                )
        if self.normalizer is None:
            if not self.counts:
                return np.full((len(keys), self.n_tables), beta, dtype=np.float32)
            return (beta / np.sqrt(counts)).astype(np.float32)
        unscaled = 1.0 / np.sqrt(counts) if self.counts else np.ones((len(keys), self.n_tables))
        return (beta * self.normalizer(unscaled, training)).astype(np.float32)

    # --- statistics (the paper's Table 1 column) ---------------------------------------------------------------

    @property
    def num_codes(self) -> int:
        """Distinct codes in the table (summed over agents' tables for ``scope="local"``)."""
        return sum(t.num_codes for t in self.tables)

    @property
    def total_count(self) -> int:
        """Transitions counted."""
        return self.tables[0].total_count if self.tables else self._constant_total

    @property
    def count1_fraction(self) -> float:
        """Share of the distinct codes seen exactly once (over all tables for ``scope="local"``)."""
        codes = self.num_codes
        return sum(t.num_count1 for t in self.tables) / codes if codes else 0.0

    @property
    def sketch_collision_rate(self) -> float | None:
        """
        With ``table="sketch"``: the chance that a code never seen is counted as seen (the mean over the tables of
        :attr:`~sb3_macb.exploration.count_min.CountMinSketch.collision_rate`); None with the exact table.
        """
        rates = [t.collision_rate for t in self.tables if isinstance(t, CountMinSketch)]
        return float(np.mean(rates)) if rates else None

    @property
    def nbytes(self) -> int:
        """Memory held by the count tables."""
        return sum(t.nbytes for t in self.tables)

    # --- saving: settings are pickled with the model, the matrices and tables go to its torch variables ---------

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["hashes"], state["tables"] = [], []
        return state

    @property
    def config(self) -> dict[str, Any]:
        """The settings, as plain values (what ``MACB(**config)`` takes)."""
        config = {"beta": self.beta, "k": self.k, "scope": self.scope, "seed": self.seed, "decimals": self.decimals}
        if not self.counts:
            config["counts"] = False
        if self.normalize is not None:
            config.update(normalize=self.normalize, normalize_rate=self.normalize_rate, std_floor=self.std_floor)
        if self.table != "exact":
            config.update(table=self.table, sketch_depth=self.sketch_depth, sketch_width=self.sketch_width)
        return config

    def state_dict(self) -> dict[str, th.Tensor]:
        """The hash matrices and count tables as tensors (saved in the model's zip file, as SB3 saves modules)."""
        self._require_setup()
        tensors: dict[str, th.Tensor] = {}
        for i, (h, table) in enumerate(zip(self.hashes, self.tables)):
            # the slot arrays as they are (views, no copy): loading adopts them without re-inserting every code
            arrays = table.arrays()
            tensors[f"matrix_{i}"] = th.from_numpy(h.matrix_t.copy())
            if isinstance(table, CountMinSketch):
                tensors[f"sketch_counts_{i}"] = th.from_numpy(arrays["counts"].view(np.int32))
                tensors[f"sketch_widths_{i}"] = th.from_numpy(arrays["widths"])
                tensors[f"sketch_stats_{i}"] = th.from_numpy(arrays["stats"])
                continue
            tensors[f"slots_{i}"] = th.from_numpy(arrays["keys"].view(np.int64))
            tensors[f"slot_counts_{i}"] = th.from_numpy(arrays["counts"].view(np.int32))
            tensors[f"total_{i}"] = th.tensor(table.total_count, dtype=th.int64)
        if not self.counts:
            tensors["constant_total"] = th.tensor(self._constant_total, dtype=th.int64)
        if self.normalizer is not None:
            tensors.update({f"normalizer.{name}": t for name, t in self.normalizer.state_dict().items()})
        return tensors

    def load_state_dict(self, state: dict[str, th.Tensor], strict: bool = True) -> None:
        """
        Restore what :meth:`state_dict` returned (after :meth:`setup`).

        :param state: The saved tensors.
        :param strict: Unused (the state must always match the MACB settings); kept for SB3's loader.
        """
        self._require_setup()
        compact = any(key.startswith("keys_") for key in state)  # written by sb3_macb < 0.8: occupied entries only
        names = ("matrix", "keys", "counts", "total") if compact else ("matrix", "slots", "slot_counts", "total")
        if self.table == "sketch":
            names = ("matrix", "sketch_counts", "sketch_widths", "sketch_stats")
        expected = {f"{name}_{i}" for i in range(len(self.tables)) for name in names}
        if not self.counts:
            expected = {"constant_total"}
        if self.normalizer is not None:
            expected |= {"normalizer.mean", "normalizer.mean_square", "normalizer.updates"}
        if set(state) != expected:
            raise ValueError(f"MACB: the saved count state does not match {self} (tables: {self.n_tables})")
        for i, h in enumerate(self.hashes):
            matrix = state[f"matrix_{i}"].cpu().numpy()
            if matrix.shape != h.matrix_t.shape:
                raise ValueError(f"MACB: saved hash matrix has shape {matrix.shape}, expected {h.matrix_t.shape}")
            h.matrix_t = matrix.astype(np.float32)
            if self.table == "sketch":
                table: CountTable | CountMinSketch = CountMinSketch.from_arrays(
                    state[f"sketch_counts_{i}"].cpu().numpy().view(np.uint32),
                    state[f"sketch_widths_{i}"].cpu().numpy(),
                    state[f"sketch_stats_{i}"].cpu().numpy(),
                )
            elif compact:
                keys = state[f"keys_{i}"].cpu().numpy().view(np.uint64)
                table = CountTable.from_state(keys, state[f"counts_{i}"].cpu().numpy())
                table.total_count = int(state[f"total_{i}"])
            else:
                slots = state[f"slots_{i}"].cpu().numpy().view(np.uint64)
                table = CountTable.from_arrays(slots, state[f"slot_counts_{i}"].cpu().numpy().view(np.uint32),
                                               int(state[f"total_{i}"]))  # fmt: skip
            self.tables[i] = table
        if not self.counts:
            self._constant_total = int(state["constant_total"])
        if self.normalizer is not None:
            self.normalizer.load_state_dict(
                {name[len("normalizer.") :]: t for name, t in state.items() if name.startswith("normalizer.")}
            )
