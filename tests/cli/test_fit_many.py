"""`neumat fit-many`: fault isolation, resume and worker loss, on a local Ray instance of 2 CPUs (started once for
the module) and one after another in the process (--engine local)."""
from __future__ import annotations

import json
import os
import signal
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import typer
from rich.console import Console
from typer.testing import CliRunner

from neumat.catalog.modelfile import save_model
from neumat.cli import fit_many
from neumat.cli.fit_engines import RunProgress, run_ray
from neumat.cli import fit_job as fit_job_module
from neumat.cli.fit_job import FitJob, run_fit_job
from neumat.methods.baselines.ggx import GGXFit

FAST = ["-m", "ggx", "--steps", "10", "--set", "batch_size=256", "--n-configs", "2048", "--image-spp", "1",
        "--image-resolution", "8", "--device", "cpu"]


@pytest.fixture
def app() -> typer.Typer:
    app = typer.Typer(pretty_exceptions_enable=False, add_completion=False)
    fit_many.register(app)
    return app


@pytest.fixture(scope="module")
def ray_2cpu():
    """A local Ray instance of 2 CPUs for the module's tests; fit-many runs on it and leaves it running."""
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, object_store_memory=200 * 2 ** 20, log_to_driver=False)
    yield ray
    ray.shutdown()


def _teachers(folder: Path, n: int) -> list[str]:
    """`n` different GGX materials saved as .nmat: small file sources."""
    folder.mkdir(exist_ok=True)
    out = []
    for i in range(n):
        torch.manual_seed(i)
        out.append(str(save_model(GGXFit(init_alpha=0.1 + 0.2 * i), folder / f"teacher{i}.nmat")))
    return out


def _rows(out: Path) -> dict[str, dict]:
    return {r["name"]: r for r in json.loads((out / "results.json").read_text())["rows"]}


@pytest.mark.parametrize("engine", ["local", pytest.param("ray", marks=pytest.mark.slow)])
def test_three_good_sources_and_a_corrupt_one_then_a_rerun_fits_only_the_failed(app, tmp_path, request, engine):
    """The same rows from both engines; the Ray run (about 3 minutes of Ray start-up on a loaded 2-core machine) is
    `slow`, as are the killed-worker tests below (`make test-slow`)."""
    if engine == "ray":
        request.getfixturevalue("ray_2cpu")
    sources = _teachers(tmp_path / "src", 3)
    (tmp_path / "src" / "corrupt.binary").write_bytes(b"\x00\x01 not a MERL table" * 100)
    out = tmp_path / "out"
    res = CliRunner().invoke(app, [str(tmp_path / "src"), *FAST, "--engine", engine, "-o", str(out)])
    assert res.exit_code == 1, res.output  # some job failed
    rows = _rows(out)
    assert sorted(rows) == ["corrupt", "teacher0", "teacher1", "teacher2"]
    for name in ("teacher0", "teacher1", "teacher2"):
        r = rows[name]
        assert r["status"] == "ok" and r["error"] is None and r["model"] == "ggx", r
        assert 0 <= r["metrics"]["rmse_hdr"] < 1 and "img_flip" in r["metrics"] and r["bytes_fp16"] > 0
        assert Path(r["nmat"]).is_file() and r["source"] in sources and len(r["source_sha256"]) == 64
        assert r["worker"] and r["device"] == "cpu" and r["fit_seconds"] > 0 and r["recipe"]["steps"] == 10
        # CPU seconds beside wall seconds: the fit's within its job's
        assert 0 < r["fit_cpu_seconds"] < r["cpu_seconds"] and 0 < r["fit_seconds"] < r["seconds"]
        assert r["picture"] == str(out / f"{name}.ggx.png") and f"![{name} x ggx]({name}.ggx.png)" in (
            out / "results.md").read_text()
    assert rows["corrupt"]["status"] == "error" and "DataFormatError" in rows["corrupt"]["error"]
    assert not (out / "corrupt.ggx.nmat").exists()
    assert "corrupt" in (out / "results.md").read_text() and "| ggx | 3 | 1 |" in (out / "results.md").read_text()

    mtimes = {n: Path(r["nmat"]).stat().st_mtime_ns for n, r in rows.items() if r["status"] == "ok"}
    res = CliRunner().invoke(app, [str(tmp_path / "src"), *FAST, "--engine", engine, "-o", str(out)])
    assert res.exit_code == 1 and "3 already done (kept), 1 to fit" in " ".join(res.output.split()), res.output
    again = _rows(out)
    assert {n: Path(again[n]["nmat"]).stat().st_mtime_ns for n in mtimes} == mtimes
    assert again["corrupt"]["status"] == "error"


