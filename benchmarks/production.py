"""
The paper's workload as ``experiments/macb_paper/scripts/reproduce.py`` runs it, timed against its arithmetic floor and
against a second checkout.

Workload: sparse Communicative Navigation, MACB(s, x) (beta 0.8, k 512) in every run, batch 100, one gradient step
per step, Gaussian noise 0.1, evaluation with 10 episodes after every 20-step training episode, 1e6 transitions of
replay buffer per run; a pack of 3 at 400-300 and a pack of 8 at 64-64. Each is timed over two windows: "early"
(right after learning starts) and "late" (every run's buffer and count table first filled with ``--prefill``
random-policy transitions). Two processes run at once, one per core, as the study runs its packs: this checkout on
one, the ``--baseline`` checkout on the other (swapping cores each round), so that the two are measured side by
side under the same load.

The floor is the measured time of the GEMMs of one update of one run at the same shapes (target actors and critics,
the critics' forward and backward, the actors' forward and the backward through critic and actor), each shape
timed alone on this machine with the faster of oneDNN's and MKL's float32 GEMM.

    python benchmarks/production.py                            # this checkout alone
    python benchmarks/production.py --baseline /tmp/base       # and a worktree of an earlier commit beside it
    python benchmarks/production.py --rounds 1 --prefill 50000 # a quicker look
    python benchmarks/production.py --baseline /tmp/base --precision bf16 --configs 400  # bf16 against float32

The baseline is driven through the API it had (``MADDPG(n_runs=...)``, ``make_task_vec_env``,
``MultiAgentEvalCallback``); a checkout from before 0.8.0 gets ``buffer_size * K`` so its runs hold as many rows.
The last line reads
``production: rs400=<x> rs64=<y> floor400=<ratio> floor64=<ratio> vs_baseline400=<r> vs_baseline64=<r>``
(rs: run-steps per second per core, the late window; floor: run-step time / GEMM floor; vs_baseline: our rs over
the baseline's).
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
ENV = "sb3_macb/CommunicativeNavigation-v0"
CONFIGS = {"400": ([400, 300], 3), "64": ([64, 64], 8)}


def worker(args: argparse.Namespace) -> None:
    """One measurement in this process (the checkout is the first entry of sys.path): prints a JSON line."""
    import numpy as np
    import torch as th
    from stable_baselines3.common.noise import NormalActionNoise

    import sb3_macb
    from sb3_macb import MACB, MADDPG
    from sb3_macb.buffers import MultiAgentReplayBuffer
    from sb3_macb.callbacks import MultiAgentEvalCallback, make_eval_vec_env
    from sb3_macb.envs.vec_tasks import make_task_vec_env

    th.set_num_threads(1)
    net, pack = CONFIGS[args.config]
    seeds = list(range(pack))
    precision = {"precision": args.precision} if args.precision != "fp32" else {}  # (a baseline may predate the option)
    per_run_buffer = hasattr(MultiAgentReplayBuffer, "buffer_size_per_run")  # 0.8.0 on: buffer_size is per run
    model = MADDPG(
        "MlpPolicy", make_task_vec_env(ENV, pack, {"reward": "sparse"}), n_runs=pack, run_seeds=seeds,
        exploration=[MACB(beta=0.8, k=512) for _ in seeds],
        action_noise=[NormalActionNoise(np.zeros(5), 0.1 * np.ones(5)) for _ in seeds],
        learning_rate=1e-3, batch_size=100, learning_starts=100 * pack, policy_kwargs=dict(net_arch=net, **precision),
        buffer_size=args.buffer if per_run_buffer else args.buffer * pack, device="cpu",
    )  # fmt: skip
    callback = MultiAgentEvalCallback(make_eval_vec_env(ENV, 10, seeds, {"reward": "sparse"}), n_eval_episodes=10,
                                      eval_freq=20, verbose=0, warn=False)  # fmt: skip
    model.learn(200 * pack, callback=callback)  # learning starts at 100 steps per run, then 100 updates
    if args.window == "late":
        prefill(model, args.prefill)
    model.learn(args.warmup * pack, callback=callback, reset_num_timesteps=False)
    start = time.perf_counter()
    model.learn(args.steps * pack, callback=callback, reset_num_timesteps=False)
    seconds = time.perf_counter() - start
    print(json.dumps({"rs": args.steps * pack / seconds, "version": sb3_macb.__version__,
                      "rows": int(model.replay_buffer.pos), "codes": int(model.explorations[0].num_codes)}))  # fmt: skip


def prefill(model, rows: int) -> None:  # type: ignore[no-untyped-def]
    """``rows`` random-policy transitions per run written into the replay buffer, and counted by each run's MACB."""
    import numpy as np

    buffer = model.replay_buffer
    rng = np.random.default_rng(0)
    start = buffer.pos
    rows = min(rows, buffer.buffer_size - start - 1)
    n_envs = buffer.n_envs
    step = 20_000
    for first in range(start, start + rows, step):
        n = min(step, start + rows - first)
        obs = rng.uniform(-1, 1, size=(n, n_envs, buffer.obs_shape[0])).astype(np.float32)
        actions = rng.uniform(0, 1, size=(n, n_envs, buffer.action_dim)).astype(np.float32)
        buffer.observations[first : first + n] = obs
        buffer.next_observations[first : first + n] = obs
        buffer.actions[first : first + n] = actions
        buffer.agent_rewards[first : first + n] = -1.0
        buffer.rewards[first : first + n] = -2.0
        buffer.timeouts[first : first + n] = (np.arange(first, first + n) % 20 == 19)[:, None]
        buffer.dones[first : first + n] = buffer.timeouts[first : first + n]
        for run, exploration in enumerate(buffer.explorations):
            envs = slice(run * buffer.envs_per_run, (run + 1) * buffer.envs_per_run)
            flat_obs = obs[:, envs].reshape(-1, obs.shape[-1])
            keys = exploration.keys(flat_obs, actions[:, envs].reshape(-1, actions.shape[-1]))
            buffer.hash_keys[first : first + n, envs, : keys.shape[1]] = keys.reshape(n, -1, keys.shape[1])
            exploration.count(keys)
    buffer.pos = start + rows


