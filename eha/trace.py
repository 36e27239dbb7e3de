"""A recorded trace: the columns every model records (:data:`OUTPUTS`, their units) and
:class:`Trace`, the samples of one run (:func:`eha.models.simulate.simulate` returns one; the
trace files of :mod:`eha.campaigns.traces` hold them).

Imports nothing of eha: the models and the campaign infrastructure both use it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: Recorded outputs of every model, in the column order of the kernels' output array (docs/model.md §8).
OUTPUTS = ("t", "com", "xu", "xj", "dxj", "xs", "xf", "p12", "cor")
#: Units of :data:`OUTPUTS`.
OUTPUT_UNITS = {"t": "s", "com": "m", "xu": "m", "xj": "m", "dxj": "m/s", "xs": "m", "xf": "m",
                "p12": "Pa", "cor": "mA"}


@dataclass(frozen=True)
class Trace:
    """Recorded outputs of one simulation.

    Attributes
    ----------
    data : float64 array, shape (n, 9)
        Columns :data:`OUTPUTS` (t [s], com [m], xu [m], xj [m], dxj [m/s],
        xs [m], xf [m], p12 [Pa], cor [mA]).
    meta : dict
        Model, command, parameters that differ from nominal, seed, t_end.
    """

    data: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        if self.data.ndim != 2 or self.data.shape[1] != len(OUTPUTS):
            raise ValueError(f"Trace.data must have shape (n, {len(OUTPUTS)}), got "
                             f"{self.data.shape}")

    def __getitem__(self, name: str) -> np.ndarray:
        return self.data[:, OUTPUTS.index(name)]

    def __len__(self) -> int:
        return self.data.shape[0]

    @property
    def t(self) -> np.ndarray:
        return self["t"]

    @property
    def xu(self) -> np.ndarray:
        return self["xu"]

    def to_pandas(self):
        import pandas as pd

        return pd.DataFrame(self.data, columns=list(OUTPUTS))

    def to_arrow(self):
        import pyarrow as pa

        schema = pa.schema(
            [pa.field(n, pa.float64(), metadata={"unit": OUTPUT_UNITS[n]}) for n in OUTPUTS],
            metadata={"eha": json.dumps(self.meta, default=float)},
        )
        return pa.Table.from_arrays([pa.array(self.data[:, i]) for i in range(len(OUTPUTS))],
                                    schema=schema)


__all__ = ["OUTPUTS", "OUTPUT_UNITS", "Trace"]
