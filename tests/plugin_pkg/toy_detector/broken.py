"""A plugin whose import fails (a missing dependency), to check that asg names it in one line."""
import a_module_that_does_not_exist  # noqa: F401


def make():
    raise AssertionError("never reached")
