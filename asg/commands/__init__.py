"""The ``asg`` subcommands that belong to no wing, one module each: ``add_arguments(parser)`` and
``run(args) -> exit code``, registered once in asg.cli's COMMAND_MODULES (the generator's,
training's and the workflows' commands sit beside what they run)."""
