"""Adam (Kingma & Ba 2015) on the fit's few tensors, and deterministic kernels, without torch's compiler stack.

Why not `torch.optim.AdamW`: its constructor imports torch._dynamo, and `torch.use_deterministic_algorithms` imports
torch._inductor's config; each costs ~1.7 s per process on the 2-core CI machines, ~6 % of a 16K-point encode
and more of a small one, for machinery the fit never uses (nothing is compiled). The fit needs plain Adam without
weight decay on two or three tensors.

The arithmetic is torch's single-tensor Adam (`torch/optim/adam.py`, `_single_tensor_adam`, the path torch takes
for CPU tensors), operation by operation and in the same order, so a CPU fit makes the same bytes as with
torch.optim (tests/test_optim.py compares the two step by step). On CUDA torch would take its multi-tensor path,
whose rounding can differ in the last bit; files made on a GPU never promised the CPU's bytes.
"""

from __future__ import annotations

from collections.abc import Iterable

import torch
from torch import Tensor

BETA1 = 0.9  # torch's defaults
BETA2 = 0.999
EPS = 1e-8


class Adam:
    """Adam without weight decay over parameter groups ``{"params": [Tensor, ...], "lr": float}``.

    The subset of `torch.optim.Optimizer` the fit uses: `param_groups` (whose "lr" may be changed between steps),
    `step()` (skips tensors without a gradient, like torch) and `zero_grad(set_to_none=True)`.
    """

    def __init__(self, groups: Iterable[dict]):
        self.param_groups = [{**group, "params": list(group["params"])} for group in groups]
        for group in self.param_groups:
            if group["lr"] < 0:
                raise ValueError(f"invalid learning rate {group['lr']}")
        self._state: dict[int, tuple[Tensor, Tensor, list[int]]] = {}

    @torch.no_grad()
    def step(self) -> None:
        """One Adam step on every parameter that has a gradient."""
        for group in self.param_groups:
            lr = group["lr"]
            for param in group["params"]:
                grad = param.grad
                if grad is None:
                    continue
                state = self._state.get(id(param))
                if state is None:
                    zeros = (torch.zeros_like(param, memory_format=torch.preserve_format) for _ in range(2))
                    state = (*zeros, [0])
                    self._state[id(param)] = state
                exp_avg, exp_avg_sq, count = state
                count[0] += 1
                step = float(count[0])
                exp_avg.lerp_(grad, 1 - BETA1)
                exp_avg_sq.mul_(BETA2).addcmul_(grad, grad, value=1 - BETA2)
                step_size = lr / (1 - BETA1**step)
                bias_correction2_sqrt = (1 - BETA2**step) ** 0.5
                denom = (exp_avg_sq.sqrt() / bias_correction2_sqrt).add_(EPS)
                param.addcdiv_(exp_avg, denom, value=-step_size)

    def zero_grad(self, set_to_none: bool = True) -> None:
        """Drop (or zero) the gradients of every parameter."""
        for group in self.param_groups:
            for param in group["params"]:
                if param.grad is None:
                    continue
                if set_to_none:
                    param.grad = None
                else:
                    param.grad.zero_()


def set_deterministic(enabled: bool, warn_only: bool = False) -> None:
    """`torch.use_deterministic_algorithms(enabled, warn_only=...)` without importing torch._inductor.

    The public function also sets the inductor's flag for compiled code, and importing that config costs ~1.7 s;
    nothing here is compiled. Falls back to the public function where torch lacks the internal setter.
    """
    setter = getattr(torch._C, "_set_deterministic_algorithms", None)
    if setter is None:
        torch.use_deterministic_algorithms(enabled, warn_only=warn_only)
    else:
        setter(enabled, warn_only=warn_only)
