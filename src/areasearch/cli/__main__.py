"""``python -m areasearch.cli``: the ``areasearch`` command line (:func:`areasearch.cli.main`)."""

from __future__ import annotations

import sys

from . import main

sys.exit(main())
