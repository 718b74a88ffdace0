"""Typed training configs: the committed files load and state only what differs from the defaults;
every field is documented where it is defined; ``--set`` overrides; the validation split's rules;
bad files and overrides get one-line errors naming them."""

import ast
import inspect
import re
import tomllib
from pathlib import Path

import pytest

from hyperbones.errors import InputFileError, ParameterError
from hyperbones.training import config as config_module
from hyperbones.training.config import (DataConfig, HyperBonesTrainingConfig, JointConfig, TeacherTrainingConfig,
                                        TrainConfig, apply_overrides, load_config)

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
SHIPPED = sorted(CONFIGS.glob("*.toml"))
CHECKPOINTS = Path(__file__).resolve().parents[1] / "src" / "hyperbones" / "checkpoints"
DATE_OR_TABLE = re.compile(r"20[0-9]{2}-[0-9]{2}-[0-9]{2}|^\s*#?\s*\|.*\|", re.MULTILINE)
MEASUREMENT = re.compile(r"\d\s*(ms|%|J|cm²|s of|min)\b|measured")


@pytest.mark.parametrize("path", SHIPPED, ids=lambda path: path.name)
def test_committed_configs_load(path):
    config = load_config(path)
    joint = "joint" in tomllib.loads(path.read_text())
    assert type(config) is (HyperBonesTrainingConfig if joint else TeacherTrainingConfig)
    assert set(config.data.train_clips).isdisjoint(config.data.test_clips)
    assert set(config.data.validation_clips) <= set(config.data.train_clips)
    assert config.data.validation_bodies == config.data.test_bodies
    assert len(config.data.templates) == 6
    assert type(config).from_dict(config.as_dict()) == config  # the checkpoint round trip


@pytest.mark.parametrize("path", SHIPPED, ids=lambda path: path.name)
def test_configs_state_only_what_differs_from_the_defaults(path):
    values = tomllib.loads(path.read_text())
    config = load_config(path)
    defaults = type(config)().as_dict()
    loaded = config.as_dict()
    for section, table in values.items():
        for key in table:
            assert loaded[section][key] != defaults[section][key], f"{path.name}: {section}.{key} is the default"
    comments = [line for line in path.read_text().splitlines() if line.lstrip().startswith("#") or " #" in line]
    assert len(comments) <= 3 and all(line.startswith("#") for line in comments)  # a header, nothing inline
    assert not DATE_OR_TABLE.search(path.read_text()) and not MEASUREMENT.search(path.read_text())
    assert f"hyperbones train --config configs/{path.name}" in path.read_text()


def test_full_size_config_is_the_papers():
    config = TeacherTrainingConfig.load(CONFIGS / "teacher.toml")
    assert (config.model.latent, config.model.blocks) == (128, 15)
    assert config.train.learning_rate == 5e-5 and config.train.grad_clip == 1.0


@pytest.mark.parametrize("section", [DataConfig, TrainConfig, JointConfig], ids=lambda kind: kind.__name__)
def test_every_field_has_its_docstring(section):
    """Each field is followed by its own docstring (the attribute docstring nerfstudio uses)."""
    body = ast.parse(inspect.getsource(section)).body[0].body
    documented = {statement.target.id for statement, after in zip(body, body[1:])
                  if isinstance(statement, ast.AnnAssign) and isinstance(after, ast.Expr)
                  and isinstance(after.value, ast.Constant) and isinstance(after.value.value, str)}
    assert documented == set(section.__dataclass_fields__)
    class_doc = inspect.getdoc(section)
    assert 1 <= len(class_doc.splitlines()) <= 3


def test_no_experiment_records_in_the_code():
    source = inspect.getsource(config_module)
    assert not DATE_OR_TABLE.search(source) and not MEASUREMENT.search(source)


