"""``python -m hybridpose`` — the same as the ``hybridpose`` command."""
from .cli import main

raise SystemExit(main())
