"""The paper's own published numbers, as data, for side-by-side comparison.

Source: P. Yin, Y. He, N. Liu, J. Han, W. Xu, "Condition directed Multi-domain Adversarial
Learning for Loop Closure Detection" (copy in ``../shared/paper/cmal_loop_closure_paper.md``),
Section IV (experiments in the GTA V game simulator, one NVIDIA Titan X):

- Table II "Recall at 100% precision": two routes x three weather pairs x four methods.
- Table III "Feature inference time per frame (millisecond)": SAD and CMAL on the same pairs.
- Section IV-D: a CMAL code is 1024 float32 values, "1024*4B=4KB" per frame.

The paper writes its pairs as "Foggy Rain", "Foggy Sunny", "Rain Sunny" without saying which
drive is the reference; we read the first weather as the reference, as in our pair names
``foggy-rainy``, ``foggy-sunny``, ``rainy-sunny`` (docs/architecture.md). Its "DNN" row is the
fully connected layer of an ImageNet-trained VGG16.

Nothing here is computed; every other number in ``reports/`` comes from the pipeline.
"""

from __future__ import annotations

import math
import re

PAPER_CITATION = (
    "Yin, He, Liu, Han, Xu, \"Condition directed Multi-domain Adversarial Learning for "
    "Loop Closure Detection\", Section IV, Tables II-III"
)
#: Where the paper's numbers were measured.
PAPER_SETTING = "GTA V simulator, NVIDIA Titan X"

#: Row labels of the paper's tables, by our method names.
PAPER_METHOD_LABELS = {
    "sad": "SAD",
    "cmal": "CMAL",
    "dnn": "DNN (VGG16)",
    "bigan": "BiGAN",
}

#: Table II, recall at 100% precision (fractions): route -> pair -> method -> recall.
PAPER_TABLE2_RECALL_AT_100P = {
    "route1": {
        "foggy-rainy": {"sad": 0.348, "cmal": 0.141, "dnn": 0.001, "bigan": 0.314},
        "foggy-sunny": {"sad": 0.297, "cmal": 0.483, "dnn": 0.045, "bigan": 0.164},
        "rainy-sunny": {"sad": 0.656, "cmal": 0.287, "dnn": 0.004, "bigan": 0.064},
    },
    "route2": {
        "foggy-rainy": {"sad": 0.110, "cmal": 0.319, "dnn": 0.008, "bigan": 0.106},
        "foggy-sunny": {"sad": 0.508, "cmal": 0.101, "dnn": 0.021, "bigan": 0.026},
        "rainy-sunny": {"sad": 0.731, "cmal": 0.224, "dnn": 0.006, "bigan": 0.054},
    },
}

#: Table III, feature inference time per frame in milliseconds: route -> pair -> method -> ms.
PAPER_TABLE3_MS = {
    "route1": {
        "foggy-rainy": {"sad": 3.2, "cmal": 3.4},
        "foggy-sunny": {"sad": 3.2, "cmal": 3.5},
        "rainy-sunny": {"sad": 3.2, "cmal": 3.6},
    },
    "route2": {
        "foggy-rainy": {"sad": 3.3, "cmal": 3.4},
        "foggy-sunny": {"sad": 3.4, "cmal": 3.4},
        "rainy-sunny": {"sad": 3.3, "cmal": 3.5},
    },
}

#: Section IV-D: storage per frame in bytes (only CMAL is stated: 1024 x float32).
PAPER_BYTES_PER_FRAME = {"cmal": 1024 * 4}


def normalise_route(route: str) -> str:
    """Route name in the paper's spelling: lower case, letters and digits only.

    ``"Route 1"``, ``"route_1"`` and ``"route1"`` all give ``"route1"``.
    """
    return re.sub(r"[^a-z0-9]", "", str(route).lower())


def paper_recall_at_100p(route: str, pair: str, method: str) -> float:
    """The paper's Table II recall at 100% precision, or NaN where it reports none.

    Parameters
    ----------
    route, pair, method : str
        Our names (``"route1"``, ``"foggy-rainy"``, ``"cmal"``).
    """
    value = PAPER_TABLE2_RECALL_AT_100P.get(normalise_route(route), {}).get(pair, {}).get(method)
    return math.nan if value is None else float(value)


def paper_inference_ms_range(method: str) -> tuple[float, float]:
    """Smallest and largest per-frame time (ms) the paper's Table III gives ``method``;
    ``(nan, nan)`` when it gives none."""
    values = [ms for pairs in PAPER_TABLE3_MS.values() for methods in pairs.values()
              for name, ms in methods.items() if name == method]
    if not values:
        return math.nan, math.nan
    return float(min(values)), float(max(values))
