"""A count-min sketch of 64-bit keys: fixed memory, counts that are never below the true ones."""

import numpy as np


def primes_from(start: int, n: int) -> list[int]:
    """The ``n`` smallest primes >= ``start`` (trial division: widths are at most a few million)."""

    def is_prime(m: int) -> bool:
        if m < 2 or m % 2 == 0:
            return m == 2
        return all(m % d for d in range(3, int(m**0.5) + 1, 2))

    primes: list[int] = []
    m = max(int(start), 2)
    while len(primes) < n:
        if is_prime(m):
            primes.append(m)
        m += 1
    return primes


class CountMinSketch:
    """
    Counts of 64-bit keys in ``depth`` rows of counters, row ``i`` of prime width ``p_i``, the key counted in cell
    ``key mod p_i`` of every row (Tang et al.'s hashing uses such prime-sized tables). A key's count is the minimum
    over its cells: never below its true count, above it only when every one of its cells is shared with other
    keys. Memory is ``4 * sum(p_i)`` bytes whatever is counted.

    ``num_codes`` and ``num_count1`` are tracked as the sketch sees them: a key is new when its count was 0 before
    it was added. They equal the exact table's when no key shares all its cells with another (a wide sketch), and
    undercount distinct codes otherwise.

    :param depth: Rows (>= 1).
    :param width: Counters per row at least; each row takes the next prime at or above it, all different.
    """

    def __init__(self, depth: int = 4, width: int = 1_000_003):
        if isinstance(depth, bool) or not isinstance(depth, (int, np.integer)) or depth < 1:
            raise ValueError(f"sketch_depth must be an integer >= 1, got {depth!r}")
        if isinstance(width, bool) or not isinstance(width, (int, np.integer)) or not 2 <= width <= 1 << 28:
            raise ValueError(f"sketch_width must be an integer in [2, 2**28], got {width!r}")
        self.widths = np.array(primes_from(int(width), int(depth)), dtype=np.uint64)
        self.offsets = np.concatenate([[0], np.cumsum(self.widths)[:-1]]).astype(np.int64)
        self.counts = np.zeros(int(self.widths.sum()), dtype=np.uint32)
        self._rows = [(int(w), int(o)) for w, o in zip(self.widths, self.offsets)]
        self.num_codes = 0
        self.total_count = 0
        self.num_count1 = 0

    @property
    def depth(self) -> int:
        return len(self.widths)

    @property
    def nbytes(self) -> int:
        return self.counts.nbytes

    @property
    def collision_rate(self) -> float:
        """
        The chance that a key never counted gets a count above 0 (every one of its cells already in use): the
        product over the rows of the share of their counters that are not 0. Near 0 the sketch counts as the exact
        table does; near 1 it calls almost every new key seen, and its counts are overestimates.
        """
        rate = 1.0
        for width, offset in self._rows:
            rate *= np.count_nonzero(self.counts[offset : offset + width]) / width
        return float(rate)

    def _cells(self, keys: np.ndarray) -> np.ndarray:
        """(n, depth) flat indices of each key's cells."""
        keys = np.asarray(keys, dtype=np.uint64)
        return (keys[:, None] % self.widths[None, :]).astype(np.int64) + self.offsets[None, :]

    def lookup(self, keys: np.ndarray) -> np.ndarray:
        """The counts of ``keys`` (the minimum over their cells); 0 only for keys never counted. :return: (n,) int64."""
        if len(keys) == 0:
            return np.zeros(0, dtype=np.int64)
        return self.counts[self._cells(keys)].min(axis=1).astype(np.int64)

    def add(self, keys: np.ndarray) -> None:
        """Count each key once (repeated keys as often as they occur)."""
        keys = np.asarray(keys, dtype=np.uint64)
        if len(keys) == 0:
            return
        if len(keys) == 1:  # one transition per step: plain Python over the rows is several times faster
            key, counts = int(keys[0]), self.counts
            slots = [key % w + o for w, o in self._rows]
            values = [int(counts[c]) for c in slots]
            before = min(values)
            for c, v in zip(slots, values):
                counts[c] = v + 1
            self.num_codes += before == 0
            self.num_count1 += (before == 0) - (before == 1)
            self.total_count += 1
            return
        unique, repeats = np.unique(keys, return_counts=True)
        cells = self._cells(unique)
        before = self.counts[cells].min(axis=1)
        new = before == 0
        self.num_codes += int(new.sum())
        self.num_count1 += int((new & (repeats == 1)).sum()) - int((before == 1).sum())
        np.add.at(self.counts, cells.ravel(), np.repeat(repeats, self.depth).astype(np.uint32))
        self.total_count += len(keys)

    def arrays(self) -> dict[str, np.ndarray]:
        """The counters and the statistics, as arrays (the counters as they are, no copy)."""
        stats = np.array([self.total_count, self.num_codes, self.num_count1], dtype=np.int64)
        return {"counts": self.counts, "widths": self.widths.view(np.int64), "stats": stats}

    @classmethod
    def from_arrays(cls, counts: np.ndarray, widths: np.ndarray, stats: np.ndarray) -> "CountMinSketch":
        """A sketch from :meth:`arrays` (the counters copied, so that the sketch owns them)."""
        widths = (
            np.asarray(widths).view(np.uint64) if np.asarray(widths).dtype == np.int64 else np.asarray(widths, dtype=np.uint64)
        )
        if len(counts) != int(widths.sum()):
            raise ValueError(
                f"count-min sketch: {len(counts)} counters do not match row widths summing to {int(widths.sum())}"
            )
        sketch = cls.__new__(cls)
        sketch.widths = widths.copy()
        sketch.offsets = np.concatenate([[0], np.cumsum(sketch.widths)[:-1]]).astype(np.int64)
        sketch.counts = np.array(counts, dtype=np.uint32)
        sketch._rows = [(int(w), int(o)) for w, o in zip(sketch.widths, sketch.offsets)]
        sketch.total_count, sketch.num_codes, sketch.num_count1 = (int(v) for v in stats)
        return sketch
