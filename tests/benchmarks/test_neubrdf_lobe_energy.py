"""benchmarks/studies/neubrdf/neubrdf_lobe_energy.py end to end on a model file against itself (its estimator,
`neumat.testing.furnace.mirror_cone_samples`, is tested in tests/testing/test_furnace_reciprocity.py)."""
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "studies" / "neubrdf" / "neubrdf_lobe_energy.py"


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
