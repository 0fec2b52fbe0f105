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


class PhasedNeuBRDF(NeuBRDF):
    """A NeuBRDF whose steps after the first 40 % (the recommended recipe's coarse phase) take 3x longer; `started`
    holds when each step began (a class attribute: the weights' EMA copy shares it)."""

    started: dict = {}

    def on_step(self, step: int, total_steps: int) -> None:
        PhasedNeuBRDF.started.setdefault(step, time.perf_counter())
        time.sleep(0.005 if step < 0.4 * total_steps else 0.015)


def test_each_phase_announces_its_own_estimate(capsys):
    """A fit of several phases announces an estimate in each, of that phase's steps and measured on them; all but
    the last name the phases still to be measured and their steps; each estimate holds within 2x."""
    import torch

    from neumat.fit.preset import build_fit

    _, resolved = build_fit("neubrdf", "recommended", device=torch.device("cpu"), source=None, overrides={}, seed=0)
    recipe = replace(resolved.recipe, steps=120, batch_size=64, log_every=10)
    model = PhasedNeuBRDF(nside=2, index_bits=2, hidden=4, features="dense")
    PhasedNeuBRDF.started.clear()
    fit(model, parse_spec("plastic:roughness=0.3"), recipe, progress=True)
    end = time.perf_counter()
    lines = [x for x in capsys.readouterr().err.splitlines() if "to go for" in x]
    assert len(lines) == 3, lines  # coarse, dense, vq
    assert "of phase 'coarse'; then 'dense' (36 steps), 'vq' (36 steps), measured when they start" in lines[0]
    assert "of phase 'dense'; then 'vq' (36 steps), measured when it starts" in lines[1]
    assert "measured when" not in lines[2]
    for line, phase_end in zip(lines, (48, 84, 120)):  # each estimate of its own phase's remaining steps
        seconds, steps = re.search(r"about (\d+) s to go for (\d+) more steps", line).groups()
        ended = end if phase_end == 120 else PhasedNeuBRDF.started[phase_end]
        remaining = ended - PhasedNeuBRDF.started[phase_end - int(steps)]  # from the step it was announced at
        assert 0.5 * remaining <= max(int(seconds), 1) <= 2 * remaining + 1, (line, remaining)


class FakeClock:
    """The trainer's clock: seconds pass only when a step says so (so the test does not depend on the machine)."""

    now = 0.0

    @classmethod
    def perf_counter(cls) -> float:
        return cls.now

    process_time = perf_counter  # the fit's CPU seconds


class LoadedNeuBRDF(NeuBRDF):
    """A NeuBRDF whose first 24 steps take 1 s and the rest 0.05 s on the fake clock: a load on the machine that
    goes away after the announcement (the steps it was measured on)."""

    loaded = 24

    def on_step(self, step: int, total_steps: int) -> None:  # the clock when step `step` + 1 ends
        FakeClock.now = min(step + 1, self.loaded) * 1.0 + max(step + 1 - self.loaded, 0) * 0.05


def test_an_estimate_that_stops_holding_is_said_again(capsys, monkeypatch):
    """The announcement, measured on slow steps, is followed by one estimate at the later steps' speed (the steps
    between two checks after it, the slow ones left out), which holds."""
    import neumat.fit.trainer

    monkeypatch.setattr(neumat.fit.trainer, "time", FakeClock)
    FakeClock.now = 0.0
    model = LoadedNeuBRDF(nside=2, index_bits=2, hidden=4)
    recipe = replace(recipe_for("neubrdf", "paper"), steps=120, batch_size=64, log_every=10)
    fit(model, parse_spec("plastic:roughness=0.3"), recipe, progress=True)
    lines = [x for x in capsys.readouterr().err.splitlines() if "to go for" in x]
    assert len(lines) == 2, lines
    (first, unit, n1), (second, _, n2) = (re.search(r"about (\d+) (s|min) to go for (\d+) more steps", x).groups()
                                          for x in lines)
    assert (first, unit, n1) == ("2", "min", "107") and "measured on the last 11)" in lines[0]  # after 10 s: 1 s a step
    # checked 16 and 32 steps later (the steps between, 29-45, after the load): 0.05 s a step
    assert int(n2) == 75 and int(second) == round(0.05 * 75) and "measured again on the last 16:" in lines[1], lines
    faster = float(re.search(r"the steps run ([\d.]+)x faster than the estimate announced", lines[1]).group(1))
    assert faster > 1.5, lines


def test_an_estimate_that_holds_is_said_once(capsys, monkeypatch):
    """Steps at one speed (the fake clock's 0.05 s) after the warm-up: the announcement is checked and not repeated."""
    import neumat.fit.trainer

    monkeypatch.setattr(neumat.fit.trainer, "time", FakeClock)
    monkeypatch.setattr(LoadedNeuBRDF, "loaded", 2)
    FakeClock.now = 0.0
    recipe = replace(recipe_for("neubrdf", "paper"), steps=120, batch_size=64, log_every=10)
    fit(LoadedNeuBRDF(nside=2, index_bits=2, hidden=4), parse_spec("plastic:roughness=0.3"), recipe, progress=True)
    lines = [x for x in capsys.readouterr().err.splitlines() if "to go for" in x]
    assert len(lines) == 1 and "about 5 s to go for 98 more steps (measured on the last 20)" in lines[0], lines


class VerySlowNeuBRDF(NeuBRDF):
    """A NeuBRDF whose steps take 11 s each on the fake clock (online batches traced on a CPU take seconds)."""

    def on_step(self, step: int, total_steps: int) -> None:
        FakeClock.now = (step + 1) * 11.0


def test_slow_steps_are_announced_after_10_s_but_on_three_steps_at_least(capsys, monkeypatch):
    """Steps of more than 10 s: the estimate comes without waiting for 20 of them, but is measured on 3 (one step
    after a change, e.g. the first online batch, pays one-off costs)."""
    import neumat.fit.trainer

    monkeypatch.setattr(neumat.fit.trainer, "time", FakeClock)
    FakeClock.now = 0.0
    recipe = replace(recipe_for("neubrdf", "paper"), steps=40, batch_size=64, log_every=10)
    fit(VerySlowNeuBRDF(nside=2, index_bits=2, hidden=4), parse_spec("plastic:roughness=0.3"), recipe, progress=True)
    lines = [x for x in capsys.readouterr().err.splitlines() if "to go for" in x]
    assert len(lines) == 1 and "about 6 min to go for 35 more steps (measured on the last 3)" in lines[0], lines
