"""benchmarks/studies/neubrdf/neubrdf_lobe_energy.py: its albedo estimator (uniform + cone directions, balance heuristic) against
closed forms for a Lambertian BRDF, and the script end to end on a model file against its source."""
import importlib.util
import math
import subprocess
import sys
from pathlib import Path

import pytest
import torch

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "studies" / "neubrdf" / "neubrdf_lobe_energy.py"


def _module():
    spec = importlib.util.spec_from_file_location("neubrdf_lobe_energy", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("theta_o_deg", [0, 40])
def test_albedo_of_a_lambertian_brdf(theta_o_deg):
    """f = 1 / pi: albedo 1; inside a cone of half-angle a around the normal (theta_o = 0) sin^2 a."""
    cone = math.radians(10)
    q, w, in_cone = _module().albedo_samples(math.radians(theta_o_deg), cone, 2 ** 18, torch.Generator().manual_seed(1))
    assert float(w.sum() / math.pi) == pytest.approx(1.0, abs=0.01)
    if theta_o_deg == 0:
        assert float((w.squeeze(-1) * in_cone).sum() / math.pi) == pytest.approx(math.sin(cone) ** 2, rel=0.01)
    assert bool((q.wi[:, 2] > 0).all())


def test_script_on_a_model_against_itself(tmp_path):
    """A model file as its own source: every albedo ratio is +0.000 and every slice ratio 1.000."""
    from neumat.catalog.modelfile import save_model
    from neumat.methods.baselines.ggx import GGXFit

    path = save_model(GGXFit(), tmp_path / "ggx.nmat")
    out = subprocess.run([sys.executable, str(SCRIPT), str(path), str(path), "--samples", "12"], capture_output=True,
                         text=True)
    assert out.returncode == 0, out.stderr
    albedo_rows = [line for line in out.stdout.splitlines() if line.startswith("| ") and "(+0.000)" in line]
    assert len(albedo_rows) == 5 and all(line.endswith("| +0.000 (+0.000) |") for line in albedo_rows)
    slice_rows = [line for line in out.stdout.splitlines() if line.startswith("| +") or line.startswith("| -")]
    assert len(slice_rows) == 2 * 11 and all(line.endswith("| 1.000 |") for line in slice_rows)
