"""Numba kernels of the actuator models: ``hf`` (detailed), ``lf`` (monitoring), ``friction``."""

#: Recorded outputs of every model, in the column order of the kernels' output array (SPEC §8).
OUTPUTS = ("t", "com", "xu", "xj", "dxj", "xs", "xf", "p12", "cor")
#: Units of :data:`OUTPUTS`.
OUTPUT_UNITS = {"t": "s", "com": "m", "xu": "m", "xj": "m", "dxj": "m/s", "xs": "m", "xf": "m",
                "p12": "Pa", "cor": "mA"}
O_T, O_COM, O_XU, O_XJ, O_DXJ, O_XS, O_XF, O_P12, O_COR = range(len(OUTPUTS))

# eha.models.friction.record writes the columns in this order.
assert OUTPUTS.index("t") == 0 and OUTPUTS.index("cor") == 8