def gemm_floor_ms(net: list[int], repeats: int = 50) -> float:
    """
    Milliseconds of the GEMMs of one update of one run (2 agents: speaker obs 3 act 3, listener obs 11 act 2; the
    critics read the joint observation and action, 19 inputs), each shape timed alone with the faster backend.
    """
    import torch as th

    from sb3_macb.common.grouped_mlp import onednn_available

    try:  # this checkout's fenced oneDNN GEMM (a baseline checkout may predate the fence)
        from sb3_macb.common.private_apis import ONEDNN_LINEAR
    except ImportError:
        ONEDNN_LINEAR = th.ops.mkldnn._linear_pointwise if onednn_available() else None

    th.set_num_threads(1)
    batch, agents = 100, [(3, 3), (11, 2)]
    critic_in = sum(o + a for o, a in agents)
    shapes: list[tuple[int, int, int]] = []  # (m, k, n) products, m x k @ k x n

    def forward(sizes: list[int]) -> list[tuple[int, int, int]]:
        return [(batch, a, b) for a, b in zip(sizes[:-1], sizes[1:])]

    def backward(sizes: list[int], input_grad_first: bool, weight_grads: bool) -> list[tuple[int, int, int]]:
        out = []
        for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
            if weight_grads:
                out.append((a, batch, b))  # dW = X^T dY
            if i > 0 or input_grad_first:
                out.append((batch, b, a))  # dX = dY W^T
        return out

    for obs, act in agents:
        actor, critic = [obs, *net, act], [critic_in, *net, 1]
        shapes += forward(actor)  # target actor
        shapes += forward(critic)  # target critic
        shapes += forward(critic) + backward(critic, False, True)  # critic update
        shapes += forward(actor) + forward(critic)  # actor output through the critic
        shapes += backward(critic, True, False) + backward(actor, False, True)  # back through the frozen critic
    linear = ONEDNN_LINEAR
    total = 0.0
    for m, k, n in shapes:
        a, w = th.randn(m, k), th.randn(n, k)
        calls = {"mkl": lambda a=a, w=w: th.mm(a, w.t())}
        if linear is not None:
            calls["onednn"] = lambda a=a, w=w: linear(a, w, None, "none", [], "")
        best = float("inf")
        for call in calls.values():
            for _ in range(5):
                call()
            start = time.perf_counter()
            for _ in range(repeats):
                call()
            best = min(best, (time.perf_counter() - start) / repeats)
        total += best
    return total * 1e3


