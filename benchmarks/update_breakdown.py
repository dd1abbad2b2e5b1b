"""
Where a pack-step of the study's workload goes, by wall clock: the update, the evaluation, the actors' actions, the
env step and the replay buffer's ``add`` (MACB's hashing and counting included); then, inside the update, the time
spent in the products (``mm``/``addmm``/``bmm``/``baddbmm`` and oneDNN's linear), in the fused Adam, in the target
averaging and in everything else, timed around each operator call, against the GEMM floor of
``benchmarks/production.py``.

    python benchmarks/update_breakdown.py                   # 400-300 pack of 3, then 64-64 pack of 8
    python benchmarks/update_breakdown.py --net 64 64 --pack 8 --steps 1000

Workload as ``production.py``'s (sparse Communicative Navigation, MACB(s, x) k 512, batch 100, evaluation of 10
episodes after every 20-step episode), buffers of ``--buffer`` rows per run. torch's profiler is not used: on CPU it
charged elementwise operators of a 64-64 pack of 8 about eight times their wall-clock time (a ReLU of a 16x100x64
tensor: 228 us in the profiler, 27 us timed around the call), so its shares mislead. The operator timing below
runs under a ``TorchDispatchMode`` that times each operator call; its own cost is left out of the operator times
but lengthens the instrumented pass, so the update's time is taken from a separate, uninstrumented pass. Last line:
``breakdown: net=<net> pack=<k> step_ms=<x> update_ms=<y> gemm_ms=<z> floor_ms=<f>`` (per pack-step).
"""

import argparse
import collections
import os
import sys
import time

import numpy as np
import torch as th
from stable_baselines3.common.noise import NormalActionNoise
from torch.utils._python_dispatch import TorchDispatchMode

from sb3_macb import MACB, MADDPG
from sb3_macb.callbacks import MultiAgentEvalCallback, make_eval_vec_env
from sb3_macb.envs.vec_tasks import make_task_vec_env

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from production import gemm_floor_ms  # noqa: E402  (beside this file)

ENV = "sb3_macb/CommunicativeNavigation-v0"
GEMMS = ("aten.mm", "aten.addmm", "aten.bmm", "aten.baddbmm", "mkldnn._linear_pointwise")


class _OperatorTimes(TorchDispatchMode):
    """Wall-clock seconds inside each operator's call, summed by operator name."""

    def __init__(self) -> None:
        super().__init__()
        self.seconds: dict[str, float] = collections.defaultdict(float)

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):  # type: ignore[no-untyped-def]
        start = time.perf_counter()
        out = func(*args, **(kwargs or {}))
        self.seconds[str(func).rsplit(".", 1)[0]] += time.perf_counter() - start
        return out


def _timed(owner: object, name: str, totals: dict[str, float], key: str) -> None:
    """Wrap ``owner.name`` so that its calls' wall-clock seconds add up in ``totals[key]``."""
    call = getattr(owner, name)

    def wrapper(*args, **kwargs):  # type: ignore[no-untyped-def]
        start = time.perf_counter()
        try:
            return call(*args, **kwargs)
        finally:
            totals[key] += time.perf_counter() - start

    setattr(owner, name, wrapper)


