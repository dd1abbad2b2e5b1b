"""
Several MLPs of the same shape (one per agent, or per agent and critic) held as stacked tensors and evaluated
in one pass.

Two interchangeable execution paths compute the same function and gradients:

- a portable path built from ``torch.baddbmm`` (any device, any activation): one batched product per layer for all
  groups; for ReLU networks without shared parameters one autograd node with a hand-written backward that makes the
  same products autograd would (the same numbers, bit for bit, with less of the graph's bookkeeping), autograd's
  graph of products, masks and activations otherwise;
- on CPU, for float32 and ReLU, one autograd ``Function`` for all groups and layers with a hand-written backward,
  calling one GEMM per group and layer: oneDNN's (:data:`~sb3_macb.common.private_apis.ONEDNN_LINEAR`) for large layers on
  AVX-512 CPUs, where it runs these shapes about twice as fast as MKL, and ``torch.addmm``/``mm`` (MKL) elsewhere
  and for small layers, where a call's fixed cost dominates. Each group's products are the same calls alone or in a
  pack.
"""

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch as th
from torch import nn

from sb3_macb.common.private_apis import ONEDNN_LINEAR, parameter_values

PRECISIONS = {"fp32": None, "bf16": th.bfloat16}  # GroupedMLP's precision option: the dtype of the products
LARGE_LAYER_PATHS = ("per_group", "batched")  # GroupedMLP's large_layers option

# Products with at least this many weights per group and this many rows go through oneDNN's GEMM; smaller ones
# (where a call's fixed cost dominates, e.g. predict() on one observation) use addmm.
ONEDNN_MIN_WEIGHTS = 8192
ONEDNN_MIN_ROWS = 16


_LINEAR = ONEDNN_LINEAR  # (probed in private_apis)


def _onednn_bf16_works() -> bool:
    """Whether oneDNN's GEMM takes bfloat16 on this CPU (it needs native bfloat16 support, e.g. AVX-512 BF16)."""
    if _LINEAR is None:
        return False
    try:
        x, w = th.ones(ONEDNN_MIN_ROWS, 128, dtype=th.bfloat16), th.ones(128, 128, dtype=th.bfloat16)
        return bool(th.allclose(_LINEAR(x, w, None, "relu", [], "").float(), (x.float() @ w.float().t())))
    except RuntimeError:
        return False


_BF16_LINEAR = _onednn_bf16_works()


def onednn_bf16_available() -> bool:
    """Whether oneDNN's GEMM takes bfloat16 on this CPU (``precision="bf16"`` uses it for large layers)."""
    return _BF16_LINEAR


def onednn_available() -> bool:
    """Whether the oneDNN CPU path can be used in this PyTorch build."""
    return _LINEAR is not None


def _onednn_fp32_preferred() -> bool:
    """
    Whether large float32 products go to oneDNN rather than MKL: on CPUs with AVX-512, where oneDNN ran these shapes
    1.6-2 times as fast as MKL (whose AVX-512 path some CPUs, AMD's in particular, do not get); on AVX2-only CPUs MKL
    was 5-10% faster. Decided from the CPU's capability, never from a timing, so a machine always computes alike.
    """
    try:
        capability = th.backends.cpu.get_cpu_capability()
    except (AttributeError, RuntimeError):
        capability = ""
    return _LINEAR is not None and capability.upper().startswith("AVX512")


_ONEDNN_FP32 = _onednn_fp32_preferred()


def large_gemm_backend() -> str:
    """The library that computes large float32 layers on this CPU: ``"onednn"`` or ``"mkl"`` (PyTorch's ``addmm``)."""
    return "onednn" if _ONEDNN_FP32 else "mkl"


def _use_onednn(weight: th.Tensor, rows: int) -> bool:
    """Whether this product goes to oneDNN: large enough, and float32 where oneDNN is preferred or bfloat16."""
    return weight.numel() >= ONEDNN_MIN_WEIGHTS and rows >= ONEDNN_MIN_ROWS and (_ONEDNN_FP32 or weight.dtype != th.float32)


