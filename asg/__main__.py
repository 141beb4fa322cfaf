"""``python -m asg``: the ``asg`` command (asg.entry)."""
from .entry import main

raise SystemExit(main())
