"""Tiny MLP: forward against a float64 hand computation, FLOP count against torch's flop counter."""
from __future__ import annotations

import pytest
import torch
from torch.utils.flop_counter import FlopCounterMode

from neumat.core.errors import InputError
from neumat.nn.mlp import MLP


def test_forward_matches_manual(gen):
    m = MLP(5, 7, 2, 3, activation="silu", out_activation="exp").double()
    x = torch.randn(11, 5, generator=gen, dtype=torch.float64)
    h = x
    lin = m.linears()
    assert len(lin) == 3
    for layer in lin[:-1]:
        h = h @ layer.weight.T + layer.bias
        h = h * torch.sigmoid(h)
    ref = torch.exp(h @ lin[-1].weight.T + lin[-1].bias)
    torch.testing.assert_close(m(x), ref)


@pytest.mark.parametrize("dims", [(32, 64, 2, 3), (8, 16, 0, 1), (35, 32, 3, 3)])
def test_flops_against_flop_counter(dims):
    m = MLP(*dims)
    batch = 17
    with FlopCounterMode(display=False) as fc:
        m(torch.randn(batch, dims[0]))
    matmul = fc.get_total_flops() / batch  # 2 in out per layer (multiply-adds), no activations
    acts = dims[1] * dims[2]
    assert m.flops() == matmul + acts
    assert m.num_parameters() == sum(p.numel() for p in m.parameters())


def test_neubrdf_default_mlp_counts():
    m = MLP(32, 64, 2, 3)
    assert m.num_parameters() == 32 * 64 + 64 + 64 * 64 + 64 + 64 * 3 + 3 == 6467
    assert m.flops() == 2 * (32 * 64 + 64 * 64 + 64 * 3) + 128


def test_gradients_flow_through_inplace_activation(gen):
    m = MLP(4, 8, 2, 2)
    x = torch.randn(6, 4, generator=gen, requires_grad=True)
    m(x).sum().backward()
    assert x.grad is not None and all(p.grad is not None for p in m.parameters())


def test_bad_input_raises():
    with pytest.raises(InputError, match="activation"):
        MLP(3, 4, 1, 1, activation="swish2")
    with pytest.raises(InputError, match="hidden"):
        MLP(3, 0, 1, 1)
    with pytest.raises(InputError, match="in_dim"):
        MLP(True, 4, 1, 1)
    with pytest.raises(InputError, match="last dimension"):
        MLP(3, 4, 1, 1)(torch.zeros(2, 4))


def test_start_constant_outputs_the_value_and_still_trains():
    torch.manual_seed(0)
    m = MLP(5, 16, 2, 3, "silu")
    value = torch.tensor([-1.0, 0.5, 2.0])
    m.start_constant(value)
    x = torch.randn(64, 5)
    torch.testing.assert_close(m(x), value.expand(64, 3))
    m(x).square().sum().backward()
    assert m.linears()[-1].weight.grad.abs().sum() > 0  # the zeroed layer gets gradient at once
    with pytest.raises(InputError, match="start_constant"):
        m.start_constant(torch.zeros(2))