def _linear(x: th.Tensor, weight: th.Tensor, bias: th.Tensor | None, relu: bool) -> th.Tensor:
    """``x @ weight.T + bias`` (then ReLU), with weight of shape (out, in)."""
    if _use_onednn(weight, x.shape[0]):
        return _LINEAR(x, weight, bias, "relu" if relu else "none", [], "")
    out = th.addmm(bias, x, weight.t()) if bias is not None else th.mm(x, weight.t())
    return out.relu_() if relu else out


def _matmul_nt(a: th.Tensor, b: th.Tensor, out: th.Tensor | None = None) -> th.Tensor:
    """``a @ b.T`` (into ``out`` when given: MKL writes there directly, oneDNN's result is copied)."""
    if _use_onednn(b, a.shape[0]):
        result = _LINEAR(a, b, None, "none", [], "")
        return result if out is None else out.copy_(result)
    return th.mm(a, b.t(), out=out)


class _GroupedReluMLP(th.autograd.Function):
    """Forward and backward of all groups and layers of a ReLU MLP in one autograd node (CPU, oneDNN)."""

    @staticmethod
    def forward(
        ctx: Any,
        x: th.Tensor,
        sum_groups: bool,
        in_mask: th.Tensor | None,
        out_masks: tuple[th.Tensor, th.Tensor] | None,
        low: tuple[th.Tensor, ...] | None,
        *params: th.Tensor,
    ) -> th.Tensor:
        # The weights arrive unmasked: masked entries are zero and stay zero because their gradient is masked.
        # ``low``: per parameter, a bfloat16 copy to compute with (large layers) or None (the float32 parameter is
        # used: small products are slower in bfloat16); the gradients go to the float32 parameters either way.
        n_layers = len(params) // 2
        if low is not None:
            params = tuple(p if c is None else c for p, c in zip(params, low))
        weights, biases = params[:n_layers], params[n_layers:]
        n_groups = weights[0].shape[0]
        shared_input = x.dim() == 2
        activations: list[list[th.Tensor]] = []  # per group: each layer's input, in that layer's dtype
        outputs = []
        for g in range(n_groups):
            h = x if shared_input else x[g]
            acts = []
            for layer in range(n_layers):
                h = h.to(weights[layer].dtype)
                acts.append(h)
                h = _linear(h, weights[layer][g], biases[layer][g], relu=layer < n_layers - 1)
            activations.append(acts)
            outputs.append(h)
        ctx.activations = activations if any(ctx.needs_input_grad) else None
        ctx.in_mask, ctx.out_masks = in_mask, out_masks
        ctx.sum_groups = sum_groups
        ctx.shared_input = shared_input
        ctx.save_for_backward(*weights)
        if sum_groups:
            out = outputs[0]
            for o in outputs[1:]:
                out = out + o
        else:
            out = th.stack(outputs)
        return out.to(x.dtype)

    @staticmethod
    def backward(ctx: Any, grad_out: th.Tensor) -> tuple[th.Tensor | None, ...]:
        weights = ctx.saved_tensors
        n_layers = len(weights)
        n_groups = weights[0].shape[0]
        needs = ctx.needs_input_grad
        need_x = needs[0]
        need_w = needs[5 : 5 + n_layers]
        need_b = needs[5 + n_layers :]
        grad_w = [th.empty_like(w) if need else None for w, need in zip(weights, need_w)]
        grad_b = [th.empty(w.shape[:2], dtype=w.dtype, device=w.device) if need else None for w, need in zip(weights, need_b)]
        grad_x_groups = []
        grad_out = grad_out.contiguous()
        for g in range(n_groups):
            acts = ctx.activations[g]
            grad = grad_out if ctx.sum_groups else grad_out[g]
            for layer in range(n_layers - 1, -1, -1):
                if layer < n_layers - 1:
                    following = acts[layer + 1]  # this layer's ReLU output, as the next layer read it
                    grad = th.ops.aten.threshold_backward(grad.to(following.dtype), following, 0)
                grad = grad.to(weights[layer].dtype)
                layer_grad_w, layer_grad_b = grad_w[layer], grad_b[layer]
                if layer_grad_w is not None:
                    _matmul_nt(grad.t(), acts[layer].t(), out=layer_grad_w[g])
                if layer_grad_b is not None:
                    th.sum(grad, dim=0, out=layer_grad_b[g])
                if layer > 0 or need_x:
                    grad = _matmul_nt(grad, weights[layer][g].t())
            if need_x:
                grad_x_groups.append(grad.to(grad_out.dtype))
        ctx.activations = None
        # the float32 parameters receive float32 gradients
        grad_w = [None if g is None else g.to(grad_out.dtype) for g in grad_w]
        grad_b = [None if g is None else g.to(grad_out.dtype) for g in grad_b]
        if grad_w[0] is not None and ctx.in_mask is not None:
            grad_w[0].mul_(ctx.in_mask)
        if ctx.out_masks is not None:
            if grad_w[-1] is not None:
                grad_w[-1].mul_(ctx.out_masks[0])
            if grad_b[-1] is not None:
                grad_b[-1].mul_(ctx.out_masks[1])
        grad_x = None
        if need_x:
            grad_x = th.stack(grad_x_groups).sum(dim=0) if ctx.shared_input else th.stack(grad_x_groups)
        return (grad_x, None, None, None, None, *grad_w, *grad_b)


