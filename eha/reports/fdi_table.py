"""The thesis' identification table (Figure 6.17) with our results beside the thesis' own:
shared by the thesis report (:mod:`eha.reports.thesis`) and the HTML report
(:mod:`eha.reports.html`), so that neither imports the other."""

from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    import pandas as pd

#: The campaign of the thesis' fault-identification cases (campaigns/thesis-fdi.toml).
FDI_CAMPAIGN = "thesis-fdi"

#: The thesis FDI cases with the LF model augmented by ``eha explain`` on nominal HF data
#: (campaigns/thesis-fdi-augmented.toml; issue 5, item 6).
AUGMENTED_CAMPAIGN = "thesis-fdi-augmented"


def fdi_table(rows: Sequence[dict], campaign, augmented: Sequence[dict] | None = None
              ) -> "pd.DataFrame":
    """The thesis' Figure 6.17 with our results beside the thesis' own, one row per case.

    Parameters
    ----------
    rows : sequence of dict
        FDI results (:class:`eha.identification.cases.FDIRow` rows, or rows of the ``fdi_results``
        table through :func:`fdi_results`), any number of seeds per case.
    campaign : eha.identification.cases.FDICampaign
        The cases: injected faults, bounds, population and the thesis' values.

    Returns
    -------
    pandas.DataFrame
        ``case, command, <p>_in, <p>_out, population, <p>_lb, <p>_ub, err_<p>_pct,
        mean_err_pct`` (medians over the seeds, ``p`` = bkl, fdj; bounds of the search), the
        spread ``mean_err_pct_min/max``, ``seeds``,
        ``seconds`` (median), ``evaluations``, ``method``, ``objective``, then
        ``thesis_<p>_out, thesis_err_<p>_pct, thesis_mean_err_pct, thesis_seconds`` and
        ``at_least_as_accurate`` (our median mean error <= the thesis'); with ``augmented``
        (rows of the same cases run with the LF model augmented by ``eha explain``, campaign
        :data:`AUGMENTED_CAMPAIGN`) also ``aug_<p>_out, aug_err_<p>_pct, aug_mean_err_pct``,
        ``aug_mean_err_pct_max`` and ``aug_at_least_as_accurate``.
    """
    import pandas as pd

    out = []
    for case in campaign.cases:
        rs = [r for r in rows if int(r["case"]) == case.case]
        if not rs:
            continue
        names = list(rs[0]["estimates"])
        med = lambda values: float(np.median(list(values)))  # noqa: E731
        row = {"case": case.case, "command": case.command}
        for n in names:
            row[f"{n.lower()}_in"] = float(rs[0]["truth"][n])
        for n in names:
            row[f"{n.lower()}_out"] = med(r["estimates"][n] for r in rs)
        row["population"] = case.pop
        for n in names:
            row[f"{n.lower()}_lb"], row[f"{n.lower()}_ub"] = case.bounds[n]
        for n in names:
            row[f"err_{n.lower()}_pct"] = med(r["errors_pct"][n] for r in rs)
        errs = [float(r["mean_err_pct"]) for r in rs]
        row.update({"mean_err_pct": med(errs), "mean_err_pct_min": min(errs),
                    "mean_err_pct_max": max(errs), "seeds": len(rs),
                    "seconds": med(r["seconds"] for r in rs),
                    "evaluations": med(r["evaluations"] for r in rs),
                    "method": rs[0]["method"], "objective": rs[0]["objective_name"]})
        th = case.thesis
        for n in names:
            row[f"thesis_{n.lower()}_out"] = th.get(n, np.nan)
        for n in names:
            row[f"thesis_err_{n.lower()}_pct"] = th.get(f"err_{n}_pct", np.nan)
        row["thesis_mean_err_pct"] = th.get("mean_err_pct", np.nan)
        row["thesis_seconds"] = th.get("seconds", np.nan)
        row["at_least_as_accurate"] = bool(row["mean_err_pct"] <= row["thesis_mean_err_pct"])
        aug = [r for r in augmented or () if int(r["case"]) == case.case]
        if aug:
            for n in names:
                row[f"aug_{n.lower()}_out"] = med(r["estimates"][n] for r in aug)
            for n in names:
                row[f"aug_err_{n.lower()}_pct"] = med(r["errors_pct"][n] for r in aug)
            row["aug_mean_err_pct"] = med(float(r["mean_err_pct"]) for r in aug)
            row["aug_mean_err_pct_max"] = max(float(r["mean_err_pct"]) for r in aug)
            row["aug_at_least_as_accurate"] = bool(
                row["aug_mean_err_pct"] <= row["thesis_mean_err_pct"])
        out.append(row)
    return pd.DataFrame(out)


__all__ = ["FDI_CAMPAIGN", "AUGMENTED_CAMPAIGN", "fdi_table"]