def breakdown(net: list[int], pack: int, steps: int, buffer: int) -> None:
    """Print the split of ``steps`` pack-steps and of the update's operators."""
    th.set_num_threads(1)
    seeds = list(range(pack))
    noises = [NormalActionNoise(np.zeros(5), 0.1 * np.ones(5)) for _ in seeds]
    model = MADDPG(
        "MlpPolicy", make_task_vec_env(ENV, pack, {"reward": "sparse"}), n_runs=pack, run_seeds=seeds,
        exploration=[MACB(beta=0.8, k=512) for _ in seeds], action_noise=noises, learning_rate=1e-3, batch_size=100,
        learning_starts=100 * pack, policy_kwargs=dict(net_arch=net), buffer_size=buffer, device="cpu",
    )  # fmt: skip
    callback = MultiAgentEvalCallback(make_eval_vec_env(ENV, 10, seeds, {"reward": "sparse"}), n_eval_episodes=10,
                                      eval_freq=20, verbose=0, warn=False)  # fmt: skip
    model.learn(300 * pack, callback=callback)
    totals: dict[str, float] = collections.defaultdict(float)
    _timed(model, "train", totals, "update")
    _timed(callback, "_evaluate", totals, "evaluation")
    _timed(model, "_sample_action", totals, "actions")
    _timed(model.env, "step_wait", totals, "env step")
    _timed(model.replay_buffer, "add", totals, "buffer add (MACB counts)")
    start = time.perf_counter()
    model.learn(steps * pack, callback=callback, reset_num_timesteps=False)
    step_ms = (time.perf_counter() - start) / steps * 1e3
    floor = gemm_floor_ms(net) * pack
    print(f"\n{'-'.join(map(str, net))}, pack of {pack}, {steps} pack-steps: {step_ms:.2f} ms per pack-step "
          f"(GEMM floor {floor:.2f} ms, ratio {step_ms / floor:.2f})")  # fmt: skip
    print("| part | ms per pack-step | share |\n|---|---|---|")
    for key, seconds in sorted(totals.items(), key=lambda kv: -kv[1]):
        print(f"| {key} | {seconds / steps * 1e3:.2f} | {100 * seconds / steps * 1e3 / step_ms:.0f}% |")
    rest = step_ms - sum(totals.values()) / steps * 1e3
    print(f"| rest (SB3's loop, callbacks, logging) | {rest:.2f} | {100 * rest / step_ms:.0f}% |")

    updates = max(steps // 4, 10)
    th.set_flush_denormal(model.flush_denormal)  # (as during learn)
    start = time.perf_counter()
    model.train(updates, 100)
    update_ms = (time.perf_counter() - start) / updates * 1e3
    timer = _OperatorTimes()
    with timer:
        model.train(updates, 100)
    th.set_flush_denormal(False)
    per = {name: s / updates * 1e3 for name, s in timer.seconds.items()}
    gemm = sum(v for k, v in per.items() if k in GEMMS)
    adam, lerp = per.get("aten._fused_adam_", 0.0), per.get("aten._foreach_lerp_", 0.0)
    others = sum(per.values()) - gemm - adam - lerp
    print(f"\none update ({updates} timed alone): {update_ms:.2f} ms")
    print("| inside the update | ms | share of the update |\n|---|---|---|")
    for label, value in (
        ("products (GEMMs)", gemm),
        ("fused Adam", adam),
        ("target averaging", lerp),
        ("other operators", others),
    ):
        print(f"| {label} | {value:.2f} | {100 * value / update_ms:.0f}% |")
    outside = update_ms - gemm - adam - lerp - others
    print(f"| Python, autograd and dispatch around the operators | {outside:.2f} | {100 * outside / update_ms:.0f}% |")
    print(f"breakdown: net={'-'.join(map(str, net))} pack={pack} step_ms={step_ms:.2f} update_ms={update_ms:.2f} "
          f"gemm_ms={gemm:.2f} floor_ms={floor:.2f}")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--net", type=int, nargs="+", default=None, help="hidden sizes (default: 400 300, then 64 64)")
    parser.add_argument("--pack", type=int, default=None, help="runs in the pack (default: 3 at 400-300, 8 at 64-64)")
    parser.add_argument("--steps", type=int, default=None, help="timed pack-steps (default: 200 at 400-300, 800 at 64-64)")
    parser.add_argument("--buffer", type=int, default=1_000_000, help="replay buffer rows per run")
    args = parser.parse_args()
    if args.pack is not None and args.pack < 1 or args.steps is not None and args.steps < 20:
        parser.error("--pack must be >= 1 and --steps >= 20")
    if args.net is not None and min(args.net) < 1 or args.buffer < 1000:
        parser.error("--net takes hidden sizes >= 1, and --buffer must be >= 1000 rows")
    configs = (
        [([400, 300], 3, 200), ([64, 64], 8, 800)] if args.net is None else [(args.net, 8 if max(args.net) < 128 else 3, 400)]
    )
    for net, pack, steps in configs:
        breakdown(net, args.pack or pack, args.steps or steps, args.buffer)


if __name__ == "__main__":
    main()
