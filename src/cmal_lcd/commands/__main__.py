"""``python -m cmal_lcd.commands``: the ``cmal-lcd`` command."""

import sys

from cmal_lcd.commands import console_main

sys.exit(console_main())
