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

import logging
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd

from cmal_lcd.evaluation.loop_closure import (dataset_ground_truth, dataset_sequences,
                                              evaluate_drive_pairs)
from cmal_lcd.evaluation.protocol import MatchingProtocol
from cmal_lcd.matching import SeqSLAMParams
from cmal_lcd.matching.normalise import CodeNormalisation, centring_sample, condition_means

logger = logging.getLogger(__name__)

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
    ground_truth : {"poses", "index"} or mapping
        As :func:`~cmal_lcd.evaluation.loop_closure.ground_truth_for_pair`'s ``kind``
        (:func:`~cmal_lcd.evaluation.loop_closure.dataset_ground_truth`).
    pose_tolerance : float
    batch_size : int
        Frames per encoder call.
    sequences : mapping
        Sequence labels of the drives holding several sequences
        (:func:`~cmal_lcd.evaluation.loop_closure.dataset_sequences`).
    """

    val_images: np.ndarray
    val_frames: pd.DataFrame
    pairs: Sequence[Sequence[str]]
    centring_images: np.ndarray
    centring_labels: np.ndarray
    n_conditions: int
    params: SeqSLAMParams
    d_thresh: int
    ground_truth: str | Mapping
    pose_tolerance: float
    batch_size: int = 128
    protocol: MatchingProtocol = field(default=MONITOR_PROTOCOL)
    sequences: Mapping = field(default_factory=dict)

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

    def score(self, val_codes: np.ndarray, centring_codes: np.ndarray) -> dict[str, float]:
        """Mean over validation pairs of :data:`MONITOR_METRICS` for given codes.

        Parameters
        ----------
        val_codes : ndarray (N, F)
            Codes of ``val_images``, same order.
        centring_codes : ndarray (M, F)
            Codes of ``centring_images``, same order.

        Returns
        -------
        dict
            ``{"val/<metric>": mean}``; empty when there are no validation pairs.
        """
        if len(val_codes) == 0 or not self.pairs:
            return {}
        import torch

        means = condition_means(np.asarray(centring_codes), np.asarray(self.centring_labels),
                                self.n_conditions)
        # numba's parallel kernels share the OpenMP runtime with torch and leave its thread
        # count at numba's (every core): restore it, or the training that called us continues
        # on more threads, with other float rounding (a resumed run would then differ)
        threads = torch.get_num_threads()
        try:
            rows = [e.metrics for _, _, e in evaluate_drive_pairs(
                np.asarray(val_codes), self.val_frames, self.pairs, metric="sqeuclidean",
                params=self.params, d_thresh=self.d_thresh, ground_truth=self.ground_truth,
                pose_tolerance=self.pose_tolerance, protocol=self.protocol, train_means=means,
                sequences=self.sequences)]
        finally:
            torch.set_num_threads(threads)
        return {f"val/{name}": float(np.mean([r[name] for r in rows]))
                for name in MONITOR_METRICS}

    def __call__(self, model: Any) -> dict[str, float]:
        """:meth:`score` of ``model``'s codes of the validation and centring frames."""
        if len(self.val_images) == 0 or not self.pairs:
            return {}
        return self.score(self.encode(model, self.val_images),
                          self.encode(model, self.centring_images))


def dataset_monitor(dataset: Any, matching: Any, *, per_condition: int
                    ) -> ValidationMonitor | None:
    """The monitor of a dataset's validation pairs; None when it has none.

    Parameters
    ----------
    dataset : cmal_lcd.data.store.Dataset
    matching : mapping
        The ``matching`` node of the checked config (typed by
        :func:`cmal_lcd.schema.validate`): Table I search, ``d_thresh``, ``pose_tolerance``.
    per_condition : int
        Training frames per condition for the centring means
        (``features.train_frames_per_condition``, as the features stage uses).
    """
    val_images, val_frames = dataset.validation()
    pairs = dataset.pairs("val")
    if len(val_images) == 0 or not pairs:
        logger.info("no validation drives in %s: nothing to monitor", dataset.path)
        return None
    d_thresh, pose_tolerance = matching["d_thresh"], matching["pose_tolerance"]
    train_images, train_frames = dataset.train()
    rows, labels = centring_sample(dataset.conditions, train_frames["condition"],
                                   per_condition=per_condition)
    return ValidationMonitor(
        val_images=val_images, val_frames=val_frames, pairs=pairs,
        centring_images=train_images[rows], centring_labels=labels,
        n_conditions=len(dataset.conditions), params=SeqSLAMParams.from_config(matching),
        d_thresh=d_thresh,
        ground_truth=dataset_ground_truth(dataset.meta),
        pose_tolerance=pose_tolerance,
        sequences=dataset_sequences(dataset.meta))
