"""One module per ``hostd`` subcommand; each exposes ``add_parser(subparsers)``.

The parser sets ``func`` to a callable ``func(args) -> int`` (the exit status).
"""
