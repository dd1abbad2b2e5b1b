"""A count table for 64-bit keys: open addressing in numpy arrays, vectorized inserts and lookups."""

import numpy as np

_EMPTY = np.uint64(0)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def mix64(x: np.ndarray) -> np.ndarray:
    """SplitMix64 finalizer: a bijective mixing of 64-bit integers (wrapping arithmetic)."""
    x = x.astype(np.uint64, copy=True)
    x ^= x >> np.uint64(30)
    x *= _M1
    x ^= x >> np.uint64(27)
    x *= _M2
    x ^= x >> np.uint64(31)
    return x


def fold_words(words: np.ndarray) -> np.ndarray:
    """
    One well-mixed non-zero 64-bit key per row of 64-bit words (a hash code of up to ``64 * n_words`` bits).

    Codes of one word map to distinct keys (the mixing is a bijection); longer codes mix each word with its
    position and combine them, so that two distinct codes share a key with probability about 2^-64.

    :param words: (n, n_words) uint64.
    :return: (n,) uint64, never 0 (0 marks an empty slot).
    """
    if words.shape[1] == 1:
        key = mix64(words[:, 0])
    else:
        offsets = (np.arange(words.shape[1], dtype=np.uint64) * _GOLDEN)[None, :]
        key = mix64(np.bitwise_xor.reduce(mix64(words + offsets), axis=1))
    key[key == _EMPTY] = np.uint64(1)
    return key


