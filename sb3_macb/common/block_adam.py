"""Adam applied block by block to stacked parameters, so that a run's update does not depend on its neighbours."""

from collections.abc import Iterable
from typing import Any

import torch as th

from sb3_macb.common.private_apis import fused_adam_


class BlockAdam(th.optim.Adam):
    """
    ``torch.optim.Adam`` with ``fused=True`` whose fused kernel is given each block of a stacked parameter (a range
    of rows along its first axis: one run's agents) as a tensor of its own.

    Adam is element-wise, so the result is the same in exact arithmetic; in floating point the fused CPU kernel
    treats the elements of a vectorized main loop and of its scalar tail differently, so an element's rounding
    depends on its position in the tensor. Given block by block, a run's parameters are updated by the same
    instructions whether the run is trained alone or packed with others. State and ``state_dict`` are Adam's.

    :param params: The parameters (one parameter group).
    :param blocks: For each parameter, in order, the ``(start, stop)`` row ranges to update as separate tensors
        (None or a missing entry: the whole tensor).
    :param kwargs: Adam's arguments (``lr``, ``betas``, ``eps``, ``weight_decay``, ``amsgrad``, ``maximize``).
    """

    def __init__(self, params: Iterable[th.Tensor], blocks: list[list[tuple[int, int]] | None] | None = None, **kwargs):
        kwargs = {**kwargs, "fused": True}
        kwargs.pop("foreach", None)
        params = list(params)
        super().__init__(params, **kwargs)
        blocks = blocks or []
        self._blocks = {id(p): (blocks[i] if i < len(blocks) and blocks[i] else None) for i, p in enumerate(params)}
        self._cache: dict[int, Any] = {}

    def _views(
        self, p: th.Tensor, state: dict[str, Any], amsgrad: bool
    ) -> tuple[list[tuple[int, int]], list[list[th.Tensor]]]:
        """The blocks of ``p`` and the views of its parameter and state tensors (cached: they are updated in place)."""
        cached = self._cache.get(id(p))
        if cached is None or cached[0] is not state["exp_avg"]:
            bounds = self._blocks.get(id(p)) or [(0, p.shape[0] if p.dim() else 1)]
            tensors = [p, state["exp_avg"], state["exp_avg_sq"], *([state["max_exp_avg_sq"]] if amsgrad else [])]
            views = [[t[a:b] if t.dim() else t for a, b in bounds] for t in tensors]
            cached = (state["exp_avg"], bounds, views)
            self._cache[id(p)] = cached
        return cached[1], cached[2]

    def zero_grad(self, set_to_none: bool = True) -> None:
        """Adam's ``zero_grad``; with ``set_to_none`` (the default) a plain loop, which costs less than the profiled
        and grouped general version at the two calls per training step."""
        if not set_to_none:
            return super().zero_grad(set_to_none=False)
        for group in self.param_groups:
            for p in group["params"]:
                p.grad = None

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self._cache = {}
        super().load_state_dict(state_dict)

    @th.no_grad()
    def step(self, closure=None):
        loss = None
        if closure is not None:
            with th.enable_grad():
                loss = closure()
        for group in self.param_groups:
            amsgrad = group["amsgrad"]
            params: list[th.Tensor] = []
            grads: list[th.Tensor] = []
            exp_avgs: list[th.Tensor] = []
            exp_avg_sqs: list[th.Tensor] = []
            max_exp_avg_sqs: list[th.Tensor] = []
            steps: list[th.Tensor] = []
            for p in group["params"]:
                if p.grad is None:
                    continue
                if p.grad.is_sparse:
                    raise RuntimeError("BlockAdam does not support sparse gradients")
                state = self.state[p]
                if not state:
                    state["step"] = th.zeros((), dtype=th.float32, device=p.device)
                    state["exp_avg"] = th.zeros_like(p, memory_format=th.preserve_format)
                    state["exp_avg_sq"] = th.zeros_like(p, memory_format=th.preserve_format)
                    if amsgrad:
                        state["max_exp_avg_sq"] = th.zeros_like(p, memory_format=th.preserve_format)
                state["step"] += 1  # once per parameter, read by every block
                bounds, views = self._views(p, state, amsgrad)
                grad = p.grad
                params += views[0]
                grads += [grad[a:b] if grad.dim() else grad for a, b in bounds]
                exp_avgs += views[1]
                exp_avg_sqs += views[2]
                if amsgrad:
                    max_exp_avg_sqs += views[3]
                steps += [state["step"]] * len(bounds)
            if not params:
                continue
            beta1, beta2 = group["betas"]
            fused_adam_(
                params,
                grads,
                exp_avgs,
                exp_avg_sqs,
                max_exp_avg_sqs,
                steps,
                amsgrad=amsgrad,
                lr=group["lr"],
                beta1=beta1,
                beta2=beta2,
                weight_decay=group["weight_decay"],
                eps=group["eps"],
                maximize=group["maximize"],
            )
        return loss
