"""Env builders the benchmarks share."""

import gymnasium as gym

from sb3_macb import make_joint_env


def speaker_listener(continuous: bool = True) -> gym.Env:
    from mpe2 import simple_speaker_listener_v4

    return make_joint_env(simple_speaker_listener_v4.parallel_env(continuous_actions=continuous, max_cycles=20))


def spread(n: int) -> gym.Env:
    from mpe2 import simple_spread_v3

    return make_joint_env(simple_spread_v3.parallel_env(N=n, continuous_actions=True, max_cycles=25))


def spread4() -> gym.Env:
    return spread(4)


def gemm_rates(rows: int = 100, n_in: int = 400, n_out: int = 300, repeats: int = 200) -> dict[str, float]:
    """
    One-thread GFLOP/s of ``x @ W.T + b`` at a 400-300 layer's shape through each CPU backend: MKL's ``addmm``,
    oneDNN's ``mkldnn._linear_pointwise`` (the path GroupedMLP takes for large layers, when available) and a batched
    ``baddbmm`` over 2 groups (the path for small layers). Measured with the current torch thread count.
    """
    import time

    import torch as th

    from sb3_macb.common.grouped_mlp import onednn_available, onednn_bf16_available

    x, w, b = th.randn(rows, n_in), th.randn(n_out, n_in), th.randn(n_out)
    xs, ws, bs = th.randn(2, rows, n_in), th.randn(2, n_out, n_in), th.randn(2, 1, n_out)
    flops = 2 * rows * n_in * n_out
    calls = {
        "mkl_addmm": (lambda: th.addmm(b, x, w.t()), flops),
        "bmm": (lambda: th.baddbmm(bs, xs, ws.transpose(1, 2)), 2 * flops),
    }
    if onednn_available():
        linear = th.ops.mkldnn._linear_pointwise
        calls["onednn"] = (lambda: linear(x, w, b, "none", [], ""), flops)
        if onednn_bf16_available():  # policy_kwargs precision="bf16"
            x16, w16, b16 = x.bfloat16(), w.bfloat16(), b.bfloat16()
            calls["onednn_bf16"] = (lambda: linear(x16, w16, b16, "none", [], ""), flops)
    rates = {}
    for name, (fn, work) in calls.items():
        for _ in range(repeats // 10):
            fn()
        start = time.perf_counter()
        for _ in range(repeats):
            fn()
        rates[name] = work * repeats / (time.perf_counter() - start) / 1e9
    return rates


def describe_device(device: str) -> str:
    """The torch device and, for a CUDA one, the GPU's name (``cpu`` alone for the CPU)."""
    import torch as th

    if not device.startswith("cuda"):
        return device
    return f"{device} ({th.cuda.get_device_name(th.device(device)) if th.cuda.is_available() else 'no CUDA'})"


def describe_backend() -> str:
    """One line: torch, threads, the GEMM rates of each backend and the path GroupedMLP takes at 400-300 and 64-64."""
    import torch as th

    from sb3_macb.common.grouped_mlp import ONEDNN_MIN_WEIGHTS, GroupedMLP, large_gemm_backend

    rates = gemm_rates()
    big = f"per-group {large_gemm_backend()}" if GroupedMLP.use_onednn else "batched baddbmm (MKL)"
    cpu = "unknown CPU"
    try:
        with open("/proc/cpuinfo") as file:
            cpu = next(line.split(":", 1)[1].strip() for line in file if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    text = ", ".join(f"{name} {rate:.0f}" for name, rate in rates.items())
    return (
        f"{cpu}; torch {th.__version__}, {th.get_num_threads()} thread(s); GEMM 100x400 @ 400x300 GFLOP/s: {text}; "
        f"path: layers with >= {ONEDNN_MIN_WEIGHTS} weights (400-300) {big}, smaller (64-64) batched baddbmm"
    )


def train_and_evaluate(make_env, steps: int, seed: int, eval_episodes: int, noise: bool = True, policy_kwargs=None, **kwargs):  # type: ignore[no-untyped-def]
    """
    Train MADDPG (64-64, batch 256, learning after 1,000 steps, Gaussian noise 0.1 when ``noise``) for ``steps`` on
    ``make_env()`` and evaluate it deterministically on a fresh env seeded ``1000 + seed``. ``policy_kwargs`` are
    added to ``net_arch=[64, 64]`` (and may replace it).

    :return: The model, its mean evaluation return and the training time in seconds.
    """
    import time

    import numpy as np
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.noise import NormalActionNoise

    from sb3_macb import MADDPG

    env = make_env()
    dim = env.action_space.shape[0]
    action_noise = NormalActionNoise(np.zeros(dim), 0.1 * np.ones(dim)) if noise else None
    model = MADDPG("MlpPolicy", env, action_noise=action_noise, learning_starts=1000, batch_size=256, seed=seed,
                   policy_kwargs={"net_arch": [64, 64], **(policy_kwargs or {})}, **kwargs)  # fmt: skip
    start = time.perf_counter()
    model.learn(steps)
    seconds = time.perf_counter() - start
    eval_env = make_env()
    eval_env.reset(seed=1000 + seed)
    return model, evaluate_policy(model, eval_env, n_eval_episodes=eval_episodes)[0], seconds
