"""
MACB's count table at scale: memory per distinct code, and the cost of the per-step operations as the table grows
from 1e3 to 1e7 codes (an insert of one transition's key per environment step, a lookup of a minibatch's keys),
plus SimHash hashing at k = 512.

    python benchmarks/count_table.py             # up to 1e7 codes (about 2 minutes, ~400 MB)
    python benchmarks/count_table.py --max 1e6
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
        lookup = per_call_us(lambda: table.lookup(next(it)), args.calls)
        insert = per_call_us(lambda: table.add(next(fresh)), args.calls)
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


if __name__ == "__main__":
    main()