def _batched_relu_layers(
    x: th.Tensor, weights: Sequence[th.Tensor], biases: Sequence[th.Tensor], inputs: list[th.Tensor] | None = None
) -> th.Tensor:
    """
    The batched path's layers of a ReLU MLP: one ``baddbmm`` per layer for all groups, ReLU between layers.

    :param x: (G, batch, in_dim) inputs.
    :param inputs: A list to append each layer's input to (for a backward pass), or None.
    """
    h = x
    for layer, (weight, bias) in enumerate(zip(weights, biases)):
        if inputs is not None:
            inputs.append(h)
        h = th.baddbmm(bias.unsqueeze(1), h, weight.transpose(1, 2))
        if layer < len(weights) - 1:
            h = h.relu_()
    return h


class _BatchedReluMLP(th.autograd.Function):
    """
    Forward and backward of all groups and layers of a ReLU MLP in one autograd node, with one batched product
    (``baddbmm``/``bmm``) per layer for all groups: the products autograd would make of the batched path, in the same
    order and on the same operands, so the results are the same bit for bit; only the graph's bookkeeping (a dozen
    nodes per call: masks, transposes, products, activations) is gone.
    """

    @staticmethod
    def forward(
        ctx: Any,
        x: th.Tensor,
        sum_groups: bool,
        in_mask: th.Tensor | None,
        out_masks: tuple[th.Tensor, th.Tensor] | None,
        *params: th.Tensor,
    ) -> th.Tensor:
        # The weights arrive unmasked: masked entries are zero and stay zero because their gradient is masked.
        n_layers = len(params) // 2
        inputs: list[th.Tensor] = []  # each layer's input (after the first, the previous layer's ReLU output)
        h = _batched_relu_layers(x, params[:n_layers], params[n_layers:], inputs)
        ctx.inputs = inputs if any(ctx.needs_input_grad) else None
        ctx.in_mask, ctx.out_masks, ctx.sum_groups = in_mask, out_masks, sum_groups
        ctx.save_for_backward(*params[:n_layers])
        return h.sum(dim=0) if sum_groups else h

    @staticmethod
    def backward(ctx: Any, grad_out: th.Tensor) -> tuple[th.Tensor | None, ...]:
        weights = ctx.saved_tensors
        n_layers = len(weights)
        needs = ctx.needs_input_grad
        need_x, need_w, need_b = needs[0], needs[4 : 4 + n_layers], needs[4 + n_layers :]
        inputs = ctx.inputs
        grad = grad_out.unsqueeze(0).expand(len(weights[0]), *grad_out.shape) if ctx.sum_groups else grad_out
        grad_w: list[th.Tensor | None] = [None] * n_layers
        grad_b: list[th.Tensor | None] = [None] * n_layers
        for layer in range(n_layers - 1, -1, -1):
            if layer < n_layers - 1:
                grad = th.ops.aten.threshold_backward(grad, inputs[layer + 1], 0)
            if need_w[layer]:  # (as autograd: the gradient of the transposed weight, transposed back)
                grad_w[layer] = th.bmm(inputs[layer].transpose(1, 2), grad).transpose(1, 2)
            if need_b[layer]:
                grad_b[layer] = grad.sum(dim=1)
            if layer > 0 or need_x:
                grad = th.bmm(grad, weights[layer])
        ctx.inputs = None
        if grad_w[0] is not None and ctx.in_mask is not None:
            grad_w[0] = grad_w[0] * ctx.in_mask
        if ctx.out_masks is not None:
            if grad_w[-1] is not None:
                grad_w[-1] = grad_w[-1] * ctx.out_masks[0]
            if grad_b[-1] is not None:
                grad_b[-1] = grad_b[-1] * ctx.out_masks[1]
        return (grad if need_x else None, None, None, None, *grad_w, *grad_b)


