"""``python -m daekit`` runs the command line (see :mod:`daekit.cli`)."""

from .cli import main

raise SystemExit(main())
