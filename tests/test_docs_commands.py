"""Every `neumat` command line in the fenced shell blocks of README.md and docs/*.md runs, in order, one document
per test, in a scratch folder where `../shared` is the real-data folder and `docs/` the repository's docs: so no
documented command can rot. Sizes are capped with each command's own options (`QUICK`: fewer steps, samples,
pixels, texels) so the whole run takes seconds per command; the files each command writes are the ones the next
command of the document reads. `make` lines are CI's own commands and are left out."""
from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
from typer.testing import CliRunner

from neumat.cli.main import app

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

#: (command words, option) -> the largest value a docs run uses; an option the line lacks is added
QUICK: dict[tuple[str, ...], dict[str, str]] = {
    ("fit",): {"--steps": "3"},
    ("eval",): {"--n-configs": "4096", "--spp": "2", "--resolution": "16"},
    ("render",): {"--spp": "2", "--resolution": "16"},
    ("compare",): {"--spp": "2", "--resolution": "16", "--n-configs": "4096"},
    ("mitsuba-render",): {"--spp": "2"},
    ("check",): {"--samples": "20000"},
    ("export",): {"--check": "64"},
    ("fit-dictionary",): {"--iterations": "2"},
    ("fit-many",): {"--steps": "3", "--image-spp": "1"},
    ("fit-clusters",): {"--steps": "3", "--n-configs": "4096"},
    ("data", "btf-generate"): {"--size": "20", "--spp": "1"},
    ("data", "texture-set"): {"--size": "32"},
    ("data", "texture-stats"): {"--samples": "2", "--crop": "16"},
    ("translucent", "trace"): {"--images": "3", "--resolution": "8", "--spp": "2"},
    ("translucent", "fit"): {"--steps": "4"},
    ("translucent", "render"): {"--spp": "2", "--resolution": "8", "--reference-spp": "2", "--env-width": "16"},
    ("translucent", "prt"): {"--light-samples": "16", "--subdivisions": "1"},
    ("translucent", "prt-render"): {"--spp": "1", "--resolution": "8", "--model-spp": "2", "--reference-spp": "2",
                                    "--env-width": "16"},
}
#: (command words, option) -> the largest value a docs run uses, only where the line has the option
CAP_ONLY: dict[tuple[str, ...], dict[str, str]] = {("eval",): {"--scales": "2"}}
#: options added to commands of these words when absent (not caps): small batches, small texture sets
EXTRA: dict[tuple[str, ...], list[str]] = {
    ("fit",): ["--set", "batch_size=256", "--source-option", "max_size=32"],
    ("translucent", "fit"): ["--set", "batch_size=256"],
    ("mitsuba-render",): ["-D", "res=16"],
}
#: options added to `neumat fit --model M` when absent: the dipole's surface quadrature from the few observations
#: of a quick trace; NeuBRDF's grids at N_side 16 (its phases, k-means and VQ run the same, in a quarter of the
#: time of the paper's N_side 64)
MODEL_EXTRA = {"dipole-bssrdf": ["--set", "samples=16"], "neubrdf": ["--set", "nside=16"]}
#: fit-many runs its jobs in this process (Ray is tested in tests/cli/test_fit_many.py)
EXTRA[("fit-many",)] = ["--engine", "local"]
#: commands that need Mitsuba 3's LLVM backend
MITSUBA = {("mitsuba-render",), ("translucent", "trace"), ("translucent", "render"), ("translucent", "prt"),
           ("translucent", "prt-render")}


def _commands(md: Path) -> list[str]:
    """The `neumat` commands of md's fenced shell blocks, continuation lines joined and `&&` chains split."""
    out = []
    for block in re.findall(r"```(?:bash|sh|shell)\n(.*?)```", md.read_text(), re.S):
        for line in block.replace("\\\n", " ").splitlines():
            for part in line.split("&&"):
                words = shlex.split(part, comments=True)
                if words and words[0] == "neumat":
                    out.append(shlex.join(words))
    return out


def _key(words: list[str]) -> tuple[str, ...]:
    return tuple(words[1:3]) if words[1] in ("data", "translucent") else (words[1],)


