from labrig.cli import run

run()
