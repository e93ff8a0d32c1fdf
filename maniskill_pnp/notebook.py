"""What the example notebooks (``examples/0N_*.py``, jupytext percent scripts) share: where their outputs go, and
showing a figure or a table in a Jupyter kernel as well as when a notebook runs as a plain script.

Example:
    >>> OUT = output_dir("01_tasks")       # $MANISKILL_PNP_EXAMPLES_OUT, or runs/examples/01_tasks in the checkout
    >>> show(fig, "heightmaps", OUT)       # OUT/heightmaps.png, shown inline in a kernel, its path printed otherwise
    >>> display(Markdown(table_text))
"""

from __future__ import annotations

import os
from pathlib import Path

try:
    from IPython import get_ipython
except ImportError:  # IPython not installed
    def get_ipython():
        return None

if get_ipython() is not None:  # in a Jupyter kernel: figures and tables inline
    from IPython.display import Image, Markdown, display
else:  # a plain script (`python examples/01_tasks.py`): figure paths and table text on stdout

    def Image(filename: str) -> str:
        return f"[figure: {filename}]"

    Markdown, display = str, print

#: Environment variable naming the folder a notebook writes into (the tests set it).
OUT_VARIABLE = "MANISKILL_PNP_EXAMPLES_OUT"


def repo_root() -> Path:
    """The checkout holding the working directory (its ``runs/`` is git-ignored), else the working directory."""
    for folder in (Path.cwd(), *Path.cwd().parents):
        if (folder / "pyproject.toml").is_file() and (folder / "maniskill_pnp").is_dir():
            return folder
    return Path.cwd()


def output_dir(notebook: str) -> Path:
    """The folder notebook ``notebook`` writes into, created: ``$MANISKILL_PNP_EXAMPLES_OUT`` when set, else
    ``runs/examples/<notebook>`` in the checkout."""
    out = Path(os.environ.get(OUT_VARIABLE) or repo_root() / "runs" / "examples" / notebook)
    out.mkdir(parents=True, exist_ok=True)
    return out


def show(fig, name: str, folder: Path) -> Path:
    """Save ``fig`` as ``folder/<name>.png``, close it and show that PNG. (Not ``plt.show()``: the package's plot
    functions switch matplotlib to its non-interactive Agg backend, after which ``plt.show()`` shows nothing.)"""
    import matplotlib.pyplot as plt

    path = Path(folder) / f"{name}.png"
    fig.savefig(path, dpi=90, bbox_inches="tight")
    plt.close(fig)
    display(Image(filename=str(path)))
    return path


__all__ = ["Image", "Markdown", "OUT_VARIABLE", "display", "output_dir", "repo_root", "show"]
