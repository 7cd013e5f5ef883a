"""The results layer: HDF5 files, plots, regression comparison and CSV export.

Data flows one way, ``Result -> file/figure``; nothing here runs an analysis.

- :mod:`mbsim.output.hdf5`: ``write_result``, ``read_result``, ``list_channels`` (layout
  in ``docs/hdf5.md``);
- :mod:`mbsim.output.plots`: ``plot_channels``, ``plot_results``, ``save_figure``
  (matplotlib ``Figure`` objects, no pyplot state; imported lazily, matplotlib is slow
  to import);
- :mod:`mbsim.output.compare`: ``compare_results``, ``compare_files``, ``Difference``;
- :mod:`mbsim.output.export`: ``export_csv`` and the channel selectors shared with plots;
- :mod:`mbsim.output.stats`: statistics of one signal (``STATS``: final, period, settle, ...),
  a study's ``numbers:`` and a sweep's ``--summary``.
"""

from __future__ import annotations

import importlib
from typing import Any

from mbsim.output.compare import Difference, compare_files, compare_results
from mbsim.output.export import export_csv, select_columns
from mbsim.output.hdf5 import list_channels, read_info, read_result, write_result

_LAZY = {"plot_channels": "plots", "plot_results": "plots", "save_figure": "plots"}

__all__ = [
    "Difference",
    "compare_files",
    "compare_results",
    "export_csv",
    "list_channels",
    "plot_channels",
    "plot_results",
    "read_info",
    "read_result",
    "save_figure",
    "select_columns",
    "write_result",
]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        module = importlib.import_module(f"mbsim.output.{_LAZY[name]}")
        return getattr(module, name)
    raise AttributeError(f"module 'mbsim.output' has no attribute {name!r}")
