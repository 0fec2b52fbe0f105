import copy
import pickle

import torch

from neumat.core.query import Query
from neumat.core.tensors import DEVICE_ROWS, by_rows, derived_from, inference_call, module_stamp
from neumat.methods.baselines.nbrdf import NBRDF


def _double(x: torch.Tensor) -> torch.Tensor:
    return x * 2


def test_inference_call_returns_a_plain_tensor_without_autograd():
    x = torch.ones(3)
    with torch.no_grad():
        out = inference_call(_double, x)
    assert not out.is_inference()
    out.add_(1)  # an inference tensor refuses in-place updates outside inference mode
    assert torch.equal(out, torch.full((3,), 3.0))


def test_inference_call_keeps_gradients_with_autograd_on():
    x = torch.ones(3, requires_grad=True)
    inference_call(_double, x).sum().backward()
    assert torch.equal(x.grad, torch.full((3,), 2.0))


def test_no_grad_eval_output_can_join_a_graph_later():
    torch.manual_seed(0)
    model = NBRDF()
    q = Query(torch.tensor([[0.0, 0.6, 0.8]]), torch.tensor([[0.0, -0.6, 0.8]]))
    with torch.no_grad():
        target = model.eval(q)
    loss = ((model.eval(q) - target) * target).sum()  # mul saves target for backward
    loss.backward()
    assert model.mlp.linears()[0].weight.grad is not None


class _Owner:
    """Counts how often the derived tensor is built."""

    def __init__(self, p: torch.Tensor) -> None:
        self.p, self.builds = p, 0

    def squared(self) -> torch.Tensor:
        def make():
            self.builds += 1
            return self.p * self.p
        return derived_from(self, "squared", [self.p], make)


def test_derived_from_builds_once_while_the_parameter_is_unchanged():
    owner = _Owner(torch.nn.Parameter(torch.tensor([1.0, 2.0])))
    with torch.no_grad():
        a, b = owner.squared(), owner.squared()
    assert a is b and owner.builds == 1 and not a.requires_grad
    with torch.inference_mode():  # kept from before, still a plain tensor
        assert owner.squared() is a and not a.is_inference()


def test_derived_from_rebuilds_after_a_step_an_in_place_update_or_a_new_dtype():
    p = torch.nn.Parameter(torch.tensor([1.0, 2.0]))
    owner = _Owner(p)
    with torch.no_grad():
        owner.squared()
    p.grad = torch.tensor([1.0, 1.0])
    torch.optim.Adam([p], lr=0.5, fused=True).step()  # in place, and the fused kernel leaves p._version as it was
    with torch.no_grad():
        assert torch.allclose(owner.squared(), torch.tensor([0.25, 2.25])) and owner.builds == 2
        p.copy_(torch.tensor([3.0, 4.0]))
        assert torch.equal(owner.squared(), torch.tensor([9.0, 16.0])) and owner.builds == 3
        owner.p = p.double()
        assert owner.squared().dtype == torch.float64 and owner.builds == 4


def test_derived_from_keeps_the_gradient_when_one_is_wanted():
    p = torch.nn.Parameter(torch.tensor([1.0, 2.0]))
    owner = _Owner(p)
    with torch.no_grad():
        owner.squared()
    owner.squared().sum().backward()  # autograd on: built afresh, in the graph
    assert owner.builds == 2 and torch.equal(p.grad, torch.tensor([2.0, 4.0]))


def test_by_rows_slices_for_the_cpu_cache_only_on_the_cpu():
    """CPU tensors go in slices of `chunk` rows; on any other device (here "meta", standing in for a GPU, where each
    slice costs its kernels' launches) in slices of chunk * 128 rows, at most DEVICE_ROWS, and never fewer than
    chunk; a Query is sliced by its wi's device."""
    sizes = []

    def fn(t):
        sizes.append(len(t))
        return t * 2

    n = 3 * 2 ** 13 + 5
    by_rows(fn, 2 ** 13, torch.ones(n, 3))
    assert sizes == [2 ** 13] * 3 + [5]
    sizes.clear()
    out = by_rows(fn, 2 ** 13, torch.ones(n, 3, device="meta"))
    assert sizes == [n] and out.device.type == "meta"
    sizes.clear()
    by_rows(fn, 2 ** 14, torch.ones(DEVICE_ROWS + 1, 3, device="meta"))
    assert sizes == [DEVICE_ROWS, 1]
    sizes.clear()
    by_rows(fn, 512, torch.ones(2 ** 17, 3, device="meta"))  # NeuPreSS's CPU slices: 2^16 on a GPU
    assert sizes == [2 ** 16, 2 ** 16]
    sizes.clear()
    up = torch.tensor([0.0, 0.0, 1.0]).expand(40, 3)
    by_rows(lambda q: fn(q.wi), 16, Query(up, up))  # a Query (checked, so not on "meta"): its wi's device, the CPU
    assert sizes == [16, 16, 8]


def test_module_stamp_follows_a_functional_call_swap_and_copies_collect_their_own():
    from neumat.models.half_precision import with_half_parameters
    model = NBRDF(hidden=8)
    weight = next(model.parameters())
    before = module_stamp(model)
    seen = with_half_parameters(model, lambda: module_stamp(model))  # the swapped (non-leaf) tensors
    assert seen[3] != before[3]
    assert module_stamp(model)[2:] == before[2:]  # the model's own tensors again, not the swap's leftovers
    with torch.no_grad():
        weight.add_(1.0)
    assert module_stamp(model)[2] != before[2]  # an in-place update of a real parameter is seen
    for twin in (copy.deepcopy(model), pickle.loads(pickle.dumps(model))):
        assert module_stamp(twin)[3] == tuple(p.data_ptr() for p in twin.parameters())
