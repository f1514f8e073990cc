"""python -m tflock."""

from tflock.cli import main

main()
