"""`python -m mbsim ...` is the same as the `mbsim` command."""

from mbsim.cli import main

main()