def test_changed_source_or_options_are_fitted_again(app, tmp_path):
    src = _teachers(tmp_path / "src", 2)
    out = tmp_path / "out"
    args = [*src, *FAST, "--engine", "local", "-o", str(out)]
    assert CliRunner().invoke(app, args).exit_code == 0
    save_model(GGXFit(init_alpha=0.9), src[1])  # the source changes: its hash no longer matches
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0 and "1 already done (kept), 1 to fit" in " ".join(res.output.split()), res.output
    res = CliRunner().invoke(app, [*args, "--steps", "11"])  # other options: everything again
    assert "0 already done (kept), 2 to fit" in " ".join(res.output.split()), res.output
    assert all(r["steps"] == 11 for r in _rows(out).values())


def test_a_changed_default_is_fitted_again(app, tmp_path, monkeypatch):
    """The same command after a recipe's default changed (e.g. an upgrade) fits again: the row holds a hash of the
    recipe contents and model Config defaults it was fitted with; unchanged defaults keep it, and a row written
    before that hash existed is kept too."""
    import dataclasses

    from neumat.fit.method import recipe_for

    src = _teachers(tmp_path / "src", 1)
    out = tmp_path / "out"
    args = [*src, *FAST, "--engine", "local", "-o", str(out)]
    assert CliRunner().invoke(app, args).exit_code == 0
    (row,) = _rows(out).values()
    assert len(row["defaults_sha256"]) == 64
    changed = dataclasses.replace(recipe_for("ggx", "cpu"), lr_min=1e-7)
    monkeypatch.setattr("neumat.fit.method.recipe_for", lambda model, name="paper":
                        changed if (model, name) == ("ggx", "cpu") else recipe_for(model, name))
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0 and "0 already done (kept), 1 to fit" in " ".join(res.output.split()), res.output
    (refit,) = _rows(out).values()
    assert refit["defaults_sha256"] != row["defaults_sha256"] and refit["nmat_sha256"]
    res = CliRunner().invoke(app, args)
    assert "1 already done (kept), 0 to fit" in " ".join(res.output.split()), res.output
    results = json.loads((out / "results.json").read_text())
    legacy = {k: v for k, v in refit.items() if k != "defaults_sha256"}
    (out / "results.json").write_text(json.dumps(results | {"rows": [legacy]}))
    monkeypatch.setattr("neumat.fit.method.recipe_for", recipe_for)
    res = CliRunner().invoke(app, args)
    assert "1 already done (kept), 0 to fit" in " ".join(res.output.split()), res.output


