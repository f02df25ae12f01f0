"""cmal_lcd: CMAL loop closure detection, from raw frames to the paper's tables and figures.

See ``docs/architecture.md`` for the package layout, the conventions (difference matrix
orientation, ground truth, metric keys) and the files passed between pipeline stages.
"""

import logging

from cmal_lcd.kernels import pin_cpu_kernels

# before any module imports torch: one kernel path on every machine (cmal_lcd.kernels)
pin_cpu_kernels()

__version__ = "0.1.0"

logger = logging.getLogger("cmal_lcd")
