"""Fits of record vs model for the Identification section: per FDI case, the HF reference with
the injected faults against the LF model with the identified ones (the first seed's run, both
re-simulated as ``eha report thesis`` does for its case figures: the runs are deterministic).

Nothing stored is embedded: each trace is simulated anew (about 30 ms per case once the
compiled kernels are loaded) and thinned to at most :data:`POINTS` samples.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

#: At most this many samples of each curve go into the page.
POINTS = 400


def _thin(n: int) -> slice:
    return slice(None, None, max(1, int(np.ceil(n / POINTS))))


def fit_figures(rows: Sequence[Any], campaign) -> dict[str, dict]:
    """One figure per case of ``campaign`` with results: position (command, HF reference,
    identified LF) in mm and the residual HF − LF in µm, against time.

    Parameters
    ----------
    rows : sequence of eha.identification.cases.FDIRow
        The campaign's results (any seeds; the lowest seed of each case is drawn).
    campaign : eha.identification.cases.FDICampaign
        The cases and the LF base of the identification.

    Returns
    -------
    dict
        ``"case N (command)" -> plotly figure dict``.
    """
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    from eha.identification.fdi import hf_reference
    from eha.models.params import resolve
    from eha.reports.html.data import unit_of
    from eha.reports.html.figures import _done
    from eha.models.simulate import simulate

    base = resolve("lf", campaign.base)
    out = {}
    for case in campaign.cases:
        mine = sorted((r for r in rows if int(r.case) == case.case), key=lambda r: r.seed)
        if not mine:
            continue
        r = mine[0]
        hf = hf_reference(case.command, case.faults, seed=r.seed, t_end=campaign.t_end)
        lf = simulate("lf", case.command, base.replace(**r.estimates), t_end=campaign.t_end)
        n = min(len(hf), len(lf))
        s = _thin(n)
        t = np.asarray(hf["t"][:n])[s]
        com, xh, xl = (np.asarray(a[:n])[s] for a in (hf["com"], hf["xu"], lf["xu"]))
        fig = make_subplots(rows=2, cols=1, shared_xaxes=True, row_heights=[0.65, 0.35],
                            vertical_spacing=0.07)
        for y, name, style in ((com, "command", {"color": "#bbbbbb", "width": 3}),
                               (xh, "HF reference (injected faults)", {"color": "#1f77b4"}),
                               (xl, "LF, identified faults", {"color": "#ff7f0e",
                                                              "dash": "dash"})):
            fig.add_trace(go.Scatter(x=t, y=np.round(1e3 * y, 6), mode="lines", name=name,
                                     line=style, hovertemplate=(
                                         f"t %{{x:.3f}} s: {name} %{{y:.4f}} mm"
                                         "<extra></extra>")), row=1, col=1)
        fig.add_trace(go.Scatter(x=t, y=np.round(1e6 * (xh - xl), 4), mode="lines",
                                 name="HF − LF", line={"color": "#2ca02c", "width": 1},
                                 hovertemplate="t %{x:.3f} s: HF − LF %{y:.3g} µm"
                                               "<extra></extra>"), row=2, col=1)
        fig.update_yaxes(title_text="position xu [mm]", row=1, col=1)
        fig.update_yaxes(title_text="HF − LF [µm]", row=2, col=1)
        fig.update_xaxes(title_text="time [s]", row=2, col=1)
        text = lambda d: ", ".join(f"{k} {unit_of(k)[1] * v:.4g} {unit_of(k)[0]}"  # noqa: E731
                                   for k, v in d.items())
        out[f"case {case.case} ({case.command})"] = _done(
            fig, f"Case {case.case}, seed {r.seed}: HF with {text(r.truth)} vs LF with the "
                 f"identified {text(r.estimates)} (mean error {r.mean_err_pct:.3g} %)",
            height=460)
    return out
