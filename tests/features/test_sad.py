"""The ``sad`` method is SeqSLAM's thumbnail of the matching library, with ``matching.sad``."""

import numpy as np
import pytest

from cmal_lcd.features import build_extractor

SAD = {"width": 16, "height": 8, "patch": 4}


def test_codes_are_the_matching_librarys_thumbnails(frames):
    from cmal_lcd.matching import sad_thumbnails

    extractor = build_extractor("sad", conf={"batch_size": 4, "sad": SAD})
    codes = extractor(frames)
    assert codes.shape == (len(frames), 16 * 8) and codes.dtype == np.float32
    np.testing.assert_array_equal(codes, sad_thumbnails(frames, width=16, height=8, patch=4))


def test_labels_and_metric(frames):
    extractor = build_extractor("sad", conf={"batch_size": 4, "sad": SAD})
    assert (extractor.label, extractor.metric, extractor.backend) == ("SAD", "sad", "numpy")
    assert "16x8" in extractor.weights and "4x4" in extractor.weights


def test_batch_size_does_not_change_the_codes(frames):
    one = build_extractor("sad", conf={"batch_size": 1, "sad": SAD})(frames)
    all_ = build_extractor("sad", conf={"batch_size": 100, "sad": SAD})(frames)
    np.testing.assert_array_equal(one, all_)


@pytest.mark.parametrize("key, value", [("width", 0), ("height", -1), ("patch", -1)])
def test_invalid_sizes_are_rejected_by_name(key, value):
    with pytest.raises(ValueError, match=f"matching.sad.{key}"):
        build_extractor("sad", conf={"batch_size": 4, "sad": {**SAD, key: value}})


def test_patch_zero_means_no_patch_normalisation(frames):
    from cmal_lcd.matching import sad_thumbnails

    extractor = build_extractor("sad", conf={"batch_size": 4, "sad": {**SAD, "patch": 0}})
    assert "no patch normalisation" in extractor.weights
    np.testing.assert_array_equal(extractor(frames),
                                  sad_thumbnails(frames, width=16, height=8, patch=0))