def measure(checkouts: list[str], config: str, window: str, args: argparse.Namespace) -> list[float]:
    """Run-steps/s per core of each checkout, measured at the same time (one process per checkout)."""
    steps = args.steps_400 if config == "400" else args.steps_64
    processes = []
    for checkout in checkouts:
        command = [sys.executable, os.path.abspath(__file__), "--worker", "--config", config, "--window", window,
                   "--steps", str(steps), "--warmup", str(max(steps // 5, 20)), "--prefill", str(args.prefill),
                   "--buffer", str(args.buffer), "--precision", args.precision if checkout == ROOT else "fp32"]  # fmt: skip
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([checkout, os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep))
        processes.append(subprocess.Popen(command, env=env, stdout=subprocess.PIPE, text=True, cwd=checkout))
    results = []
    for process in processes:
        out, _ = process.communicate()
        if process.returncode:
            raise RuntimeError(f"a measurement failed (exit {process.returncode})")
        results.append(json.loads(out.strip().splitlines()[-1])["rs"])
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--baseline", default=None, help="a second checkout (e.g. a git worktree of an earlier commit)")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--steps-400", type=int, default=300, help="timed steps per run at 400-300")
    parser.add_argument("--steps-64", type=int, default=800, help="timed steps per run at 64-64")
    parser.add_argument("--prefill", type=int, default=200_000, help="random transitions per run before the late window")
    parser.add_argument("--buffer", type=int, default=1_000_000, help="replay buffer transitions per run")
    parser.add_argument("--precision", choices=["fp32", "bf16"], default="fp32",
                        help="this checkout's products (the baseline stays float32)")  # fmt: skip
    parser.add_argument("--configs", nargs="+", choices=sorted(CONFIGS), default=sorted(CONFIGS), help="which networks")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--config", choices=sorted(CONFIGS), help=argparse.SUPPRESS)
    parser.add_argument("--window", choices=["early", "late"], help=argparse.SUPPRESS)
    parser.add_argument("--steps", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--warmup", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        sys.path.insert(0, os.getcwd())
        worker(args)
        return
    sys.path[:0] = [ROOT, HERE]
    import platform

    import torch as th

    import sb3_macb

    checkouts = [ROOT] + ([os.path.abspath(args.baseline)] if args.baseline else [])
    from benchmarks_common import gemm_rates

    floors = {config: gemm_floor_ms(net) for config, (net, _) in CONFIGS.items()}
    rates = gemm_rates()
    cpu = platform.processor() or platform.machine()
    print(f"sb3_macb {sb3_macb.__version__} (this checkout, {args.precision}), torch {th.__version__}, {cpu}, "
          f"one thread per process, {len(checkouts)} process(es) at once")  # fmt: skip
    print("GEMM 100x400 @ 400x300, GFLOP/s: " + ", ".join(f"{k} {v:.0f}" for k, v in rates.items() if v))
    print(f"GEMM floor of one update of one run: 400-300 {floors['400']:.2f} ms, 64-64 {floors['64']:.3f} ms")
    results: dict[tuple[str, str, int], list[float]] = {}
    for round_ in range(args.rounds):
        for config in args.configs:
            for window in ("early", "late"):
                order = checkouts if round_ % 2 == 0 else checkouts[::-1]  # (which one starts first)
                rates_now = measure(order, config, window, args)
                for checkout, rate in zip(order, rates_now):
                    results.setdefault((config, window, checkouts.index(checkout)), []).append(rate)
                named = [f"{'ours' if checkouts.index(c) == 0 else 'baseline'} {r:.0f}" for c, r in zip(order, rates_now)]
                print(f"round {round_ + 1}: {config} {window}: " + ", ".join(named), flush=True)
    print("\n| networks | window | checkout | run-steps/s per core | ms per run-step | / GEMM floor |")
    print("|---|---|---|---|---|---|")
    summary: dict[str, float] = {}
    for config in args.configs:
        for window in ("early", "late"):
            for index, name in enumerate(["ours", "baseline"][: len(checkouts)]):
                rate = statistics.median(results[(config, window, index)])
                ratio = 1e3 / rate / floors[config]
                print(
                    f"| {'400-300' if config == '400' else '64-64'} | {window} | {name} | {rate:.0f} | "
                    f"{1e3 / rate:.2f} | {ratio:.2f} |"
                )
                if window == "late":
                    summary[f"rs{config}" if index == 0 else f"base{config}"] = rate
                    if index == 0:
                        summary[f"floor{config}"] = ratio
    vs = {c: summary[f"rs{c}"] / summary[f"base{c}"] if f"base{c}" in summary else float("nan") for c in args.configs}
    figures = [f"rs{c}={summary[f'rs{c}']:.0f}" for c in args.configs] + [
        f"floor{c}={summary[f'floor{c}']:.2f}" for c in args.configs
    ]
    figures += [f"vs_baseline{c}={vs[c]:.2f}" for c in args.configs]
    print(f"\nproduction: {' '.join(figures)}" + ("" if args.precision == "fp32" else f" precision={args.precision}"))

if __name__ == "__main__":
    main()
