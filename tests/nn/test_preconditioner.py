import numpy as np
import pytest
import torch

from neumat.core.errors import InputError
from neumat.nn.preconditioner import FrequencyPreconditioner, precondition, unprecondition


def _explicit(raw: np.ndarray, strength: float) -> np.ndarray:
    """Reference with numpy's full complex FFT, the kernel built from its own frequency grid."""
    h, w = raw.shape[-2:]
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.fftfreq(w)[None, :]
    k = 1 / (1 + strength * np.sqrt(fx ** 2 + fy ** 2))
    return np.real(np.fft.ifft2(np.fft.fft2(raw) * k))


@pytest.mark.parametrize("shape, strength", [((3, 16, 16), 10.0), ((2, 9, 24), 5.0), ((1, 1, 7), 5.0)])
def test_matches_explicit_fft(shape, strength):
    raw = torch.randn(shape, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    got = precondition(raw, strength)
    np.testing.assert_allclose(got.numpy(), _explicit(raw.numpy(), strength), atol=1e-12)


def test_is_a_circular_convolution_keeping_the_mean():
    """Spatial-domain check: the texture is the circular convolution of raw with the kernel's inverse FFT."""
    raw = torch.randn(1, 8, 8, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    delta = torch.zeros(1, 8, 8, dtype=torch.float64)
    delta[0, 0, 0] = 1
    kernel = precondition(delta, 10.0)[0]
    ref = torch.zeros(8, 8, dtype=torch.float64)
    for i in range(8):
        for j in range(8):
            ref += raw[0, i, j] * torch.roll(kernel, (i, j), (0, 1))
    torch.testing.assert_close(precondition(raw, 10.0)[0], ref)
    torch.testing.assert_close(precondition(raw, 10.0).mean(), raw.mean())


def test_inverse_and_gradient():
    raw = torch.randn(2, 8, 12, dtype=torch.float64, requires_grad=True)
    tex = precondition(raw, 5.0)
    torch.testing.assert_close(unprecondition(tex, 5.0), raw.detach())
    assert torch.autograd.gradcheck(lambda x: precondition(x, 5.0), (raw,))


def test_module_and_bad_strength():
    raw = torch.randn(1, 4, 4)
    assert torch.equal(FrequencyPreconditioner(0.0)(raw), raw)
    with pytest.raises(InputError, match="strength"):
        FrequencyPreconditioner(-1.0)


def test_flat_matches_per_texture_preconditioning_with_gradients():
    """`flat` (FFT for large textures, one block-diagonal matrix for small ones) equals `precondition` of every
    texture, values and gradients, for a mip pyramid and for non-square / unordered sizes."""
    g = torch.Generator().manual_seed(1)
    for shapes in ([(3, 32 >> l, 32 >> l) for l in range(6)], [(2, 3, 5), (2, 24, 20), (2, 1, 1), (2, 16, 16)]):
        raws = [torch.randn(s, dtype=torch.float64, generator=g, requires_grad=True) for s in shapes]
        module = FrequencyPreconditioner(10.0)
        got = module.flat(raws)
        ref = torch.cat([precondition(r, 10.0).reshape(shapes[0][0], -1) for r in raws], 1)
        torch.testing.assert_close(got, ref, rtol=1e-12, atol=1e-12)
        weight = torch.randn(got.shape, dtype=torch.float64, generator=g)
        a = torch.autograd.grad((got * weight).sum(), raws)
        b = torch.autograd.grad((ref * weight).sum(), raws)
        for x, y in zip(a, b):
            torch.testing.assert_close(x, y, rtol=1e-12, atol=1e-12)
        torch.testing.assert_close(module.flat(raws), got)  # cached matrix / kernels reused
    assert torch.equal(FrequencyPreconditioner(0.0).flat(raws), torch.cat([r.reshape(2, -1) for r in raws], 1))


@pytest.mark.parametrize("shape", [(2, 16, 16), (3, 6, 5), (1, 7, 8), (2, 1, 1), (1, 2, 9)])
def test_module_backward_is_the_same_filter_as_autograds(shape):
    """The module's backward (the filter itself: the map is symmetric) equals autograd's gradient of
    `precondition` (float64), for even and odd sizes; gradcheck passes."""
    g = torch.Generator().manual_seed(3)
    raw = torch.randn(shape, dtype=torch.float64, generator=g, requires_grad=True)
    weight = torch.randn(shape, dtype=torch.float64, generator=g)
    module = FrequencyPreconditioner(10.0)
    (got,) = torch.autograd.grad((module(raw) * weight).sum(), raw)
    (want,) = torch.autograd.grad((precondition(raw, 10.0) * weight).sum(), raw)
    torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(module(raw), precondition(raw, 10.0), rtol=1e-12, atol=1e-12)
    assert torch.autograd.gradcheck(module, (raw,))
