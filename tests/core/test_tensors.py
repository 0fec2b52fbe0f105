import torch

from neumat.core.query import Query
from neumat.core.tensors import inference_call
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