def test_reference_renderings_are_kept_for_later_runs_and_other_processes(app, tmp_path, monkeypatch):
    """The image metrics' reference renderings are kept (OUT/reference-renders by default, --reference-cache for a
    folder several runs share): a later run with another model renders no reference and scores against the same
    one (the same floor); another source, or a changed source, gets its own file; an unreadable file is rendered
    again."""
    from neumat.cli import fit_job as fit_job_module
    from neumat.render import comparison

    src = _teachers(tmp_path / "src", 2)
    out, cache = tmp_path / "out", tmp_path / "cache"
    fit_job_module._REFERENCE_RENDERS.clear()  # another test's teachers are the same files
    rendered = []
    real = comparison.reference_renders
    monkeypatch.setattr(comparison, "reference_renders", lambda *a, **k: rendered.append(1) or real(*a, **k))
    assert CliRunner().invoke(app, [src[0], *FAST, "--engine", "local", "-o", str(out)]).exit_code == 0
    assert len(rendered) == 1 and len(list((out / "reference-renders").glob("*.pt"))) == 1
    first = _rows(out)["teacher0"]["metrics"]
    other = [src[0], *FAST, "-m", "nbrdf", "--steps", "2", "--engine", "local", "-o", str(out)]
    fit_job_module._REFERENCE_RENDERS.clear()  # a new process: only the folder holds it
    assert CliRunner().invoke(app, other).exit_code == 0
    assert len(rendered) == 1
    again = {r["model"]: r for r in json.loads((out / "results.json").read_text())["rows"]}["nbrdf"]["metrics"]
    assert again["img_floor_mae"] == first["img_floor_mae"]
    shared = [*FAST, "--engine", "local", "--reference-cache", str(cache)]
    assert CliRunner().invoke(app, [src[1], *shared, "-o", str(tmp_path / "a")]).exit_code == 0
    assert len(rendered) == 2 and len(list(cache.glob("*.pt"))) == 1
    fit_job_module._REFERENCE_RENDERS.clear()
    assert CliRunner().invoke(app, [src[1], *shared, "-o", str(tmp_path / "b")]).exit_code == 0
    assert len(rendered) == 2                                # the other output folder found it in the shared one
    save_model(GGXFit(init_alpha=0.7), src[1])               # the source changes: its renderings are new ones
    fit_job_module._REFERENCE_RENDERS.clear()
    assert CliRunner().invoke(app, [src[1], *shared, "-o", str(tmp_path / "b")]).exit_code == 0
    assert len(rendered) == 3 and len(list(cache.glob("*.pt"))) == 2
    for path in cache.glob("*.pt"):
        path.write_bytes(b"cut off")
    fit_job_module._REFERENCE_RENDERS.clear()
    assert CliRunner().invoke(app, [src[1], *shared, "--steps", "3", "-o", str(tmp_path / "b")]).exit_code == 0
    assert len(rendered) == 4


def test_threads_set_torch_threads_for_each_job_only_and_keep_the_rows(app, tmp_path, monkeypatch):
    """--threads N: each job runs with N torch threads and restores the caller's afterwards; it changes no hash,
    so a rerun with another --threads keeps every row."""
    src = _teachers(tmp_path / "src", 2)
    out = tmp_path / "out"
    args = [*src, *FAST, "--engine", "local", "-o", str(out)]
    before = torch.get_num_threads()
    seen = []
    real_fit = fit_job_module._fit_and_evaluate
    monkeypatch.setattr(fit_job_module, "_fit_and_evaluate",
                        lambda job, sha: (seen.append(torch.get_num_threads()), real_fit(job, sha))[1])
    torch.set_num_threads(2)
    try:
        assert CliRunner().invoke(app, [*args, "--threads", "1"]).exit_code == 0
        assert seen == [1, 1] and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
    res = CliRunner().invoke(app, [*args, "--threads", "2"])
    assert res.exit_code == 0 and "2 already done (kept), 0 to fit" in " ".join(res.output.split()), res.output
    assert CliRunner().invoke(app, [*args, "--threads", "0"]).exit_code == 2


