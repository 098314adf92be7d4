"""``python -m svains``: the ``svains`` command."""

from svains.cli.main import main

main()
