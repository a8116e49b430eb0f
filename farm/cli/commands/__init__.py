"""The `farm` commands, one module each: `register(subparsers)` adds the command and its flags to
the `farm` parser, `run(args)` runs it and returns the exit status."""
