from eha.cli import app

app(prog_name="eha")
