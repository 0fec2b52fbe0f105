"""Bit packing of small non-negative integers (codebook indices, pruning levels) for model files.

`pack_bits(values, bits)` stores every value in `bits` bits, little-endian within each value, the values one
after another, in a uint8 tensor of ceil(N bits / 8) bytes: the b-bit indices of NeuBRDF's grid take
exactly the paper's 2 n b bits (plus at most 7 of padding). `unpack_bits` inverts it.
"""
from __future__ import annotations

import torch

from neumat.core.checks import check_int
from neumat.core.errors import DataFormatError, InputError


def pack_bits(values: torch.Tensor, bits: int) -> torch.Tensor:
    """values (N,) integers in [0, 2^bits) -> uint8 (ceil(N bits / 8),)."""
    check_int(bits, "pack_bits bits")
    if bits > 31:
        raise InputError(f"pack_bits bits: expected 1 .. 31, got {bits}")
    if values.dtype.is_floating_point or values.dtype == torch.bool or values.ndim != 1:
        raise InputError(f"pack_bits values: expected a 1-d integer tensor, got {values.dtype} {tuple(values.shape)}")
    v = values.long()
    if v.numel() and (int(v.min()) < 0 or int(v.max()) >= 2 ** bits):
        raise InputError(f"pack_bits values: expected integers in [0, {2 ** bits}), got [{int(v.min())}, "
                         f"{int(v.max())}]")
    shifts = torch.arange(bits, device=v.device)
    stream = ((v.unsqueeze(-1) >> shifts) & 1).flatten().to(torch.uint8)  # (N bits,)
    stream = torch.cat([stream, stream.new_zeros(-stream.numel() % 8)]).view(-1, 8)
    return (stream << torch.arange(8, device=v.device, dtype=torch.uint8)).sum(-1, dtype=torch.uint8)


def unpack_bits(packed: torch.Tensor, bits: int, count: int, what: str = "packed values") -> torch.Tensor:
    """The `count` values (int64) that `pack_bits(values, bits)` stored in `packed`; DataFormatError naming
    `what` when `packed` does not hold ceil(count bits / 8) bytes."""
    need = -(-count * bits // 8)
    if packed.dtype != torch.uint8 or packed.ndim != 1 or packed.numel() != need:
        raise DataFormatError(f"{what}: expected {need} bytes (uint8) holding {count} values of {bits} bits, got "
                              f"{packed.dtype} {tuple(packed.shape)}")
    stream = (packed.unsqueeze(-1) >> torch.arange(8, device=packed.device, dtype=torch.uint8)) & 1
    stream = stream.flatten()[:count * bits].view(count, bits).long()
    return (stream << torch.arange(bits, device=packed.device)).sum(-1)
