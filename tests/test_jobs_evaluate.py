"""eval --split: the training config's validation set chooses, its test set only reports."""

from pathlib import Path

import pytest

from hyperbones.errors import ParameterError
from hyperbones.jobs.evaluate import split_set
from hyperbones.training.config import DataConfig


def test_the_splits_come_from_the_config_and_do_not_share_clips():
    data = DataConfig()
    validation, validation_bodies, rates = split_set("validation")
    test, test_bodies, _ = split_set("test")
    assert [Path(path).stem for path in validation] == list(data.validation_clips)
    assert [Path(path).stem for path in test] == list(data.test_clips)
    assert not {Path(path).stem for path in validation} & {Path(path).stem for path in test}
    assert {Path(path).stem for path in validation} <= set(data.train_clips)
    assert validation_bodies == list(data.validation_bodies) and test_bodies == list(data.test_bodies)
    assert rates == data.source_fps
    custom = DataConfig(validation_clips=("01_01",))
    assert [Path(path).stem for path in split_set("validation", custom)[0]] == ["01_01"]
    with pytest.raises(ParameterError, match="--split must be one of"):
        split_set("train")
