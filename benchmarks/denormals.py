"""
What denormal floats cost in training, and what ``MADDPG(flush_denormal=True)`` (the default) saves.

After some 10^4-10^5 updates, Adam's moments of weights whose gradient stays zero (inputs of dead ReLU units) decay
below 1.2e-38 into the denormal range. A checkpoint of the 400-300 Communicative Navigation pack at step 60,000 had
48% of the actor's and 59% of the critic's 300x400 first moments denormal, and many CPUs (Intel's in particular)
compute on denormals 10-100 times slower. This script builds that state (a given share of each moment tensor
set to denormal values, the rest ordinary) for the three 400-300 runs x two agents of a pack, and times the fused
Adam step of the optimizer the package uses, with and without flushing.

    python benchmarks/denormals.py
    python benchmarks/denormals.py --share 0.3 --repeats 50
"""

import argparse
import time

import torch as th

from benchmarks_common import describe_backend
from sb3_macb.common.block_adam import BlockAdam


def adam_ms(share: float, flush: bool, repeats: int) -> float:
    """ms per ``BlockAdam.step`` on a (6, 300, 400) parameter whose moments hold ``share`` denormals."""
    generator = th.Generator().manual_seed(0)
    param = th.nn.Parameter(th.randn(6, 300, 400, generator=generator) * 0.05)
    optimizer = BlockAdam([param], blocks=[[(2 * k, 2 * k + 2) for k in range(3)]], lr=1e-3)
    grad = th.randn(6, 300, 400, generator=generator) * 1e-3
    dead = th.rand(6, 300, 400, generator=generator) < share
    grad[dead] = 0.0  # dead units: no gradient, so their moments only decay
    param.grad = grad
    optimizer.step()  # creates the state
    state = optimizer.state[param]
    state["exp_avg"][dead] = 1e-39
    state["exp_avg_sq"][dead] = 1e-40
    state["step"].fill_(60_000)
    th.set_flush_denormal(flush)
    try:
        start = time.perf_counter()
        for _ in range(repeats):
            # without flushing the decayed moments stay denormal; with it they become 0 on the first step
            optimizer.step()
        return (time.perf_counter() - start) / repeats * 1e3
    finally:
        th.set_flush_denormal(False)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--share", type=float, default=0.5, help="share of the moments that are denormal")
    parser.add_argument("--repeats", type=int, default=30)
    args = parser.parse_args()
    th.set_num_threads(1)
    print(describe_backend())
    if not th.set_flush_denormal(False):
        print("this CPU cannot flush denormals: nothing to compare")
        return
    plain = [adam_ms(args.share, False, args.repeats) for _ in range(3)]
    flushed = [adam_ms(args.share, True, args.repeats) for _ in range(3)]
    plain_ms, flushed_ms = sorted(plain)[1], sorted(flushed)[1]
    print(f"Adam step, 6 x 300 x 400 weights, {args.share:.0%} of the moments denormal (median of 3 x {args.repeats}):")
    print(
        f"  without flushing: {plain_ms:.2f} ms;  flush_denormal=True: {flushed_ms:.2f} ms;  "
        f"ratio {plain_ms / flushed_ms:.1f}x"
    )


if __name__ == "__main__":
    main()
