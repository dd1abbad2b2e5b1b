"""
Does the same seed give the same run on a GPU? Trains the same model twice from one seed on a CUDA device and
compares the weights and the replay buffers bit for bit: MADDPG + MACB (400-300 and 64-64), MATD3 (target policy
noise, delayed actor updates) and a pack of 3 runs.

    python benchmarks/cuda_determinism.py                    # PyTorch's defaults
    python benchmarks/cuda_determinism.py --deterministic    # torch.use_deterministic_algorithms(True)

With ``--deterministic`` the script sets CUBLAS_WORKSPACE_CONFIG=:4096:8 before CUDA starts (cuBLAS needs it), and
an operation with no deterministic CUDA implementation raises an error that names it.
"""

import argparse
import os
from collections.abc import Callable

import numpy as np
import torch as th
from stable_baselines3.common.noise import NormalActionNoise

from benchmarks_common import describe_device
from sb3_macb import MACB, MADDPG
from sb3_macb.envs.vec_tasks import make_task_vec_env

ENV = "sb3_macb/CommunicativeNavigation-v0"


def train(n_runs: int, net: list[int], steps: int, device: str, **kwargs: object) -> MADDPG:
    model = MADDPG(
        "MlpPolicy",
        make_task_vec_env(ENV, n_runs, {"reward": "sparse"}),
        n_runs=n_runs,
        run_seeds=list(range(n_runs)),
        exploration=MACB(beta=0.8, k=512),
        action_noise=NormalActionNoise(np.zeros(5), 0.1 * np.ones(5)),
        batch_size=100,
        learning_starts=100 * n_runs,
        policy_kwargs=dict(net_arch=net, n_critics=2 if "target_policy_noise" in kwargs else 1),
        device=device,
        **kwargs,  # type: ignore[arg-type]
    )
    model.learn(steps * n_runs)
    return model


def same(a: MADDPG, b: MADDPG) -> tuple[bool, bool, float]:
    """(weights identical, replay buffers identical, largest weight difference)."""
    pa, pb = [p.detach().cpu() for p in a.policy.parameters()], [p.detach().cpu() for p in b.policy.parameters()]
    weights = all(th.equal(x, y) for x, y in zip(pa, pb))
    largest = max(float((x - y).abs().max()) for x, y in zip(pa, pb))
    buffers = np.array_equal(a.replay_buffer.observations, b.replay_buffer.observations)
    return weights, buffers, largest


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--steps", type=int, default=1000, help="steps per run")
    parser.add_argument("--deterministic", action="store_true")
    args = parser.parse_args()
    if args.deterministic:
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
        th.use_deterministic_algorithms(True)
    print(f"torch {th.__version__}, device {describe_device(args.device)}, deterministic algorithms: {args.deterministic}")
    cases: dict[str, Callable[[], MADDPG]] = {
        "MADDPG + MACB, 400-300": lambda: train(1, [400, 300], args.steps, args.device),
        "MADDPG + MACB, 64-64": lambda: train(1, [64, 64], args.steps, args.device),
        "MATD3 + MACB, 64-64": lambda: train(1, [64, 64], args.steps, args.device, policy_delay=2, target_policy_noise=0.2),
        "pack of 3, MADDPG + MACB, 64-64": lambda: train(3, [64, 64], args.steps, args.device),
    }
    print("| case | weights identical | replay buffers identical | largest weight difference |")
    print("|---|---|---|---|")
    for name, make in cases.items():
        try:
            weights, buffers, largest = same(make(), make())
            print(f"| {name} | {weights} | {buffers} | {largest:.3g} |", flush=True)
        except RuntimeError as exc:
            print(f"| {name} | error: {str(exc).splitlines()[0]} | | |", flush=True)


if __name__ == "__main__":
    main()
