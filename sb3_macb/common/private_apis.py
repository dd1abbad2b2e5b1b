"""
The private APIs of other libraries that sb3_macb uses, fenced in one place.

PyTorch's fast paths are probed once at import: each must exist and compute what its public fallback computes on a
small example. Where a probe fails (a PyTorch version that renamed or dropped the operator), the public fallback
runs instead and gives the same results. Setting ``use_private = False`` runs every fallback (the tests compare the
two). Stable-Baselines3's and Optuna's private attributes are checked where they are used; Optuna's has a public
fallback, SB3's per-env seeds have none, so a missing attribute is one clear error there.

- :func:`lerp_`: ``torch._foreach_lerp_`` (one call for a list of tensors); fallback ``Tensor.lerp_`` per tensor.
- :func:`fused_adam_`: ``torch._fused_adam_`` on tensors whose step counters are already counted; fallback
  ``torch.optim.adam.adam(..., fused=True)``, which runs the same kernel after counting the steps itself.
- :func:`parameter_values`: an ``nn.ParameterList``'s parameters from its ``_parameters`` dict (its own
  ``__iter__`` costs more than a small layer's product); fallback ``list(parameter_list)``.
- :data:`ONEDNN_LINEAR`: oneDNN's GEMM, ``torch.ops.mkldnn._linear_pointwise`` (None where it is missing or wrong);
  :class:`~sb3_macb.common.grouped_mlp.GroupedMLP` falls back to MKL's ``addmm``/``bmm`` without it.
- :func:`set_next_reset_seeds` / :func:`next_reset_seeds`: SB3's ``VecEnv._seeds`` (the seeds of the next reset,
  which ``VecEnv.seed(s)`` sets to ``s + index``; sb3_macb gives each env its own: a pack's runs and the paper's
  evaluation episodes).
- :func:`trial_id`: Optuna's ``Trial._trial_id`` (the storage's id, for heartbeats); fallback: the public storage
  API, from the study's name and the trial's number.

Not fenced, because they are the libraries' own extension points: mpe2's ``_mpe_utils`` (its scenario API, which
PettingZoo's documentation of custom MPE environments uses) and SB3's ``EvalCallback._is_success_buffer`` (what a
subclass of ``EvalCallback`` fills).
"""

from collections.abc import Callable, Sequence
from typing import Any

import torch as th
from torch import nn
from torch.optim.adam import adam as public_adam  # (torch.optim's namespace drops the submodule's name)

use_private = True  # False: every public fallback


def _probe(check: Callable[[], bool]) -> bool:
    try:
        return bool(check())
    except (AttributeError, RuntimeError, TypeError, NotImplementedError):
        return False


def _foreach_lerp_check() -> bool:
    targets, sources = [th.zeros(3), th.ones(2)], [th.ones(3), th.zeros(2)]
    th._foreach_lerp_(targets, sources, 0.25)
    return th.equal(targets[0], th.full((3,), 0.25)) and th.equal(targets[1], th.full((2,), 0.75))


def _adam_tensors(seed: int) -> list[list[th.Tensor]]:
    gen = th.Generator().manual_seed(seed)
    return [[th.randn(5, generator=gen)] for _ in range(4)] + [[th.tensor(3.0)]]


def _fused_adam_check() -> bool:
    settings: dict[str, Any] = dict(amsgrad=False, lr=1e-3, beta1=0.9, beta2=0.999, weight_decay=0.0, eps=1e-8, maximize=False)
    p, g, m, v, step = _adam_tensors(0)
    v = [t.abs() for t in v]
    th._fused_adam_(p, g, m, v, [], step, grad_scale=None, found_inf=None, **settings)
    q, h, n, w, _ = _adam_tensors(0)
    w = [t.abs() for t in w]
    public_adam(q, h, n, w, [], [th.tensor(2.0)], fused=True, **settings)  # counts 2 -> 3 itself
    return th.equal(p[0], q[0]) and th.equal(m[0], n[0]) and th.equal(v[0], w[0])


def _parameter_values_check() -> bool:
    plist = nn.ParameterList([nn.Parameter(th.zeros(1)), nn.Parameter(th.ones(2))])
    values = list(plist._parameters.values())
    return len(values) == 2 and all(a is b for a, b in zip(values, plist))


