"""Subcommands of the `densecalib` command, one module each, each with
`add_arguments(parser)` and `run(args) -> int` (exit code)."""
