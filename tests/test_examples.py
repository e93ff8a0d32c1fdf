"""The example notebooks of ``examples/``, jupytext percent scripts (``examples/0*_*.py``): each is valid percent
format, and each runs top to bottom headless at its small sizes, read into a notebook by jupytext and executed by
nbclient in the venv's kernel, and writes its outputs."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

jupytext = pytest.importorskip("jupytext", reason="needs the examples extra (jupytext, nbformat, nbclient, ipykernel)")
nbformat = pytest.importorskip("nbformat", reason="needs the examples extra (jupytext, nbformat, nbclient, ipykernel)")
nbclient = pytest.importorskip("nbclient", reason="needs the examples extra (jupytext, nbformat, nbclient, ipykernel)")

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


def test_every_notebook_is_listed():
    """Every script directly in examples/ is a notebook and has its expected outputs here (helpers such as
    examples/scenes/make_meshes.py live in subfolders)."""
    scripts = {p.stem for p in EXAMPLES.glob("*.py")}
    assert scripts == set(EXPECTED_OUTPUTS), f"examples/*.py and EXPECTED_OUTPUTS differ: {scripts ^ set(EXPECTED_OUTPUTS)}"
    assert (EXAMPLES / "scenes" / "make_meshes.py").is_file() and "make_meshes" not in scripts


@pytest.mark.parametrize("stem", list(EXPECTED_OUTPUTS))
def test_notebook_is_jupytext_percent(stem):
    path = EXAMPLES / f"{stem}.py"
    text = path.read_text()
    nb = jupytext.read(path)
    representation = nb.metadata["jupytext"]["text_representation"]
    assert representation["extension"] == ".py" and representation["format_name"] == "percent", representation
    assert nb.metadata["kernelspec"]["name"] == "python3"
    # every cell starts at a `# %%` marker: nothing before the first one but the header, and the number of markers is
    # the number of cells
    assert text.count("\n# %%") == len(nb.cells) and text.lstrip().startswith("# ---")
    assert nb.cells[0].cell_type == "markdown" and nb.cells[0].source.startswith("# "), "first cell: the title"
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert "MANISKILL_PNP_EXAMPLES_SMALL" in code[0].source and f'output_dir("{stem}")' in code[0].source
    # the percent text round-trips: what jupytext writes back from it is the same cells
    again = jupytext.reads(jupytext.writes(nb, fmt="py:percent"), fmt="py:percent")
    assert [(c.cell_type, c.source) for c in again.cells] == [(c.cell_type, c.source) for c in nb.cells]
    compile(text, str(path), "exec")  # it is a plain Python script too
    nbformat.validate(nbformat.reads(jupytext.writes(nb, fmt="ipynb"), as_version=4))  # `jupytext --to notebook`


@pytest.mark.parametrize("stem", list(EXPECTED_OUTPUTS))
def test_notebook_runs_headless(stem, tmp_path, monkeypatch):
    out = tmp_path / "out"
    monkeypatch.setenv("MANISKILL_PNP_EXAMPLES_SMALL", "1")
    monkeypatch.setenv("MANISKILL_PNP_EXAMPLES_OUT", str(out))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = jupytext.read(EXAMPLES / f"{stem}.py")
    nb.cells.append(nbformat.v4.new_code_cell(KERNEL_PROBE))  # which python the kernel ran
    work = tmp_path / "cwd"
    work.mkdir()
    client = nbclient.NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(work)}})
    client.execute()  # raises CellExecutionError (with the cell and traceback) at the first failing cell

    code = [c for c in nb.cells if c.cell_type == "code"]
    assert all(c.execution_count for c in code), "a code cell did not run"
    errors = [o for c in code for o in c.outputs if o.output_type == "error"]
    assert not errors, errors
    shown = [o for c in code for o in c.outputs if o.output_type == "display_data"]
    assert any("image/png" in o.data for o in shown), "no figure was shown inline (IPython's display in a kernel)"
    kernel_python = "".join(o.get("text", "") for o in code[-1].outputs).strip()
    assert Path(kernel_python).resolve() == Path(sys.executable).resolve(), "the kernel is not this environment's python"
    missing = [f for f in EXPECTED_OUTPUTS[stem] if not (out / f).is_file() or (out / f).stat().st_size == 0]
    assert not missing, f"{stem} did not write {missing} into {out}"
    assert not any(work.iterdir()), f"{stem} wrote into its working directory: {sorted(work.iterdir())}"
