"""The time a fit announces is measured on the fit itself (after its warm-up steps), not a constant."""
from __future__ import annotations

import re
import time
from dataclasses import replace

from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.methods.neubrdf.model import NeuBRDF
from neumat.reflectance.spec import parse_spec


class SlowNeuBRDF(NeuBRDF):
    """A NeuBRDF whose steps take at least `delay` seconds (a sleep dominates, so the test does not depend on load)."""

    delay = 0.03

    def on_step(self, step: int, total_steps: int) -> None:
        time.sleep(self.delay)


def test_announced_time_is_within_2x_of_the_real_one(capsys):
    model = SlowNeuBRDF(nside=2, index_bits=2, hidden=4)
    recipe = replace(recipe_for("neubrdf", "paper"), steps=80, batch_size=64, log_every=10)
    t0 = time.perf_counter()
    fit(model, parse_spec("plastic:roughness=0.3"), recipe, progress=True)
    total = time.perf_counter() - t0
    line = [x for x in capsys.readouterr().err.splitlines() if "to go for" in x]
    assert len(line) == 1, line  # announced once
    seconds, steps = re.search(r"about (\d+) s to go for (\d+) more steps", line[0]).groups()
    remaining = int(steps) / 80 * total  # the real time those steps took (steps cost alike here)
    assert int(steps) < 80 and 0.5 * remaining <= max(int(seconds), 1) <= 2 * remaining + 1, (line, total)
