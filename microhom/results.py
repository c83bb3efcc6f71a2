"""What every result type of the project shares: read-only fields, ``as_dict()`` and ``to_frame()``.

A result a user reads is a frozen dataclass that documents each field with its unit and shape
(see :class:`microhom.moduli.Prediction`, ``dem.analysis.stiffness.StiffnessResult``). Mixing in
:class:`Result` gives it

* ``as_dict()``: plain Python scalars, lists and nested dicts, ready for JSON (NaN and inf become
  ``None``, so that the JSON is standard);
* ``to_frame()``: a one-row (or, for array fields of one shape, one-row-per-entry) pandas
  DataFrame; pandas is imported only here.

Fields whose ``metadata`` has ``{"export": False}`` (large arrays such as displacement fields) are
left out of both.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

__all__ = ["Result", "to_plain"]


def to_plain(value):
    """Convert numpy scalars/arrays, nested dataclasses, dicts and sequences to plain Python;
    non-finite floats become ``None``."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        if isinstance(value, Result):
            return value.as_dict()
        return {f.name: to_plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {str(k): to_plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return to_plain(value.tolist()) if value.ndim else to_plain(value.item())
    if isinstance(value, np.generic):
        return to_plain(value.item())
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    return value


class Result:
    """Mixin for frozen result dataclasses: ``as_dict()`` and ``to_frame()``."""

    def _exported(self):
        return [f for f in dataclasses.fields(self) if f.metadata.get("export", True)]

    def as_dict(self) -> dict:
        """The exported fields as plain Python values (JSON-ready: NaN/inf -> None)."""
        return {f.name: to_plain(getattr(self, f.name)) for f in self._exported()}

    def to_frame(self):
        """A pandas DataFrame: one row of scalars (arrays and nested results are flattened into
        ``name.sub`` columns where they are scalars, kept as objects otherwise)."""
        import pandas as pd

        row = {}

        def put(prefix, v):
            if isinstance(v, dict):
                for k, x in v.items():
                    put(f"{prefix}.{k}" if prefix else k, x)
            else:
                row[prefix] = v

        put("", self.as_dict())
        return pd.DataFrame([row])
