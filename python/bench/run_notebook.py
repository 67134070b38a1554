"""Runs a notebook's code cells in order as plain Python (no Jupyter kernel needed) and fails on the
first error: how CI executes examples/*.ipynb. Usage: python run_notebook.py NOTEBOOK.ipynb

Figures go to matplotlib's non-interactive Agg backend (MPLBACKEND=Agg unless set) and are closed at the
end; a notebook that wants them kept saves them itself."""

import json
import os
import sys

os.environ.setdefault("MPLBACKEND", "Agg")


def main():
    with open(sys.argv[1], encoding="utf-8") as handle:
        notebook = json.load(handle)
    namespace = {"__name__": "__main__"}
    for index, cell in enumerate(notebook["cells"]):
        if cell["cell_type"] != "code":
            continue
        source = "".join(cell["source"])
        exec(compile(source, f"{sys.argv[1]} cell {index}", "exec"), namespace)
    if "matplotlib.pyplot" in sys.modules:
        sys.modules["matplotlib.pyplot"].close("all")
    return 0


if __name__ == "__main__":
    sys.exit(main())
