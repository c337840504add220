"""``python -m ibt``: the command line."""

from ibt.cli import main

raise SystemExit(main())
