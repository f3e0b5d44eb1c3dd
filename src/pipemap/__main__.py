from pipemap.cli import app

if __name__ == "__main__":  # not when a spawned process imports it as its parent's main module
    app()