def test_changed_evaluation_options_evaluate_the_saved_models_again_without_refitting(app, tmp_path):
    """--image-spp changed: the saved models are evaluated again (same .nmat, fit seconds and recipe kept, new
    image metrics with the reference's noise floor); a row written before fit_sha256 existed (only its options
    hash of that time) is recognised as fitted too."""
    src = _teachers(tmp_path / "src", 1)
    out = tmp_path / "out"
    args = [*src, *FAST, "--engine", "local", "-o", str(out)]
    assert CliRunner().invoke(app, args).exit_code == 0
    (first,) = _rows(out).values()
    res = CliRunner().invoke(app, [*args, "--image-spp", "2"])
    text = " ".join(res.output.split())
    assert res.exit_code == 0 and "1 to fit (1 of them fitted before: evaluated again)" in text, res.output
    (again,) = _rows(out).values()
    assert again["nmat_sha256"] == first["nmat_sha256"] and again["fit_seconds"] == first["fit_seconds"]
    assert again["fit_cpu_seconds"] == first["fit_cpu_seconds"] and again["cpu_seconds"] != first["cpu_seconds"]
    assert again["recipe"] == first["recipe"] and again["steps"] == first["steps"]
    assert again["metrics"]["img_mae"] != first["metrics"]["img_mae"] and "img_floor_mae" in again["metrics"]
    assert again["metrics"]["log_err"] == first["metrics"]["log_err"]  # same model, same queries

    job = FitJob(source=src[0], name="teacher0", model="ggx", out_dir=str(out), steps=10,
                 overrides={"batch_size": 256}, device="cpu", eval_n=2048, image_spp=2, image_resolution=8)
    assert job.fit_sha256() == again["fit_sha256"] and job.options_sha256() == again["options_sha256"]
    legacy = {k: v for k, v in again.items() if k != "fit_sha256"} | {"options_sha256": job.legacy_options_sha256()}
    results = json.loads((out / "results.json").read_text())
    (out / "results.json").write_text(json.dumps(results | {"rows": [legacy]}))
    res = CliRunner().invoke(app, [*args, "--image-spp", "2"])
    assert "(1 of them fitted before: evaluated again)" in " ".join(res.output.split()), res.output
    assert _rows(out)["teacher0"]["nmat_sha256"] == first["nmat_sha256"]


def test_each_fit_gets_its_picture_and_a_rerun_without_it_evaluates_again_without_refitting(app, tmp_path):
    """Evaluated on images, a fit's picture is OUT/<source>.<model>.png: reference | model | FLIP error | the floor's
    FLIP error, with the row's scores; a row whose picture is gone (or made before pictures existed) is evaluated
    again, keeping its fit, and the same scores come back (the same renders)."""
    from PIL import Image

    src = _teachers(tmp_path / "src", 1)
    out = tmp_path / "out"
    args = [*src, *FAST, "--image-spp", "2", "--image-resolution", "16", "--engine", "local", "-o", str(out)]
    assert CliRunner().invoke(app, args).exit_code == 0
    (first,) = _rows(out).values()
    picture = np.asarray(Image.open(first["picture"]))
    assert picture.shape[1] == 4 * 160 + 5 * 4 and picture.std() > 0  # four panels of 16 px enlarged 10x, not blank
    Path(first["picture"]).unlink()
    res = CliRunner().invoke(app, args)
    assert "1 to fit (1 of them fitted before: evaluated again)" in " ".join(res.output.split()), res.output
    (again,) = _rows(out).values()
    assert again["nmat_sha256"] == first["nmat_sha256"] and again["metrics"] == first["metrics"]
    assert np.array_equal(np.asarray(Image.open(again["picture"])), picture)
    res = CliRunner().invoke(app, args)  # with its picture: kept
    assert "1 already done (kept), 0 to fit" in " ".join(res.output.split()), res.output


