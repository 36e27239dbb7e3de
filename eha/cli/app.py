"""The ``eha`` application: the guarded top-level group and its commands, in the order
``eha --help`` lists them."""

from __future__ import annotations

import typer

from eha.cli import campaign, design, explain, health, identify, models, prognostics, report
from eha.cli.guard import STATE, GuardedGroup

app = typer.Typer(cls=GuardedGroup, add_completion=False, no_args_is_help=True,
                  help="Model-based prognostics of electro-hydraulic actuators (HF/LF models, "
                       "fault campaigns, identification).")


@app.callback()
def _options(debug: bool = typer.Option(False, "--debug", help="Show the traceback of an "
                                        "unexpected error.")):
    if debug:
        STATE["debug"] = True


app.command()(models.simulate)
app.command()(models.params)
app.command()(models.commands)
app.command()(models.faults)
app.command()(report.reproduce)
app.add_typer(campaign.campaign_app, name="campaign")
app.command()(campaign.query)
app.command()(campaign.export)
app.command()(campaign.plot)
app.command()(identify.fdi)
app.command()(explain.explain)
app.add_typer(report.report_app, name="report")
app.add_typer(health.health_app, name="health")
app.add_typer(design.design_app, name="design")
app.add_typer(prognostics.fleet_app, name="fleet")
app.command()(prognostics.rul)
app.command()(prognostics.limits)


def main() -> None:  # pragma: no cover - the console script and `python -m eha`
    app(prog_name="eha")
