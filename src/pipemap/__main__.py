from pipemap.cli import app

app()