def test_preset_cpu_fits_with_the_cpu_recipe_and_counts_as_other_options(app, tmp_path):
    """--preset cpu: each model's CPU path (neubrdf: 2^13 queries a step, not the paper's 2^14); a rerun with the
    paper's preset fits again; a paper-preset row's options hash of before the image protocol was hashed does not
    mention the preset (results written before the option existed are recognised); the default is recommended."""
    from neumat.fit.method import recipe_for

    out = tmp_path / "out"
    args = ["ggx:roughness=0.3", "-m", "neubrdf", "--steps", "2", "--set", "nside=2", "--set", "index_bits=3",
            "--set", "hidden=8", "--n-configs", "2048", "--image-spp", "0", "--device", "cpu", "--engine", "local",
            "-o", str(out)]
    res = CliRunner().invoke(app, [*args, "--preset", "cpu"])
    assert res.exit_code == 0, res.output
    (row,) = _rows(out).values()
    assert row["recipe"]["batch_size"] == recipe_for("neubrdf", "cpu").batch_size != recipe_for("neubrdf").batch_size
    from neumat.catalog.modelfile import load_model
    saved = load_model(row["nmat"])
    assert saved.is_runtime and saved.cfg.interpolation == "uniform"  # the shipped form, as `neumat fit` writes
    res = CliRunner().invoke(app, [*args, "--preset", "paper"])
    assert "0 already done (kept), 1 to fit" in " ".join(res.output.split()), res.output
    (row,) = _rows(out).values()
    assert row["recipe"]["batch_size"] == recipe_for("neubrdf").batch_size
    import hashlib
    from dataclasses import asdict

    job = FitJob(source="s", name="s", model="ggx", out_dir=str(tmp_path), preset="paper")
    before = {k: v for k, v in asdict(job).items()
              if k not in ("source", "name", "out_dir", "device", "preset", "evaluate_only", "threads",
                           "reference_cache")}
    assert job.legacy_options_sha256() == hashlib.sha256(json.dumps(before, sort_keys=True).encode()).hexdigest()
    assert job.options_sha256() != FitJob(source="s", name="s", model="ggx", out_dir=str(tmp_path),
                                          preset="cpu").options_sha256()
    assert FitJob(source="s", name="s", model="ggx", out_dir=str(tmp_path)).preset == "recommended"
    bad = CliRunner().invoke(app, [*args, "--preset", "gpu"])
    assert bad.exit_code == 2 and "model neubrdf has no preset 'gpu'" in " ".join(bad.output.split())


def test_model_presets_scope_a_preset_to_one_model():
    """fit-many --preset: a plain value for every model, MODEL:NAME for one (it wins), recommended by default;
    each checked against that model's presets; a scope naming no --model is refused."""
    from neumat.cli.fit_many import model_presets
    from neumat.core.errors import InputError, UnknownNameError

    models = ["neubrdf", "ggx"]
    assert model_presets([], models) == {"neubrdf": "recommended", "ggx": "recommended"}
    assert model_presets(["cpu", "neubrdf:dense"], models) == {"neubrdf": "dense", "ggx": "cpu"}
    assert model_presets(["neubrdf:dense"], models) == {"neubrdf": "dense", "ggx": "recommended"}
    with pytest.raises(UnknownNameError, match="model ggx has no preset 'dense'"):
        model_presets(["dense"], models)
    with pytest.raises(InputError, match="--preset: nbrdf is not one of the --model values"):
        model_presets(["nbrdf:cpu"], models)


class KillFirstAttempt:
    """A fit-many task that kills its own worker process (SIGKILL) the first time it runs `victim`; it logs
    every call's source to `log`."""

    def __init__(self, victim: str, log: Path):
        self.victim, self.log = victim, log

    def __call__(self, job: FitJob) -> dict:
        with open(self.log, "a") as f:
            f.write(job.source + "\n")
        marker = self.log.with_suffix(".killed")
        if job.source == self.victim and not marker.exists():
            marker.touch()
            os.kill(os.getpid(), signal.SIGKILL)
        return run_fit_job(job)