def _onednn_linear_op() -> Any:
    if not th.backends.mkldnn.is_available():
        return None
    op = th.ops.mkldnn._linear_pointwise
    x, w = th.ones(2, 3), th.ones(4, 3)
    return op if th.allclose(op(x, w, None, "none", [], ""), x @ w.t()) else None


FOREACH_LERP = _probe(_foreach_lerp_check)
FUSED_ADAM = _probe(_fused_adam_check)
PARAMETER_DICT = _probe(_parameter_values_check)
try:
    ONEDNN_LINEAR: Any = _onednn_linear_op()
except (AttributeError, RuntimeError):
    ONEDNN_LINEAR = None


def lerp_(targets: list[th.Tensor], sources: list[th.Tensor], weight: float) -> None:
    """``target += weight * (source - target)`` for each pair, in place."""
    if use_private and FOREACH_LERP:
        th._foreach_lerp_(targets, sources, weight)
        return
    for target, source in zip(targets, sources):
        target.lerp_(source, weight)


def fused_adam_(
    params: list[th.Tensor],
    grads: list[th.Tensor],
    exp_avgs: list[th.Tensor],
    exp_avg_sqs: list[th.Tensor],
    max_exp_avg_sqs: list[th.Tensor],
    steps: list[th.Tensor],
    **settings: Any,
) -> None:
    """
    One fused Adam step on these tensors (CPU's fused kernel), with step counters already counted for this step.

    :param steps: Each tensor's step counter (the same counter may be listed for several tensors; it is only read).
    :param settings: ``amsgrad``, ``lr``, ``beta1``, ``beta2``, ``weight_decay``, ``eps``, ``maximize``.
    """
    if use_private and FUSED_ADAM:
        th._fused_adam_(
            params, grads, exp_avgs, exp_avg_sqs, max_exp_avg_sqs, steps, grad_scale=None, found_inf=None, **settings
        )
        return
    # the public function counts the steps itself: give it copies one behind
    public_adam(params, grads, exp_avgs, exp_avg_sqs, max_exp_avg_sqs, [s - 1 for s in steps], fused=True, **settings)


def parameter_values(parameters: nn.ParameterList) -> list[th.Tensor]:
    """The parameters of ``parameters``, in order."""
    if use_private and PARAMETER_DICT:
        return list(parameters._parameters.values())  # type: ignore[arg-type]
    return list(parameters)


def set_next_reset_seeds(venv: Any, seeds: Sequence[int | None]) -> None:
    """
    Seed each env of ``venv`` (an SB3 ``VecEnv``, unwrapped) with its own seed at its next reset, as ``VecEnv.seed``
    does with ``seed + index``.

    :param venv: The VecEnv (not a wrapper).
    :param seeds: One seed (or None) per env.
    """
    _check_seeds_attribute(venv)
    if len(seeds) != venv.num_envs:
        raise ValueError(f"{len(seeds)} seeds for {venv.num_envs} envs")
    venv._seeds = list(seeds)


def next_reset_seeds(venv: Any) -> list[int | None]:
    """The seeds ``venv`` (an SB3 ``VecEnv``) will reset its envs with (None: not seeded)."""
    _check_seeds_attribute(venv)
    return venv._seeds


def _check_seeds_attribute(venv: Any) -> None:
    if not isinstance(getattr(venv, "_seeds", None), list):
        import stable_baselines3

        raise RuntimeError(
            f"stable-baselines3 {stable_baselines3.__version__} does not keep a VecEnv's next seeds in VecEnv._seeds: "
            "sb3_macb cannot seed each env (the versions that work are listed in its pyproject.toml)"
        )


def trial_id(trial: Any, storage: Any, study_name: str) -> int:
    """
    The storage's id of an Optuna trial (what ``storage.record_heartbeat`` takes).

    :param trial: The ``optuna.Trial``.
    :param storage: The study's storage.
    :param study_name: The study's name.
    """
    private = getattr(trial, "_trial_id", None)
    if use_private and isinstance(private, int):
        return private
    study_id = storage.get_study_id_from_name(study_name)
    return int(storage.get_trial_id_from_study_id_trial_number(study_id, trial.number))


def describe() -> dict[str, bool]:
    """Which private fast paths this PyTorch offers (and passed their probe)."""
    return {
        "foreach_lerp": FOREACH_LERP,
        "fused_adam": FUSED_ADAM,
        "parameter_dict": PARAMETER_DICT,
        "onednn_linear": ONEDNN_LINEAR is not None,
    }
