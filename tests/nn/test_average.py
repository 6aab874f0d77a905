import pytest

torch = pytest.importorskip("torch")

from geoface.nn.average import WeightAverage  # noqa: E402
from geoface.nn.errors import NNError  # noqa: E402


def test_weight_average_is_the_bias_corrected_exponential_average():
    lin = torch.nn.Linear(2, 1)
    avg = WeightAverage(lin, 0.5)
    with pytest.raises(NNError, match="no update"):
        avg.copy_to(lin)
    for v in (1.0, 2.0, 3.0):
        with torch.no_grad():
            lin.weight.fill_(v)
            lin.bias.fill_(-v)
        avg.update(lin)
    avg.copy_to(lin)
    want = (0.25 * 1 + 0.5 * 2 + 1 * 3) / 1.75  # weights 0.5^age over the three updates, normalised
    assert torch.allclose(lin.weight, torch.full((1, 2), want)) and torch.allclose(lin.bias, torch.tensor([-want]))
    last = WeightAverage(lin, 0.0)  # decay 0: the last values
    with torch.no_grad():
        lin.weight.fill_(7.0)
    last.update(lin)
    with torch.no_grad():
        lin.weight.fill_(0.0)
    last.copy_to(lin)
    assert torch.all(lin.weight == 7.0)
    with torch.no_grad():
        lin.weight = torch.nn.Parameter(torch.zeros(3, 2))
    with pytest.raises(NNError, match="changed shape"):
        last.update(lin)
