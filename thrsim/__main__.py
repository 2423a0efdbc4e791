"""``python -m thrsim`` runs the ``thrsim`` command."""

from thrsim.cli import main

main()