class _SharedGather(th.autograd.Function):
    """
    ``params.index_select(0, index)`` whose backward sums each parameter group's gradients in a fixed order (its
    evaluation groups in index order), so that a run's shared gradients do not depend on the other runs of a pack
    (``index_select``'s own backward accumulates through a sort whose order of equal keys is not fixed).
    """

    @staticmethod
    def forward(ctx: Any, params: th.Tensor, index: th.Tensor, members: th.Tensor) -> th.Tensor:
        ctx.save_for_backward(members)
        return params.index_select(0, index)

    @staticmethod
    def backward(ctx: Any, grad: th.Tensor) -> tuple[th.Tensor | None, ...]:
        (members,) = ctx.saved_tensors
        padded = th.cat([grad, grad.new_zeros(1, *grad.shape[1:])])  # row len(grad): a zero for absent members
        total = padded.index_select(0, members[:, 0])
        for k in range(1, members.shape[1]):
            total = total + padded.index_select(0, members[:, k])
        return total, None, None


def _select_groups(
    groups: slice | None,
    weights: list[th.Tensor],
    biases: list[th.Tensor],
    in_mask: th.Tensor | None,
    out_mask: th.Tensor,
    out_bias_mask: th.Tensor,
) -> tuple[list[th.Tensor], list[th.Tensor], th.Tensor | None, th.Tensor, th.Tensor]:
    """The parameters and masks of the groups to evaluate (all of them when ``groups`` is None)."""
    if groups is None:
        return weights, biases, in_mask, out_mask, out_bias_mask
    # (slicing parameters that need a gradient would cost a zero-filled copy in backward)
    return (
        [w[groups] for w in weights],
        [b[groups] for b in biases],
        None if in_mask is None else in_mask[groups],
        out_mask[groups],
        out_bias_mask[groups],
    )


