"""EMA of parameters against a hand computation; buffers copied; bad weights."""
from __future__ import annotations

import pytest
import torch
from torch import nn

from neumat.core.errors import InputError
from neumat.fit.ema import EMA


class Tiny(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.w = nn.Parameter(torch.tensor([1.0, -2.0], dtype=torch.float64))
        self.register_buffer("level", torch.zeros(2, dtype=torch.int8))


def test_ema_update_by_hand():
    m = Tiny()
    ema = EMA(m, 0.25)
    values = [[3.0, 2.0], [0.0, 0.0], [-1.0, 5.0]]
    shadow = [1.0, -2.0]
    for i, v in enumerate(values):
        with torch.no_grad():
            m.w.copy_(torch.tensor(v, dtype=torch.float64))
            m.level.fill_(i + 1)
        ema.update(m)
        shadow = [0.75 * s + 0.25 * x for s, x in zip(shadow, v)]
        assert ema.shadow.w.tolist() == pytest.approx(shadow, rel=1e-15)
        assert ema.shadow.level.tolist() == [i + 1, i + 1]
    # by hand: 1 -> 1.5 -> 1.125 -> 0.59375 and -2 -> -1 -> -0.75 -> 0.6875
    assert ema.shadow.w.tolist() == [0.59375, 0.6875]
    assert not ema.shadow.w.requires_grad and m.w.requires_grad
    copy = EMA(Tiny(), 0.5)
    copy.load_state_dict(ema.state_dict())
    assert torch.equal(copy.shadow.w, ema.shadow.w)


def test_ema_bad_weight_or_changed_model_raises():
    with pytest.raises(InputError, match="EMA weight"):
        EMA(Tiny(), 0.0)
    ema = EMA(Tiny(), 0.5)
    other = Tiny()
    other.extra = nn.Parameter(torch.zeros(1))
    with pytest.raises(InputError, match="no longer match"):
        ema.update(other)
