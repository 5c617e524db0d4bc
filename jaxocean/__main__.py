"""``python -m jaxocean ...``: the ``jaxocean`` command (:mod:`jaxocean.cli`)."""

import sys

from jaxocean.cli import main

sys.exit(main())
