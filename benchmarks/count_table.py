"""
MACB's count table at scale: memory per distinct code, and the cost of the per-step operations as the table grows
from 1e3 to 1e7 codes (an insert of one transition's key per environment step, a lookup of a minibatch's keys),
plus SimHash hashing at k = 512.

    python benchmarks/count_table.py             # up to 1e7 codes (about 2 minutes, ~400 MB)
    python benchmarks/count_table.py --max 1e6

It ends with the peak memory (tracemalloc, numpy's allocations) of the largest table's last doubling and of saving
and loading it as MACB does (the model zip's tensors), beside the table's own size:
``count_table: codes=... table_mb=... grow_peak_mb=... save_load_peak_mb=... load_s=...``.
"""

import argparse
import time

import numpy as np

from sb3_macb.exploration import CountTable, SimHash
from sb3_macb.exploration.count_table import mix64


def per_call_us(fn, n: int) -> float:
    start = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - start) / n * 1e6


def memory(codes: int) -> str:
    """Peak memory (MB, above what was held before) of growing a table past ``codes`` and of saving and loading it."""
    import io
    import tracemalloc

    import torch as th

    table = CountTable()
    doubling = int(CountTable.max_load * (1 << int(np.floor(np.log2(codes / CountTable.max_load)))))  # the last one
    batch = 1_000_000
    added = 0
    while added + batch < min(codes, doubling):
        table.add(mix64(np.arange(1 + added, 1 + added + batch, dtype=np.uint64)))
        added += batch
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    while added < codes:  # past the doubling
        n = min(batch, codes - added)
        table.add(mix64(np.arange(1 + added, 1 + added + n, dtype=np.uint64)))
        added += n
    grow_peak = (tracemalloc.get_traced_memory()[1] - before) / 1e6
    # saved as MACB.state_dict saves it (the slot arrays as tensors), loaded as MACB.load_state_dict loads it
    buffer = io.BytesIO()
    tracemalloc.reset_peak()
    before = tracemalloc.get_traced_memory()[0]
    arrays = table.arrays()
    th.save(
        {"slots": th.from_numpy(arrays["keys"].view(np.int64)), "counts": th.from_numpy(arrays["counts"].view(np.int32))},
        buffer,
    )
    start = time.perf_counter()
    buffer.seek(0)
    state = th.load(buffer)
    loaded = CountTable.from_arrays(state["slots"].numpy().view(np.uint64), state["counts"].numpy().view(np.uint32),
                                    table.total_count)  # fmt: skip
    load_s = time.perf_counter() - start
    del state
    peak = (tracemalloc.get_traced_memory()[1] - before - buffer.getbuffer().nbytes) / 1e6
    tracemalloc.stop()
    assert loaded.num_codes == table.num_codes
    return (f"count_table: codes={table.num_codes:.2e} table_mb={table.nbytes / 1e6:.0f} grow_peak_mb={grow_peak:.0f} "
            f"save_load_peak_mb={peak:.0f} load_s={load_s:.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--max", type=float, default=1e7, help="largest table size (codes)")
    parser.add_argument("--batch", type=int, default=100, help="minibatch size for lookups")
    parser.add_argument("--calls", type=int, default=2000)
    args = parser.parse_args()

    rng = np.random.default_rng(0)
    table = CountTable()
    next_key = 1
    print("| codes | bytes per code | insert 1 key (us) | lookup batch (us) | lookup per key (us) |")
    print("|---|---|---|---|---|")
    size = 1e3
    while size <= args.max:
        target = int(size)
        while table.num_codes < target:  # fill in large batches of fresh keys
            n = min(1_000_000, target - table.num_codes)
            table.add(mix64(np.arange(next_key, next_key + n, dtype=np.uint64)))
            next_key += n
        present = mix64(rng.integers(1, next_key, size=(args.calls, args.batch)).astype(np.uint64))
        fresh = iter(mix64(np.arange(next_key, next_key + args.calls, dtype=np.uint64)).reshape(-1, 1))
        it = iter(present)
        lookup = per_call_us(lambda it=it: table.lookup(next(it)), args.calls)
        insert = per_call_us(lambda fresh=fresh: table.add(next(fresh)), args.calls)
        next_key += args.calls
        print(
            f"| {table.num_codes:.1e} | {table.nbytes / table.num_codes:.1f} | {insert:.1f} | {lookup:.1f} | "
            f"{lookup / args.batch:.2f} |"
        )
        size *= 10

    simhash = SimHash(512, 22, rng)
    vectors = rng.normal(size=(args.batch, 22)).astype(np.float32)
    one = vectors[:1]
    print(f"\nSimHash k=512, D=22: one vector {per_call_us(lambda: simhash.keys(one), args.calls):.1f} us, "
          f"a batch of {args.batch} {per_call_us(lambda: simhash.keys(vectors), args.calls):.1f} us")
    print(memory(int(args.max)))


if __name__ == "__main__":
    main()