class CountTable:
    """
    Counts of 64-bit keys (non-zero, well mixed), stored in two flat arrays: keys (uint64) and counts (uint32),
    probed linearly. The table doubles when more than 3/4 full, so it uses 16 to 32 bytes per distinct key,
    and an insert or a lookup costs a few vectorized passes whatever the table size.

    :param capacity: Initial number of slots (rounded up to a power of two).
    """

    max_load = 0.75
    probe_window = 8
    chunk = 1 << 16  # keys probed at a time: bounds the (keys x window) work arrays to a few MB at any table size

    def __init__(self, capacity: int = 64):
        capacity = 1 << max(4, int(np.ceil(np.log2(max(capacity, 16)))))
        self.keys = np.zeros(capacity, dtype=np.uint64)
        self.counts = np.zeros(capacity, dtype=np.uint32)
        self.num_codes = 0
        self.total_count = 0
        self.num_count1 = 0

    @property
    def capacity(self) -> int:
        return len(self.keys)

    @property
    def nbytes(self) -> int:
        return self.keys.nbytes + self.counts.nbytes

    def _probe(self, keys: np.ndarray, insert: bool) -> np.ndarray:
        """
        Slots of distinct ``keys``; missing keys are inserted (count 0) or reported as -1 (in chunks of
        :attr:`chunk` keys, so that the work arrays stay small however many keys come at once).
        """
        if len(keys) <= self.chunk:
            return self._probe_chunk(keys, insert)
        return np.concatenate([self._probe_chunk(keys[i : i + self.chunk], insert) for i in range(0, len(keys), self.chunk)])

    def _probe_chunk(self, keys: np.ndarray, insert: bool) -> np.ndarray:
        """
        :meth:`_probe` of one chunk.

        Linear probing, vectorized over the keys and over a window of ``probe_window`` slots at a time, so that a
        lookup or an insert takes one or two passes at any load the table allows.
        """
        mask = self.capacity - 1
        window = np.arange(self.probe_window)
        table_keys = self.keys
        start = (keys & np.uint64(mask)).astype(np.int64)
        result = np.full(len(keys), -1, dtype=np.int64)
        pending = np.arange(len(keys))
        while len(pending):
            base = start[pending]
            slots = (base[:, None] + window) & mask
            current = table_keys[slots]
            pending_keys = keys[pending]
            stop = (current == pending_keys[:, None]) | (current == _EMPTY)
            resolved = stop.any(axis=1)
            # rows whose whole window is taken by other keys move on to the next window
            start[pending[~resolved]] = (base[~resolved] + self.probe_window) & mask
            rows = np.flatnonzero(resolved)
            slot = slots[rows, stop[rows].argmax(axis=1)]
            found = table_keys[slot] == pending_keys[rows]
            result[pending[rows[found]]] = slot[found]
            retry = pending[~resolved]
            if insert:
                claim = rows[~found]
                claim_slots = slot[~found]
                # several keys may claim the same empty slot: the first wins, the others probe on from there
                _, first = np.unique(claim_slots, return_index=True)
                won = np.zeros(len(claim), dtype=bool)
                won[first] = True
                table_keys[claim_slots[won]] = keys[pending[claim[won]]]
                result[pending[claim[won]]] = claim_slots[won]
                self.num_codes += int(won.sum())
                losers = pending[claim[~won]]
                start[losers] = claim_slots[~won]
                retry = np.concatenate([retry, losers])
            pending = retry
        return result

    def _grow(self, needed: int) -> None:
        capacity = self.capacity
        while needed > self.max_load * capacity:
            capacity *= 2
        if capacity == self.capacity:
            return
        old_keys, old_counts = self.keys, self.counts
        self.keys = np.zeros(capacity, dtype=np.uint64)
        self.counts = np.zeros(capacity, dtype=np.uint32)
        self.num_codes = 0
        for start in range(0, len(old_keys), self.chunk):  # re-insert chunk by chunk: no copy of the old table
            keys, counts = old_keys[start : start + self.chunk], old_counts[start : start + self.chunk]
            occupied = keys != _EMPTY
            self.counts[self._probe_chunk(keys[occupied], insert=True)] = counts[occupied]

    def _probe_one(self, key: int, insert: bool) -> int:
        """
        :meth:`_probe` of one key in plain Python (for a few keys, a vectorized pass costs more): its slot; a missing
        key is inserted (count 0) or reported as -1.
        """
        table_keys = self.keys
        mask = len(table_keys) - 1
        slot = key & mask
        while True:
            current = int(table_keys[slot])
            if current == key:
                return slot
            if current == 0:
                if not insert:
                    return -1
                table_keys[slot] = key
                self.num_codes += 1
                return slot
            slot = (slot + 1) & mask

    def add(self, keys: np.ndarray) -> None:
        """Count each key once more (a key repeated in ``keys`` is counted as often as it appears)."""
        keys = np.asarray(keys, dtype=np.uint64).ravel()
        if len(keys) == 1:  # one transition per step and run: the common case while collecting
            self._grow(self.num_codes + 1)
            slot = self._probe_one(int(keys[0]), insert=True)
            count = int(self.counts[slot]) + 1
            self.counts[slot] = count
            self.num_count1 += (count == 1) - (count == 2)
            self.total_count += 1
            return
        unique, repeats = np.unique(keys, return_counts=True)
        self._grow(self.num_codes + len(unique))
        slots = self._probe(unique, insert=True)
        old = self.counts[slots]
        new = old + repeats.astype(np.uint32)
        self.counts[slots] = new
        self.num_count1 += int(np.count_nonzero(new == 1)) - int(np.count_nonzero(old == 1))
        self.total_count += len(keys)

    def lookup(self, keys: np.ndarray) -> np.ndarray:
        """Counts of ``keys`` (0 for a key never counted)."""
        keys = np.asarray(keys, dtype=np.uint64).ravel()
        # most keys sit in their home slot: one gather resolves them, the probe handles the rest
        home = (keys & np.uint64(self.capacity - 1)).astype(np.int64)
        counts = self.counts[home]
        away = np.flatnonzero(self.keys[home] != keys)
        if 0 < len(away) <= 32:  # a few: probed one by one in plain Python
            for row in away.tolist():
                slot = self._probe_one(int(keys[row]), insert=False)
                counts[row] = self.counts[slot] if slot >= 0 else 0
        elif len(away):
            slots = self._probe(keys[away], insert=False)  # (repeated keys are fine when nothing is inserted)
            counts[away] = np.where(slots >= 0, self.counts[np.maximum(slots, 0)], 0)
        return counts

    def state(self) -> dict[str, np.ndarray]:
        """The occupied entries, compactly (for saving)."""
        occupied = self.keys != _EMPTY
        return {"keys": self.keys[occupied], "counts": self.counts[occupied]}

    def arrays(self) -> dict[str, np.ndarray]:
        """The table as it is in memory (slot arrays with their empty slots), for saving without a rebuild on load."""
        return {"keys": self.keys, "counts": self.counts}

    @classmethod
    def from_arrays(cls, keys: np.ndarray, counts: np.ndarray, total_count: int) -> "CountTable":
        """
        The table that :meth:`arrays` returned, copied as it is (no re-insertion: loading needs one copy of the
        arrays beside them, and no time per code).

        :param keys: (capacity,) uint64 slot keys (0: empty), capacity a power of two.
        :param counts: (capacity,) uint32 counts.
        :param total_count: Transitions counted (``total_count`` of the saved table).
        """
        # (copied: the table must not share memory with the tensors it was saved to or loaded from)
        keys, counts = np.array(keys, dtype=np.uint64), np.array(counts, dtype=np.uint32)
        capacity = len(keys)
        if capacity < 16 or capacity & (capacity - 1) or counts.shape != keys.shape:
            raise ValueError(
                f"a count table's slot arrays need one power-of-two length >= 16, got {keys.shape} and {counts.shape}"
            )
        table = cls.__new__(cls)
        table.keys, table.counts = keys, counts
        occupied = keys != _EMPTY
        table.num_codes = int(np.count_nonzero(occupied))
        if table.num_codes > cls.max_load * capacity or np.count_nonzero(counts[~occupied]):
            raise ValueError("a count table's slot arrays are inconsistent (too full, or counts in empty slots)")
        table.total_count = int(total_count)
        table.num_count1 = int(np.count_nonzero(counts == 1))
        return table

    @classmethod
    def from_state(cls, keys: np.ndarray, counts: np.ndarray) -> "CountTable":
        keys = np.asarray(keys, dtype=np.uint64)
        counts = np.asarray(counts, dtype=np.uint32)
        table = cls(capacity=int(len(keys) / cls.max_load) + 1)
        slots = table._probe(keys, insert=True)
        table.counts[slots] = counts
        table.total_count = int(counts.sum(dtype=np.int64))
        table.num_count1 = int(np.count_nonzero(counts == 1))
        return table