@pytest.mark.slow  # 5 s idle, 150-170 s on a 2-core machine under two busy loops (Ray's retry of a dead worker);
# the default run keeps Ray's worker-death path through the next test
def test_a_killed_worker_loses_only_its_task_which_is_retried(ray_2cpu, tmp_path):
    ray_2cpu.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the task class lives in this test
    sources = _teachers(tmp_path / "src", 2)  # two jobs: each Ray worker start costs seconds (minutes under load)
    jobs = [FitJob(source=s, name=Path(s).stem, model="ggx", out_dir=str(tmp_path), overrides={"batch_size": 256},
                   steps=10, device="cpu", eval_n=2048, image_spp=0) for s in sources]
    log = tmp_path / "calls.log"
    progress = RunProgress(len(jobs), Console(file=open(os.devnull, "w")))
    rows = list(run_ray(jobs, KillFirstAttempt(sources[1], log), progress, workers=None, address=None,
                        gpus_per_task=0.0, retries=1, log=lambda text: None))
    assert sorted(r["name"] for r in rows) == ["teacher0", "teacher1"]
    assert all(r["status"] == "ok" for r in rows), rows
    calls = log.read_text().split()
    assert calls.count(sources[1]) == 2 and calls.count(sources[0]) == 1
    assert progress.done == 2 and progress.failed == 0


@pytest.mark.slow  # 10-20 s idle, ~80 s on a 2-core machine under two busy loops (a Ray cluster's start): an eighth
# of the default run there; the default run keeps Ray through the unreachable-address test below
def test_a_task_killed_every_time_gets_an_error_row(ray_2cpu, tmp_path):
    ray_2cpu.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    source = _teachers(tmp_path / "src", 1)[0]
    job = FitJob(source=source, name="teacher0", model="ggx", out_dir=str(tmp_path), steps=1, image_spp=0)
    progress = RunProgress(1, Console(file=open(os.devnull, "w")))
    rows = list(run_ray([job], KillFirstAttempt(source, tmp_path / "calls.log"), progress, workers=None,
                        address=None, gpus_per_task=0.0, retries=0, log=lambda text: None))
    assert rows[0]["status"] == "error" and "Worker" in rows[0]["error"] and progress.failed == 1


def test_sources_expand_from_folders_and_lists(tmp_path):
    (tmp_path / "a.h5").write_bytes(b"")
    (tmp_path / "a.json").write_text("{}")           # the architecture of the NBRDF network a.h5: not a source
    (tmp_path / "b.json").write_text("{}")           # a layered material: a source
    (tmp_path / "notes.md").write_text("")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "a.binary").write_bytes(b"")
    (tmp_path / "list.txt").write_text("# database\nsub/a.binary\n\nplastic:roughness=0.3  # a spec\n")
    got = fit_many.expand_sources([str(tmp_path), str(tmp_path / "list.txt"), str(tmp_path / "a.h5")])
    assert got == [str(tmp_path / "a.h5"), str(tmp_path / "b.json"), str(tmp_path / "sub" / "a.binary"),
                   "plastic:roughness=0.3"]
    names = fit_many.source_names(got)
    assert list(names.values()) == ["a.h5", "b", "a.binary", "plastic_roughness_0.3"]


def test_model_scoped_overrides():
    got = fit_many.model_overrides({"steps": 5, "nbrdf:hidden": 8, "neubrdf:nside": 4, "neubrdf:steps": 6},
                                   ["nbrdf", "neubrdf"])
    assert got == {"nbrdf": {"steps": 5, "hidden": 8}, "neubrdf": {"steps": 6, "nside": 4}}
    with pytest.raises(Exception, match="ggx is not one of the --model values"):
        fit_many.model_overrides({"ggx:x": 1}, ["nbrdf"])


def _free_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_an_address_where_no_cluster_answers_fails_in_seconds(app, tmp_path):
    """Ray itself retries for minutes printing warnings; nothing is written."""
    import time
    pytest.importorskip("ray")
    t0 = time.perf_counter()
    for address in (f"127.0.0.1:{_free_port()}", f"ray://127.0.0.1:{_free_port()}"):
        r = CliRunner().invoke(app, ["lambert", *FAST, "--engine", "ray", "--address", address,
                                     "-o", str(tmp_path / "out")])
        said = " ".join(r.output.split())
        assert r.exit_code == 2 and f"--address {address}: no Ray cluster answers at that address" in said, said
        assert said.count("error:") == 1
    assert time.perf_counter() - t0 < 20 and not (tmp_path / "out").exists()


