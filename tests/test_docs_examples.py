"""Every ```python block of README.md and docs/*.md runs as written (in a scratch folder, with `../shared`
pointing at the real-data folder beside the repository), so the documented examples cannot rot. Examples that
use Mitsuba run in a fresh interpreter (its variant is process-wide); the others run in this test process
(`runpy`, torch's random state restored afterwards), which saves each the 5-6 s of importing torch and the
first optimiser's torch._dynamo import."""
from __future__ import annotations

import os
import re
import runpy
import subprocess
import sys
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def _examples() -> list:
    cases = []
    for md in DOCS:
        for i, code in enumerate(re.findall(r"```python\n(.*?)```", md.read_text(), re.S)):
            cases.append(pytest.param(code, id=f"{md.relative_to(ROOT)}#{i}"))
    return cases


@pytest.mark.parametrize("code", _examples())
def test_documented_example_runs(code, tmp_path, request):
    if "import mitsuba" in code or "integrations import mitsuba" in code:
        from mitsuba_util import mitsuba_or_skip
        mitsuba_or_skip()  # skips with the reason when Mitsuba 3's LLVM backend is unusable
    if "../shared" in code:
        shared = request.getfixturevalue("shared_data").parent  # skips when ../shared/data is absent
        code = code.replace("../shared", str(shared))
    script = tmp_path / "example.py"
    script.write_text(code)
    if "mitsuba" in code:
        env = {**os.environ, "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
        run = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
                             timeout=300)
        assert run.returncode == 0, f"example failed:\n{code}\n--- stderr ---\n{run.stderr[-3000:]}"
        return
    monkeypatch = request.getfixturevalue("monkeypatch")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    rng = torch.get_rng_state()
    try:
        runpy.run_path(str(script), run_name="__main__")
    finally:
        torch.set_rng_state(rng)
