"""``eha report html``: one self-contained, interactive HTML report of a results folder.

The page (docs/report.md) has a section for whatever the folder's ``eha.duckdb`` holds —
Fleet (``eha rul``), Health (``eha health check``, calibrations, detection campaigns),
Identification (FDI campaigns, the thesis table), Fault identification (``eha fdi
--results``), Residual loop (``eha explain``), Test design (``eha design --results``),
Campaigns (runs by status, HF-vs-LF errors) — and names the others, with the command that
fills each. Figures are plotly's, its JavaScript embedded
once; tables are plain HTML, sortable and filterable by a few lines of script. It opens from
disk with no server and makes no request (a Content-Security-Policy forbids any). Nothing is
embedded per stored trace: every figure aggregates the database's rows.

Modules: :mod:`~eha.reports.html.data` (read), :mod:`~eha.reports.html.figures` (plotly
figures), :mod:`~eha.reports.html.sections` (the sections' HTML), :mod:`~eha.reports.html.page`
(the page).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from eha.errors import InputError

#: Section ids and headings, in page order.
SECTIONS = {"fleet": "Fleet", "health": "Health", "identification": "Identification",
            "fdi": "Fault identification", "explain": "Residual loop", "design": "Test design",
            "campaigns": "Campaigns"}
#: What fills each section (named on the page when the section is absent).
FILLED_BY = {"fleet": "eha fleet simulate, then eha rul",
             "health": "eha health check (eha health calibrate for verdicts), or the detection "
                       "campaign campaigns/health-detection.toml",
             "identification": "an FDI campaign: eha reproduce, or eha campaign run "
                               "campaigns/thesis-fdi.toml",
             "fdi": "eha fdi ... --results DIR",
             "explain": "eha explain RECORD",
             "design": "eha design ... --results DIR",
             "campaigns": "eha campaign run FILE, or eha reproduce"}


class ReportError(InputError):
    """Nothing to report: the results folder is missing, empty, or holds no result (one line;
    the CLI exits 2)."""


@dataclass
class ReportResult:
    """What :func:`build_report` wrote: the file, its sections (ids of :data:`SECTIONS`), its
    size [bytes], the number of figures, and the build time [s]."""

    path: Path
    sections: list[str] = field(default_factory=list)
    bytes: int = 0
    figures: int = 0
    seconds: float = 0.0


def build_report(results: str | Path, out: str | Path, truth: str | Path | None = None
                 ) -> ReportResult:
    """Write the HTML report of the results folder ``results`` to ``out``.

    Parameters
    ----------
    results : path
        Results folder (``eha.duckdb`` and what the commands wrote beside it).
    out : path
        HTML file to write (replaced atomically: a failed build leaves no partial file).
    truth : path, optional
        True end of life of the fleet (``truth.json`` of ``eha fleet simulate`` or CSV
        ``actuator,eol``); default: a ``truth.json`` found beside the records of each
        ``eha rul`` run.

    Returns
    -------
    ReportResult

    Raises
    ------
    ReportError
        ``results`` is not a folder, has no database, or the database holds no result.
    eha.campaigns.store.StoreError
        The database cannot be read (locked by a running campaign, damaged).
    """
    from eha.reports.html import data as D
    from eha.reports.html import sections as S
    from eha.reports.html import tools as T
    from eha.reports.html.figures import shared_template
    from eha.reports.html.page import Page, esc
    from eha.models.simulate import MODEL_VERSION
    from eha.campaigns.store import connect, db_path

    t0 = time.perf_counter()
    results, out = Path(results), Path(out)
    if not results.is_dir():
        raise ReportError(f"`results` {results}: no such folder; run eha reproduce, eha rul or "
                          "eha campaign run first")
    if not db_path(results).is_file():
        raise ReportError(f"`results` {results}: empty results folder (no {db_path(results).name}"
                          "); run eha reproduce, eha rul or eha campaign run first")
    con = connect(results, read_only=True)
    unread: dict[str, str] = {}
    try:
        fleets = _read(unread, "fleet", D.read_fleets, con, truth)
        health = _read(unread, "health", D.read_health, con)
        ident = _read(unread, "identification", D.read_identification, con)
        fdi_runs = _read(unread, "fdi", D.read_fdi_runs, con)
        explain = _read(unread, "explain", D.read_explain, con)
        designs = _read(unread, "design", D.read_designs, con)
        camps = _read(unread, "campaigns", D.read_campaigns, con)
    finally:
        con.close()
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    page = Page(f"eha report — {results.resolve().name}",
                f"Results folder {esc(results.resolve())} · generated {stamp} · model version "
                f"{esc(MODEL_VERSION)}")
    builders = [("fleet", fleets or None, S.fleet_section),
                ("health", health, S.health_section),
                ("identification", ident, S.identification_section),
                ("fdi", fdi_runs, T.fdi_section),
                ("explain", explain, S.explain_section),
                ("design", designs, T.design_section),
                ("campaigns", camps, S.campaigns_section)]
    with shared_template():
        for sid, value, build in builders:
            if value is not None:
                page.add_section(sid, SECTIONS[sid], build(page, value))
    if not page.sections:
        raise ReportError(f"`results` {results}: the database holds no result to report; run "
                          "eha reproduce, eha rul, eha campaign run, eha explain, or eha fdi "
                          "or eha design with --results first")
    absent = [sid for sid in SECTIONS if sid not in {s[0] for s in page.sections}]
    if absent:
        page.subtitle += ("<br>Not in this report (nothing in the database yet): " + "; ".join(
            f"<b>{esc(SECTIONS[sid])}</b> — {esc(FILLED_BY[sid])}"
            + (f" ({esc(unread[sid])})" if sid in unread else "") for sid in absent) + ".")
    text = page.render("Generated by <code>eha report html</code>. Figures: plotly (zoom: drag; "
                       "double-click: reset; hover: values with units). Units SI unless the "
                       "axis says otherwise.")
    _write_atomic(out, text)
    return ReportResult(out, [s[0] for s in page.sections], out.stat().st_size, page.figures,
                        time.perf_counter() - t0)


def _read(unread: dict[str, str], sid: str, reader, *args):
    """``reader(*args)``; a table its section needs and the database lacks (a folder that
    other commands, or an older version, wrote) leaves the section out, noted in
    ``unread[sid]``, never a failed report: a missing table is not a damaged database."""
    import duckdb

    try:
        return reader(*args)
    except duckdb.CatalogException as exc:
        unread[sid] = "the database has no table it needs: " + str(exc).splitlines()[0]
        return None


def _write_atomic(path: Path, text: str) -> None:
    from eha.outputs import write_atomic

    write_atomic(path, text)


__all__ = ["build_report", "ReportError", "ReportResult", "SECTIONS"]
