"""The example notebooks of ``examples/``: each runs top to bottom headless at its small sizes, in the venv's kernel,
and writes its outputs; and each ``.ipynb`` is exactly what ``examples/build_notebooks.py`` builds (no outputs)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat", reason="needs the examples extra (nbformat, nbclient, ipykernel)")
nbclient = pytest.importorskip("nbclient", reason="needs the examples extra (nbformat, nbclient, ipykernel)")

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

#: Files (relative to MANISKILL_PNP_EXAMPLES_OUT) each notebook must write.
EXPECTED_OUTPUTS = {
    "01_tasks": ["conveyor_episode.png", "conveyor_rays.png", "clutter_heightmaps.png", "clutter_after_grasp.png",
                 "slide.png"],
    "02_conveyor_tabular": ["runs/qlearning_normal_seed0/qtable.pt", "runs/sarsa_normal_seed0/qtable.pt",
                            "learning_curves.png", "eval/test_cases.md", "eval/test_cases.csv", "eval/categories.md",
                            "eval/eval.json"],
    "03_pixel_grasp_agent": ["heightmaps.png", "untrained_q_heatmaps.png",
                             "runs/cpu-equi_equivariant_r16_px64_seed0/checkpoint.pt",
                             "runs/cpu-equi_equivariant_r16_px64_seed0/actions.csv", "training_curves.png",
                             "eval/eval_table.md", "eval/eval_summary.json", "eval/q_heatmaps.png"],
    "04_grasp_and_slide": ["layouts.png", "slide_then_grasp.png", "gs_q_heatmaps.png", "gs_step0.png"],
}

KERNEL_PROBE = "import sys\nprint(sys.executable)"


def _builder():
    spec = importlib.util.spec_from_file_location("build_notebooks", EXAMPLES / "build_notebooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_notebooks_are_what_the_generator_builds():
    builder = _builder()
    assert set(builder.NOTEBOOKS) == set(EXPECTED_OUTPUTS) == {p.stem for p in EXAMPLES.glob("*.ipynb")}
    for stem in builder.NOTEBOOKS:
        on_disk = nbformat.read(EXAMPLES / f"{stem}.ipynb", as_version=4)
        built = builder.build(stem)
        assert [(c.cell_type, c.source) for c in on_disk.cells] == [(c.cell_type, c.source) for c in built.cells], (
            f"examples/{stem}.ipynb is out of date: run .venv/bin/python examples/build_notebooks.py"
        )
        assert (EXAMPLES / f"{stem}.ipynb").read_text() == builder.render(stem), f"{stem}.ipynb: metadata or ids differ"
        code = [c for c in on_disk.cells if c.cell_type == "code"]
        assert all(not c.outputs and c.execution_count is None for c in code), f"{stem}.ipynb was saved with outputs"
        assert "MANISKILL_PNP_EXAMPLES_SMALL" in code[0].source and "MANISKILL_PNP_EXAMPLES_OUT" in code[0].source


@pytest.mark.parametrize("stem", list(EXPECTED_OUTPUTS))
def test_notebook_runs_headless(stem, tmp_path, monkeypatch):
    out = tmp_path / "out"
    monkeypatch.setenv("MANISKILL_PNP_EXAMPLES_SMALL", "1")
    monkeypatch.setenv("MANISKILL_PNP_EXAMPLES_OUT", str(out))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(EXAMPLES / f"{stem}.ipynb", as_version=4)
    nb.cells.append(nbformat.v4.new_code_cell(KERNEL_PROBE))  # which python the kernel ran
    work = tmp_path / "cwd"
    work.mkdir()
    client = nbclient.NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(work)}})
    client.execute()  # raises CellExecutionError (with the cell and traceback) at the first failing cell

    code = [c for c in nb.cells if c.cell_type == "code"]
    assert all(c.execution_count for c in code), "a code cell did not run"
    errors = [o for c in code for o in c.outputs if o.output_type == "error"]
    assert not errors, errors
    kernel_python = "".join(o.get("text", "") for o in code[-1].outputs).strip()
    assert Path(kernel_python).resolve() == Path(sys.executable).resolve(), "the kernel is not this environment's python"
    missing = [f for f in EXPECTED_OUTPUTS[stem] if not (out / f).is_file() or (out / f).stat().st_size == 0]
    assert not missing, f"{stem} did not write {missing} into {out}"
    assert not any(work.iterdir()), f"{stem} wrote into its working directory: {sorted(work.iterdir())}"
