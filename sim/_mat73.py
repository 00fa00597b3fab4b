"""Read a MATLAB v7.3 (HDF5) .mat with h5py, in a process of its own.

    python -P sim/_mat73.py FILE

libhdf5 is compiled code that a crafted file can crash, so :func:`sim.logio.read_log` runs this script as a
child process and turns a crash into an error. It imports nothing from the project (so it starts fast and
sees no package state) and writes to stdout a pickle of ``("ok", variables)``, ``variables`` as
``loadmat(simplify_cells=True)`` gives them (vectors, str, dicts of struct fields, object arrays of cells), or
``("error", message)``.
"""

from __future__ import annotations

import pickle
import sys
from typing import Any

import numpy as np


def read_mat73(path: str) -> dict[str, Any]:
    """The variables of the v7.3 file ``path``, in the file's (sorted) order."""
    import h5py

    def value(obj: Any) -> Any:
        cls = obj.attrs.get("MATLAB_class", b"")
        cls = cls.decode() if isinstance(cls, bytes) else str(cls)
        if isinstance(obj, h5py.Group):  # a struct: one member per field, in MATLAB's order if recorded
            return {key: value(obj[key]) for key in fields(obj) or list(obj)}
        data = obj[()]
        if obj.attrs.get("MATLAB_empty", 0):
            return "" if cls == "char" else np.zeros(0)
        if cls == "char":
            return "".join(map(chr, np.ravel(data, order="F")))  # MATLAB stores chars as UTF-16 code units
        if cls == "cell":  # references to the cells' contents
            cells = np.empty(data.shape, dtype=object)
            for index in np.ndindex(data.shape):
                cells[index] = value(obj.file[data[index]])
            return cells.T
        return np.asarray(data).T  # HDF5 holds MATLAB arrays transposed; .T restores MATLAB's shape

    def fields(group: Any) -> list[str]:
        names = group.attrs.get("MATLAB_fields")
        return [] if names is None else [b"".join(np.ravel(f)).decode() for f in names]

    with h5py.File(path, "r") as fh:
        return {name: value(fh[name]) for name in fh if not name.startswith("#")}  # '#refs#': cell data


def main(argv: list[str]) -> None:
    try:
        result: tuple[str, Any] = ("ok", read_mat73(argv[1]))
    except Exception as err:  # h5py raises OSError, KeyError, ValueError, TypeError, ... on a bad file
        result = ("error", f"{type(err).__name__}: {err}")
    sys.stdout.buffer.write(pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL))


if __name__ == "__main__":
    main(sys.argv)