def quick(command: str, cwd: Path) -> list[str]:
    """`command` with the sizes of QUICK capped and EXTRA options added; paths are relative to `cwd`."""
    words = shlex.split(command)
    key = _key(words)
    for option, cap in QUICK.get(key, {}).items():
        if option in words:
            i = words.index(option) + 1
            words[i] = str(min(float(words[i]), float(cap))).removesuffix(".0")
        else:
            words += [option, cap]
    for option, cap in CAP_ONLY.get(key, {}).items():
        if option in words:
            i = words.index(option) + 1
            words[i] = str(min(int(words[i]), int(cap)))
    model = words[words.index("--model") + 1] if "--model" in words else None
    extra = EXTRA.get(key, []) + MODEL_EXTRA.get(model, [])
    for flag, value in zip(extra[::2], extra[1::2]):
        name = value.split("=")[0]
        if name not in words and not any(w.startswith(name + "=") for w in words):
            if name == "max_size" and (not (cwd / words[2]).is_dir() or "crop=" in " ".join(words)):
                continue  # reader options only apply to texture-set folders; a crop replaces max_size
            words += [flag, value]
    if "--device" in words and words[words.index("--device") + 1].startswith("cuda"):
        import torch
        if not torch.cuda.is_available():
            words[words.index("--device") + 1] = "cpu"  # the docs show a GPU run; this machine has none
    return words


DOC_CASES = [pytest.param(md, id=str(md.relative_to(ROOT))) for md in DOCS if _commands(md)]


@pytest.mark.parametrize("md", DOC_CASES)
def test_documented_commands_run(md, tmp_path, request, monkeypatch):
    commands = _commands(md)
    shared = request.getfixturevalue("shared_data").parent if any("../shared" in c for c in commands) else None
    if any(_key(shlex.split(c)) in MITSUBA for c in commands):
        from mitsuba_util import mitsuba_or_skip
        mitsuba_or_skip()
    work = tmp_path / "repo"
    work.mkdir()
    (work / "docs").symlink_to(ROOT / "docs")
    if shared is not None:
        (tmp_path / "shared").symlink_to(shared)
    monkeypatch.chdir(work)  # the commands' relative paths (../shared, docs/, their own outputs) start here
    monkeypatch.setenv("MPLBACKEND", "Agg")
    for command in commands:
        words = quick(command, work)
        run = CliRunner().invoke(app, words[1:])
        assert run.exit_code == 0, (f"{md.name}: `{command}` failed (run as `neumat {shlex.join(words[1:])}`):\n"
                                    f"{run.output[-3000:]}\n{run.exception!r}")


def test_every_docs_command_is_run():
    """No command line hides in a block the test skips: every line starting with `neumat ` in a fenced block of
    the docs is in a bash block."""
    for md in DOCS:
        for lang, block in re.findall(r"```(\w*)\n(.*?)```", md.read_text(), re.S):
            if lang not in ("bash", "sh", "shell"):
                lines = [ln for ln in block.splitlines() if ln.strip().startswith("neumat ")]
                assert not lines, f"{md.name}: commands in a ```{lang} block are not run by the docs test: {lines}"


def _inline_commands() -> list:
    """`neumat ...` code spans in the prose of the docs (usage lines, commands quoted in text)."""
    out = []
    for md in DOCS:
        text = re.sub(r"```.*?```", "", md.read_text(), flags=re.S)
        for span in re.findall(r"`(neumat [^`]+)`", text):
            out.append(pytest.param(span, id=f"{md.name}:{span[:40]}"))
    return out


@pytest.mark.parametrize("span", _inline_commands())
def test_inline_commands_name_options_that_exist(span):
    """Every --option a command quoted in the prose names is an option of that command (usage lines cannot rot
    either)."""
    import typer.main

    command = typer.main.get_command(app)
    words = span.replace("\\|", "|").split()[1:]
    while words and hasattr(command, "commands") and words[0] in command.commands:
        command = command.commands[words.pop(0)]
    known = {opt for p in command.params for opt in (*p.opts, *p.secondary_opts)}
    named = {w.split("=")[0].strip("[]()") for w in words if w.lstrip("[").startswith("--")}
    assert named <= known, f"`{span}`: {sorted(named - known)} are not options of `{command.name}`"
