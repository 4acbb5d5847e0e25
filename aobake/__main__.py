"""``python -m aobake`` runs the command-line interface."""

from .cli import main

main()
