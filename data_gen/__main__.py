"""Entry point of ``python -m data_gen`` (see :mod:`data_gen.cli`)."""

from data_gen.cli import main

raise SystemExit(main())
