"""Errors that a user can fix: the CLI prints their message on one line and exits with code 2."""


class InputError(Exception):
    """Bad user input (a file, a name, a value). The message says what is wrong and how to fix it."""
