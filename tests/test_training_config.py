"""Typed training configs: the committed files load; bad files get one-line errors naming them."""

from pathlib import Path

import pytest

from hyperbones.errors import InputFileError
from hyperbones.training.config import TeacherTrainingConfig

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


@pytest.mark.parametrize("name", ["teacher.toml", "teacher-small.toml"])
def test_committed_configs_load(name):
    config = TeacherTrainingConfig.load(CONFIGS / name)
    assert set(config.data.train_clips).isdisjoint(config.data.test_clips)
    assert len(config.data.templates) == 6
    assert TeacherTrainingConfig.from_dict(config.as_dict()) == config  # the checkpoint round trip


def test_full_size_config_is_the_papers():
    config = TeacherTrainingConfig.load(CONFIGS / "teacher.toml")
    assert (config.model.latent, config.model.blocks) == (128, 15)
    assert config.train.learning_rate == 5e-5 and config.train.grad_clip == 1.0


@pytest.mark.parametrize("text, problem", [
    ("[model]\nlatent = 'big'\n", "must be int"),
    ("[model]\nwidth = 3\n", "unknown key"),
    ("[optimizer]\nlr = 1\n", "unknown section"),
    ("[data]\ntrain_clips = '02_01'\n", "must be a list"),
    ("[train\nsteps = 3\n", "not valid TOML"),
])
def test_bad_config_files(tmp_path, text, problem):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(InputFileError) as error:
        TeacherTrainingConfig.load(path)
    message = str(error.value)
    assert problem in message and "bad.toml" in message and "\n" not in message


def test_missing_config_file(tmp_path):
    with pytest.raises(InputFileError, match="not found"):
        TeacherTrainingConfig.load(tmp_path / "nope.toml")
