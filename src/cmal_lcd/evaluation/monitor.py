"""Validation place recognition measured *during* training, to see where training plateaus.

The training losses say how well the GAN plays its game, not whether the codes recognise
places. :class:`ValidationMonitor` encodes the validation drives (the world's validation route,
or a real dataset's validation index range; never a test drive) with the model as it is at a
logged iteration and scores them exactly as the ``select_protocol`` stage scores a candidate:
SeqSLAM with Table I's search over every validation pair. The training loop writes the result
to ``train_log.csv`` (columns ``val/recall_at_100p``, ``val/auc_pr``,
``val/single_frame_recall_at_1``), and ``iterations`` is chosen where these flatten.

The monitor fixes one protocol, :data:`MONITOR_PROTOCOL` (condition-directed centring from the
model's own codes of a training sample, L2, no enhancement): the protocol stage has not run yet
when the model trains. Encoding uses eval mode and no random draw, so a monitored run trains
the same weights as an unmonitored one (tested).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import pandas as pd

from cmal_lcd.evaluation.loop_closure import evaluate_drive_pairs
from cmal_lcd.evaluation.protocol import MatchingProtocol
from cmal_lcd.matching import SeqSLAMParams
from cmal_lcd.matching.normalise import CodeNormalisation, condition_means

#: Centre each code by the training mean of its nearest condition, L2, no enhancement.
MONITOR_PROTOCOL = MatchingProtocol(CodeNormalisation("condition", True), enhance=False,
                                    r_window=10)
#: Metrics logged, as the mean over validation pairs (``val/<name>`` in ``train_log.csv``).
MONITOR_METRICS = ("recall_at_100p", "auc_pr", "single_frame_recall_at_1")


@dataclass
class ValidationMonitor:
    """Scores a model's codes on the validation pairs; ``monitor(model) -> {"val/...": float}``.

    Attributes
    ----------
    val_images : ndarray, uint8 (N, H, W, 3)
        Every validation frame, in the order of ``val_frames``.
    val_frames : DataFrame
        Their frame table (index ``0..N-1``; ``drive``, and ``x, y`` for pose ground truth).
    pairs : sequence of [route, reference_drive, query_drive, pair]
        The validation pairs (``Dataset.pairs("val")``).
    centring_images : ndarray, uint8 (M, H, W, 3)
        Training frames whose codes give the per-condition centring means.
    centring_labels : ndarray, int (M,)
        Their condition index.
    n_conditions : int
    params : SeqSLAMParams
        Table I search; enhancement is set by :data:`MONITOR_PROTOCOL`.
    d_thresh : int
    ground_truth : {"poses", "index"}
    pose_tolerance : float
    batch_size : int
        Frames per encoder call.
    """

    val_images: np.ndarray
    val_frames: pd.DataFrame
    pairs: Sequence[Sequence[str]]
    centring_images: np.ndarray
    centring_labels: np.ndarray
    n_conditions: int
    params: SeqSLAMParams
    d_thresh: int
    ground_truth: str
    pose_tolerance: float
    batch_size: int = 128
    protocol: MatchingProtocol = field(default=MONITOR_PROTOCOL)

    def encode(self, model: Any, images: np.ndarray) -> np.ndarray:
        """Codes ``float32 (len(images), F)`` of ``model.encode`` in eval mode, without
        gradients; the model's train/eval mode is restored afterwards."""
        import torch

        from cmal_lcd.models.images import preprocess

        device = next(model.parameters()).device
        was_training = model.training
        model.eval()
        try:
            with torch.inference_mode():
                parts = [model.encode(preprocess(images[i:i + self.batch_size],
                                                 image_size=model.image_size).to(device))
                         .reshape(len(images[i:i + self.batch_size]), -1)
                         .to("cpu", torch.float32).numpy()
                         for i in range(0, len(images), self.batch_size)]
        finally:
            model.train(was_training)
        return np.concatenate(parts, axis=0)

    def __call__(self, model: Any) -> dict[str, float]:
        """Mean over validation pairs of :data:`MONITOR_METRICS`, keys ``val/<metric>``."""
        if len(self.val_images) == 0 or not self.pairs:
            return {}
        means = condition_means(self.encode(model, self.centring_images),
                                np.asarray(self.centring_labels), self.n_conditions)
        codes = self.encode(model, self.val_images)
        rows = [e.metrics for _, _, e in evaluate_drive_pairs(
            codes, self.val_frames, self.pairs, metric="sqeuclidean", params=self.params,
            d_thresh=self.d_thresh, ground_truth=self.ground_truth,
            pose_tolerance=self.pose_tolerance, protocol=self.protocol, train_means=means)]
        return {f"val/{name}": float(np.mean([r[name] for r in rows]))
                for name in MONITOR_METRICS}
