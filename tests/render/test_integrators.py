"""The direct-lighting integrator's helpers."""
from __future__ import annotations

import torch


def test_below_one_keeps_rounded_up_numbers_inside_the_unit_interval():
    """float64 uniforms cast to float32 can round up to 1.0, which Material.sample refuses."""
    from neumat.render.integrators import below_one

    u = torch.tensor([0.0, 0.5, 1.0 - 1e-12], dtype=torch.float64).float()
    assert u[2] == 1.0
    out = below_one(u)
    assert (out[2] < 1 and out[2] == torch.nextafter(torch.tensor(1.0), torch.tensor(0.0))
            and torch.equal(out[:2], u[:2]))
