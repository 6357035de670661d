"""`python -m cooploc` runs the command-line interface (same as the `cooploc` script)."""

from cooploc.cli import main

main()