class GroupedMLP(nn.Module):
    """
    ``G`` independent MLPs of the same hidden sizes, evaluated together.

    Group ``g`` reads only the input features where ``in_mask[g]`` is 1 and writes only the outputs where
    ``out_mask[g]`` is 1, so groups with different input and output sizes share one set of stacked tensors
    (no padding or gathering): the masked weights are multiplied by zero in the forward pass and never
    receive a gradient. Each group is initialised like an ``nn.Linear`` of its own fan-in. Weights have
    shape (G, out, in) and biases (G, out).

    :param in_mask: (G, in_dim) 0/1 matrix: the input features each group reads.
    :param hidden_sizes: Hidden layer sizes, shared by all groups.
    :param out_mask: (G, out_dim) 0/1 matrix: the output features each group writes.
    :param activation_fn: Activation between layers.
    :param sum_groups: Return the sum over groups, (batch, out_dim), instead of (G, batch, out_dim). With
        disjoint output masks this assembles one joint output vector.
    :param group_runs: (G,) the run each group belongs to, when several independent runs share the stacked
        tensors (see :class:`~sb3_macb.MADDPG`'s ``n_runs``); None: all groups are one run.
    :param generators: One ``torch.Generator`` per run to draw its groups' initial weights from, so that a run's
        weights do not depend on which other runs are packed with it. None: torch's global generator.
    :param group_blocks: (G,) block id of each group: consecutive groups of one id form a block that the
        optimizer updates as a tensor of its own (see :class:`~sb3_macb.common.block_adam.BlockAdam`). Default:
        ``group_runs``.
    :param param_index: (G',) for parameter sharing: evaluation group ``j`` uses parameter group ``param_index[j]``
        (the masks, runs and blocks above describe the G parameter groups). None: one parameter group per evaluation
        group. Shared parameters receive the sum of their evaluation groups' gradients.
    :param precision: ``"fp32"`` (default) or ``"bf16"``: compute the products in bfloat16 from float32 master
        weights (the parameters, their gradients and the optimizer stay float32; outputs are float32). On the oneDNN
        path only the large layers (at least ``ONEDNN_MIN_WEIGHTS`` weights) of minibatches (at least
        ``ONEDNN_MIN_ROWS`` rows) run in bfloat16, since smaller products are faster in float32; networks without a
        large layer (e.g. 64-64) compute exactly as in float32. On the batched path (other devices, activations) the
        minibatches of networks with a large layer run wholly in bfloat16. Opt-in: it pays where the CPU has native
        bfloat16 GEMMs (AVX-512 BF16, AMX) and the layers are large.
    :param large_layers: How networks with a large layer compute their products on the CPU: ``"per_group"``
        (default) one oneDNN (or MKL) product per group and layer, ``"batched"`` one batched product per layer for all
        groups, as small networks always do. Either way a run computes the same alone or in a pack; the two give
        the same results up to float32 rounding, and which is faster depends on the CPU
        (``benchmarks/update_paths.py``).
    """

    # buffers (registered in __init__)
    in_mask: th.Tensor | None
    out_mask: th.Tensor
    out_bias_mask: th.Tensor
    param_index: th.Tensor | None
    param_members: th.Tensor

    use_onednn: bool = True  # class-wide switch of the per-group GEMM path (oneDNN or MKL), taken only where it applies
    # class-wide switch of the batched path's one-node ReLU MLP (False: autograd's graph of the same products; the
    # numbers are the same either way, the switch is for tests and benchmarks)
    fused_batched: bool = True

    def __init__(
        self,
        in_mask: np.ndarray,
        hidden_sizes: list[int],
        out_mask: np.ndarray,
        activation_fn: type[nn.Module] = nn.ReLU,
        sum_groups: bool = False,
        group_runs: np.ndarray | None = None,
        generators: list[th.Generator] | None = None,
        group_blocks: np.ndarray | None = None,
        param_index: np.ndarray | None = None,
        precision: str = "fp32",
        large_layers: str = "per_group",
    ):
        super().__init__()
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {sorted(PRECISIONS)}, got {precision!r}")
        if large_layers not in LARGE_LAYER_PATHS:
            raise ValueError(f"large_layers must be one of {list(LARGE_LAYER_PATHS)}, got {large_layers!r}")
        self.precision = precision
        self.large_layers = large_layers
        self._low_dtype = PRECISIONS[precision]
        in_mask_t = th.as_tensor(np.asarray(in_mask), dtype=th.float32)
        out_mask_t = th.as_tensor(np.asarray(out_mask), dtype=th.float32)
        n_groups = in_mask_t.shape[0]
        self.n_groups = n_groups
        self.sum_groups = sum_groups
        self.activation = activation_fn()
        self._relu = activation_fn is nn.ReLU
        sizes = [in_mask_t.shape[1], *hidden_sizes, out_mask_t.shape[1]]
        fan_ins = [in_mask_t.sum(dim=1), *[th.full((n_groups,), float(h)) for h in hidden_sizes]]
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        runs = np.zeros(n_groups, dtype=np.int64) if group_runs is None else np.asarray(group_runs, dtype=np.int64)
        if runs.shape != (n_groups,):
            raise ValueError(f"group_runs must have one entry per group ({n_groups}), got shape {runs.shape}")
        run_groups = [th.as_tensor(np.flatnonzero(runs == run)) for run in range(int(runs.max()) + 1)]
        if generators is not None and len(generators) != len(run_groups):
            raise ValueError(f"Expected one generator per run ({len(run_groups)}), got {len(generators)}")
        for layer, (n_in, n_out) in enumerate(zip(sizes[:-1], sizes[1:])):
            bound = 1.0 / fan_ins[layer].clamp(min=1.0).sqrt()
            weight = th.empty(n_groups, n_out, n_in)
            bias = th.empty(n_groups, n_out)
            # each run draws its own groups (in group order) from its own generator, weights then biases
            for run, idx in enumerate(run_groups):
                gen = None if generators is None else generators[run]
                weight[idx] = th.rand(len(idx), n_out, n_in, generator=gen) * 2 - 1
                bias[idx] = th.rand(len(idx), n_out, generator=gen) * 2 - 1
            self.weights.append(nn.Parameter(weight * bound.view(n_groups, 1, 1)))
            self.biases.append(nn.Parameter(bias * bound.view(n_groups, 1)))
        # Networks with a large layer take the per-group oneDNN path (bound by arithmetic); small ones (e.g. 64-64),
        # bound by the number of calls, take one batched call per layer for all groups. The choice depends only
        # on the layer sizes, so a run computes the same way alone or in a pack.
        self._large = max(a * b for a, b in zip(sizes[:-1], sizes[1:])) >= ONEDNN_MIN_WEIGHTS
        ids = runs if group_blocks is None else np.asarray(group_blocks)
        edges = [0, *(int(g) for g in np.flatnonzero(ids[1:] != ids[:-1]) + 1), n_groups]
        self.block_bounds = list(zip(edges[:-1], edges[1:]))  # row ranges of the stacked tensors, one per block
        full_in = bool(in_mask_t.all())
        self._full_out = bool(out_mask_t.all())
        # Masks are buffers (they move with .to(device)); None when nothing is masked
        self.register_buffer("in_mask", None if full_in else in_mask_t.unsqueeze(1))
        self.register_buffer("out_mask", out_mask_t.unsqueeze(-1))
        self.register_buffer("out_bias_mask", out_mask_t)
        with th.no_grad():
            if not full_in:
                self.weights[0].mul_(self.in_mask)
            self.weights[-1].mul_(self.out_mask)
            self.biases[-1].mul_(self.out_bias_mask)
        if param_index is not None:
            index = np.asarray(param_index, dtype=np.int64)
            if index.ndim != 1 or index.min() < 0 or index.max() >= n_groups:
                raise ValueError(f"param_index must be a 1-D array of parameter groups in [0, {n_groups}), got {index}")
            self.register_buffer("param_index", th.as_tensor(index), persistent=False)
            width = int(np.bincount(index, minlength=n_groups).max())
            members = np.full((n_groups, width), len(index), dtype=np.int64)  # len(index): the zero row
            for p in range(n_groups):
                rows = np.flatnonzero(index == p)
                members[p, : len(rows)] = rows
            self.register_buffer("param_members", th.as_tensor(members), persistent=False)
        else:
            self.param_index = None

    def forward(self, x: th.Tensor, groups: slice | None = None, detach_params: bool = False) -> th.Tensor:
        """
        :param x: (batch, in_dim), the same input for every group, or (G', batch, in_dim), one per group.
        :param groups: Evaluate only these groups (e.g. the first critic of each agent).
        :param detach_params: Use the parameters without recording their gradient (input gradients only):
            used when back-propagating through a frozen network.
        :return: (G', batch, out_dim), or (batch, out_dim) with ``sum_groups``.
        """
        # (the ParameterLists' own __getitem__/__iter__ cost more than the small layers' matmuls)
        weights, biases = parameter_values(self.weights), parameter_values(self.biases)
        in_mask, out_mask, out_bias_mask = self.in_mask, self.out_mask, self.out_bias_mask
        large = (
            self._large
            and self.large_layers == "per_group"
            and self.use_onednn
            and self._relu
            and x.device.type == "cpu"
            and x.dtype == th.float32
        )
        # bfloat16 for the large layers of minibatches only: small products (small layers; acting and evaluating on
        # a few rows) are faster in float32
        use_low = self._low_dtype is not None and self._large and x.shape[-2] >= ONEDNN_MIN_ROWS
        large = large and (not use_low or _BF16_LINEAR)  # bfloat16 without oneDNN's: the batched path, cast
        low = self._low_params(weights + biases) if use_low and large else None
        if detach_params:
            weights = [w.detach() for w in weights]
            biases = [b.detach() for b in biases]
        if not large:
            if use_low:  # networks with a large layer on the batched path: cast with autograd (float32 gradients)
                dtype = self._low_dtype
                x, weights, biases = x.to(dtype), [w.to(dtype) for w in weights], [b.to(dtype) for b in biases]
                in_mask = None if in_mask is None else in_mask.to(dtype)
                out_mask, out_bias_mask = out_mask.to(dtype), out_bias_mask.to(dtype)
            masks = (in_mask, out_mask, out_bias_mask)
            if self._relu and not use_low and self.param_index is None and x.dim() == 3 and self.fused_batched:
                weights, biases, in_mask, out_mask, out_bias_mask = _select_groups(groups, weights, biases, *masks)
                if not th.is_grad_enabled() or not (x.requires_grad or (weights[0].requires_grad and not detach_params)):
                    out = _batched_relu_layers(x, weights, biases)  # (nothing to record: no autograd node at all)
                    return out.sum(dim=0) if self.sum_groups else out
                out_masks = None if self._full_out else (out_mask, out_bias_mask)
                return _BatchedReluMLP.apply(x, self.sum_groups, in_mask, out_masks, *weights, *biases)
            if self.param_index is not None:
                out = self._shared_forward(x, weights, biases, groups, *masks)
            else:
                out = self._batched(x, *_select_groups(groups, weights, biases, *masks))
            return out.float() if use_low else out
        if self.param_index is not None:  # shared parameters: each evaluation group reads its parameter group
            index = self.param_index
            weights = [_SharedGather.apply(w, index, self.param_members) for w in weights]
            biases = [_SharedGather.apply(b, index, self.param_members) for b in biases]
            low = None if low is None else [None if p is None else p.index_select(0, index) for p in low]
            in_mask = None if in_mask is None else in_mask.index_select(0, index)
            out_mask, out_bias_mask = out_mask.index_select(0, index), out_bias_mask.index_select(0, index)
        weights, biases, in_mask, out_mask, out_bias_mask = _select_groups(
            groups, weights, biases, in_mask, out_mask, out_bias_mask
        )
        if low is not None and groups is not None:
            low = [None if p is None else p[groups] for p in low]
        # masked weights are zero already; the Function masks their gradients instead of the weights
        out_masks = None if self._full_out else (out_mask, out_bias_mask)
        low_params = None if low is None else tuple(low)
        return _GroupedReluMLP.apply(x, self.sum_groups, in_mask, out_masks, low_params, *weights, *biases)

    def _batched(
        self,
        x: th.Tensor,
        weights: list[th.Tensor],
        biases: list[th.Tensor],
        in_mask: th.Tensor | None,
        out_mask: th.Tensor,
        out_bias_mask: th.Tensor,
    ) -> th.Tensor:
        """One batched product per layer for all groups (masks applied to the weights)."""
        if in_mask is not None:
            weights[0] = weights[0] * in_mask
        weights[-1] = weights[-1] * out_mask
        biases[-1] = biases[-1] * out_bias_mask

        if x.dim() == 2:
            # same input for all groups: one broadcast matmul, no copies
            h = th.matmul(x, weights[0].transpose(1, 2)).add_(biases[0].unsqueeze(1))
        else:
            h = th.baddbmm(biases[0].unsqueeze(1), x, weights[0].transpose(1, 2))
        for weight, bias in zip(weights[1:], biases[1:]):
            h = th.baddbmm(bias.unsqueeze(1), self.activation(h), weight.transpose(1, 2))
        return h.sum(dim=0) if self.sum_groups else h

    def _low_params(self, params: list[th.Tensor]) -> list[th.Tensor | None]:
        """
        Low-precision copies of the parameters of large layers (None for the small ones), made at every call: a
        parameter's version counter would tell when it changed, but fused optimizers (``_fused_adam_``) and
        ``_foreach_lerp_`` target updates do not move it, so a cached copy could go stale silently.
        """
        n_layers = len(params) // 2
        with th.no_grad():
            return [None if params[i % n_layers][0].numel() < ONEDNN_MIN_WEIGHTS else p.to(self._low_dtype)
                    for i, p in enumerate(params)]  # fmt: skip

    def _shared_forward(
        self,
        x: th.Tensor,
        weights: list[th.Tensor],
        biases: list[th.Tensor],
        groups: slice | None,
        in_mask: th.Tensor | None,
        out_mask: th.Tensor,
        out_bias_mask: th.Tensor,
    ) -> th.Tensor:
        """
        The batched path with shared parameters. Each bias enters as a weight column on a constant input, so that its
        gradient is summed over the batch inside the group's own product (a sum over a (G, batch, out) tensor rounds
        differently with the number of groups G, and a pack's run must not depend on its neighbours). MKL's batched
        GEMM may also round a matrix differently by its position in the batch, so the products run one block (one
        run, or one critic of one run) at a time: the same calls as the run alone. Masks and the bias column are
        applied to the parameter groups, before they are gathered for the evaluation groups.
        """
        if in_mask is not None:
            weights[0] = weights[0] * in_mask
        weights[-1] = weights[-1] * out_mask
        biases[-1] = biases[-1] * out_bias_mask
        assert self.param_index is not None
        augmented = [_SharedGather.apply(th.cat([w, b.unsqueeze(-1)], dim=-1), self.param_index, self.param_members)
                     for w, b in zip(weights, biases)]  # fmt: skip
        if groups is not None:
            augmented = [w[groups] for w in augmented]
        h = x.expand(len(augmented[0]), *x.shape[-2:]) if x.dim() == 2 else x
        chunk = len(self.param_index) // len(self.block_bounds)  # evaluation groups per block
        for layer, w in enumerate(augmented):
            if layer > 0:
                h = self.activation(h)
            h = th.cat([h, h.new_ones(*h.shape[:-1], 1)], dim=-1)
            if len(h) <= chunk:
                h = th.bmm(h, w.transpose(1, 2))
            else:
                h = th.cat([th.bmm(a, b.transpose(1, 2)) for a, b in zip(h.split(chunk), w.split(chunk))])
        return h.sum(dim=0) if self.sum_groups else h
