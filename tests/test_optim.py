"""fit.optim: the fit's Adam against torch.optim.AdamW step by step, and the deterministic switch."""

import pytest
import torch

from tetweave_codec.fit.optim import Adam, set_deterministic


def _pair(seed: int):
    g = torch.Generator().manual_seed(seed)
    a = torch.randn(257, 3, generator=g)
    b = torch.randn(1000, generator=g) * 1e-3
    return a, b


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_adam_matches_torch_bit_for_bit(seed):
    """Same parameters after 60 steps with changing learning rates, skipped steps and tiny or zero gradients."""
    ours = [t.clone().requires_grad_(True) for t in _pair(seed)]
    ref = [t.clone().requires_grad_(True) for t in _pair(seed)]
    opt = Adam([{"params": [ours[0]], "lr": 3e-3}, {"params": [ours[1]], "lr": 5e-4}])
    ref_opt = torch.optim.AdamW([{"params": [ref[0]], "lr": 3e-3}, {"params": [ref[1]], "lr": 5e-4}], weight_decay=0)
    g = torch.Generator().manual_seed(100 + seed)
    for it in range(60):
        target = torch.randn(257, 3, generator=g)
        scale = 0.0 if it % 7 == 3 else 10.0 ** float(torch.randint(-8, 2, (1,), generator=g))
        for params in (ours, ref):
            loss = scale * ((params[0] - target) ** 2).sum()
            if it % 5 != 4:  # the second tensor skips some steps (no gradient), as the fit's points do
                loss = loss + (params[1] ** 3).sum()
            loss.backward()
        for o in (opt, ref_opt):
            for k, group in enumerate(o.param_groups):
                group["lr"] = (3e-3, 5e-4)[k] * (1.0 + 0.5 * (it % 3))
            o.step()
            o.zero_grad(set_to_none=True)
        assert ours[0].grad is None and ours[1].grad is None
    for a, b in zip(ours, ref, strict=True):
        assert torch.equal(a.detach(), b.detach())


def test_adam_moves_by_about_the_step_and_minimizes():
    x = torch.tensor([5.0, -3.0], requires_grad=True)
    opt = Adam([{"params": [x], "lr": 0.1}])
    (x**2).sum().backward()
    opt.step()
    assert torch.allclose(x.detach(), torch.tensor([4.9, -2.9]), atol=1e-6)  # first step: lr x sign(grad)
    for _ in range(300):
        opt.zero_grad()
        (x**2).sum().backward()
        opt.step()
    assert x.detach().abs().max() < 0.05


def test_adam_rejects_negative_learning_rate():
    with pytest.raises(ValueError):
        Adam([{"params": [torch.zeros(2, requires_grad=True)], "lr": -1.0}])


def test_set_deterministic_switches_and_restores():
    was = (torch.are_deterministic_algorithms_enabled(), torch.is_deterministic_algorithms_warn_only_enabled())
    try:
        set_deterministic(True, warn_only=True)
        assert torch.are_deterministic_algorithms_enabled()
        assert torch.is_deterministic_algorithms_warn_only_enabled()
        set_deterministic(False)
        assert not torch.are_deterministic_algorithms_enabled()
    finally:
        set_deterministic(*was)