def test_mistyped_paths_are_refused_before_any_job(app, tmp_path):
    for source in (str(tmp_path / "paper_whte.bsdf"), str(tmp_path / "nowhere" / "set")):
        r = CliRunner().invoke(app, ["lambert", source, *FAST, "--engine", "local", "-o", str(tmp_path / "out")])
        assert r.exit_code == 2 and f"materialfile'{source}'doesnotexist" in "".join(r.output.split()), r.output
    assert not (tmp_path / "out").exists()


def test_help_shows_the_ray_extra(app):
    r = CliRunner().invoke(app, ["--help"], terminal_width=200)
    assert "pip install 'neumat[ray]'" in r.output, r.output


def test_a_job_stopped_with_its_process_resumes_its_fit_from_its_checkpoint(tmp_path, monkeypatch):
    """A job whose process stops mid-fit (here Ctrl-C after the first checkpoint) leaves its checkpoint; run again, it
    resumes from it (the trainer loads it once, at step 4) and ends with the model an uninterrupted job fits, bit for
    bit, and no checkpoint. A job whose options changed since (another seed) removes the old checkpoint and fits from
    the start; a job whose fit fails removes its own."""
    from neumat.catalog.modelfile import load_model
    from neumat.fit import trainer

    source = _teachers(tmp_path / "src", 1)[0]

    def job(folder: str, **kw) -> FitJob:
        return FitJob(**{"source": source, "name": "teacher0", "model": "ggx", "out_dir": str(tmp_path / folder),
                         "steps": 10, "overrides": {"batch_size": 256, "checkpoint_every": 4}, "device": "cpu",
                         "eval_n": 2048, "image_spp": 0} | kw)

    whole = run_fit_job(job("whole"))
    save = trainer._save_checkpoint

    def save_then_stop(*args, **kwargs):
        save(*args, **kwargs)
        raise KeyboardInterrupt

    monkeypatch.setattr(trainer, "_save_checkpoint", save_then_stop)
    with pytest.raises(KeyboardInterrupt):
        run_fit_job(job("stopped"))
    monkeypatch.setattr(trainer, "_save_checkpoint", save)
    (checkpoint,) = (tmp_path / "stopped").glob("*.ckpt")
    assert checkpoint == fit_job_module.checkpoint_path(job("stopped"), "cpu", fit_job_module.source_sha256(source))
    assert not job("stopped").out.exists()
    loads, load = [], trainer._load_checkpoint

    def counted_load(*args):
        state = load(*args)
        loads.append(state["step"])
        return state

    monkeypatch.setattr(trainer, "_load_checkpoint", counted_load)
    resumed = run_fit_job(job("stopped"))
    assert resumed["status"] == "ok" and loads == [4] and resumed["steps"] == whole["steps"] == 10
    for name, value in load_model(whole["nmat"]).state_dict().items():
        assert torch.equal(load_model(resumed["nmat"]).state_dict()[name], value), name
    assert not list((tmp_path / "stopped").glob("*.ckpt"))

    monkeypatch.setattr(trainer, "_save_checkpoint", save_then_stop)
    with pytest.raises(KeyboardInterrupt):
        run_fit_job(job("stopped"))
    monkeypatch.setattr(trainer, "_save_checkpoint", save)
    loads.clear()
    other = run_fit_job(job("stopped", seed=3))
    assert other["status"] == "ok" and loads == [] and not list((tmp_path / "stopped").glob("*.ckpt"))

    def save_then_fail(*args, **kwargs):
        save(*args, **kwargs)
        raise OSError("no space left on device")

    monkeypatch.setattr(trainer, "_save_checkpoint", save_then_fail)
    failed = run_fit_job(job("failed"))
    assert failed["status"] == "error" and "no space left" in failed["error"]
    assert not list((tmp_path / "failed").glob("*.ckpt"))