@pytest.mark.parametrize("text, problem", [
    ("[model]\nlatent = 'big'\n", "must be int"),
    ("[model]\nwidth = 3\n", "unknown key"),
    ("[optimizer]\nlr = 1\n", "unknown section"),
    ("[data]\ntrain_clips = '02_01'\n", "must be a list"),
    ("[train\nsteps = 3\n", "not valid TOML"),
    ("[data]\nvalidation_clips = ['16_21']\n", "are test clips"),
    ("[data]\ntrain_clips = ['01_01']\n", "not in data.train_clips"),
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


def test_overrides():
    config = load_config(CONFIGS / "hyperbones-small.toml")
    changed = apply_overrides(config, ["train.steps=100", "train.learning_rate=1e-3", "runtime.use_conv=false",
                                       "train.init_from=runs/teacher/checkpoint.pt", "train.device=cpu",
                                       "data.source_fps={\"74_06\" = 50}", "joint.bank=", "data.hop_speeds=[1, 2]"])
    assert type(changed) is HyperBonesTrainingConfig and changed is not config
    assert changed.train.steps == 100 and changed.train.learning_rate == 1e-3 and changed.runtime.use_conv is False
    assert changed.train.init_from == "runs/teacher/checkpoint.pt" and changed.train.device == "cpu"
    assert changed.data.source_fps == {"74_06": 50.0} and changed.joint.bank == ""
    assert changed.data.hop_speeds == (1.0, 2.0) and isinstance(changed.data.hop_speeds[0], float)
    assert changed.train.seed == config.train.seed and config.train.steps != 100  # the rest, and the input, unchanged
    assert apply_overrides(config, ["train.init_from=123"]).train.init_from == "123"  # a string field keeps the text
    assert apply_overrides(config, []) == config and apply_overrides(config, None) == config
    # A section's overrides apply together: the training clips and the validation clips among them.
    narrowed = apply_overrides(config, ['data.train_clips=["01_01", "02_01"]', 'data.validation_clips=["02_01"]'])
    assert narrowed.data.train_clips == ("01_01", "02_01") and narrowed.data.validation_clips == ("02_01",)
    assert type(narrowed).from_dict(narrowed.as_dict()) == narrowed


@pytest.mark.parametrize("override, problem", [
    ("train.stepz=3", "unknown key 'stepz'"),
    ("trian.steps=3", "unknown section 'trian'"),
    ("joint.bank=runs/x", "unknown section 'joint'"),  # a teacher config has no [joint]
    ("train.steps", "expected section.key=value"),
    ("steps=3", "expected section.key=value"),
    ("train.steps=1e3", "train.steps must be int"),
    ("train.steps=many", "train.steps must be int"),
    ("data.drape=1", "data.drape must be bool"),
    ("data.train_clips=01_01", "data.train_clips must be a list"),
    ('data.train_clips=["01_01", "02_01"]', "not in data.train_clips"),
    ('data.validation_clips=["16_21"]', "are test clips"),
])
def test_override_errors_are_one_line(override, problem):
    with pytest.raises(ParameterError) as error:
        apply_overrides(load_config(CONFIGS / "teacher-small.toml"), [override])
    message = str(error.value)
    assert message.startswith(f"--set {override}") and problem in message and "\n" not in message


def test_override_given_twice():
    with pytest.raises(ParameterError, match="given twice"):
        apply_overrides(TeacherTrainingConfig(), ["train.steps=1", "train.steps=2"])


def test_validation_split():
    data = DataConfig()
    assert set(data.validation_clips) <= set(data.train_clips)
    assert not set(data.validation_clips) & set(data.test_clips)
    assert data.validation_bodies == data.test_bodies
    with pytest.raises(ParameterError, match="are test clips"):
        DataConfig(validation_clips=("16_07", "16_35"))
    with pytest.raises(ParameterError, match="not in data.train_clips"):
        DataConfig(validation_clips=("16_07", "86_01"))
    # Built-in motions alone (no clip trained on) leave no clip to validate on: nothing to check.
    assert DataConfig(train_clips=(), builtins=("walk",)).validation_clips == data.validation_clips


def test_checkpoints_from_before_the_validation_split_load():
    """A checkpoint's saved config lacks fields added since; they take the defaults, so ``--resume``
    (which compares ``from_dict`` of the saved dict with the config file's) still matches."""
    config = load_config(CONFIGS / "hyperbones-small.toml")
    saved = config.as_dict()
    for key in ("validation_clips", "validation_bodies"):
        del saved["data"][key]
    assert HyperBonesTrainingConfig.from_dict(saved).as_dict() == config.as_dict()


@pytest.mark.parametrize("checkpoint, path", [("teacher.pt", "teacher-small.toml"),
                                              ("hyperbones.pt", "hyperbones-finetune.toml")])
def test_shipped_checkpoints_were_trained_by_the_shipped_configs(checkpoint, path):
    """Every setting the shipped checkpoint saved is its config file's, except where the machine
    that trained it kept its bank and its starting checkpoint (files, not settings)."""
    from hyperbones.models.loading import load_checkpoint

    payload = load_checkpoint(CHECKPOINTS / checkpoint)
    config = load_config(CONFIGS / path)
    saved = type(config).from_dict(payload["config"], checkpoint).as_dict()  # as the --resume check reads it
    expected = config.as_dict()
    if "joint" in expected:
        for section, key in (("joint", "bank"), ("train", "init_from")):
            assert saved[section][key] and expected[section][key]
            saved[section][key] = expected[section][key]
    assert saved == expected
