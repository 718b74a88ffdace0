"""A HyperBones checkpoint that reads its teacher from the teacher checkpoint beside it
(``models.loading.TEACHER_FROM``, how the shipped ``hyperbones.pt`` is saved): it loads as the
whole model everywhere, bit for bit, and a missing, replaced or odd teacher file or record is
a one-line error naming the checkpoint."""

from __future__ import annotations

import pytest
import torch

from hyperbones.cli import main
from hyperbones.errors import InputFileError, ParameterError
from hyperbones.models.hyperbones import HyperBonesConfig, HyperBonesModel
from hyperbones.models.loading import (SHIPPED_HYPERBONES, SHIPPED_TEACHER, TEACHER_FROM, hyperbones_from_checkpoint,
                                       load_checkpoint, load_module_a, save_checkpoint, teacher_from_checkpoint,
                                       without_teacher)
from hyperbones.models.module_a import ModuleAConfig
from hyperbones.models.teacher import Teacher, TrunkConfig
from hyperbones.training.config import HyperBonesTrainingConfig, TeacherTrainingConfig

TRUNK = TrunkConfig(latent=8, blocks=1)
RUNTIME = ModuleAConfig(num_bones=8, shape_code=8, hidden=16, layers=2, pose_embedding=4, uv_features=4,
                        uv_resolution=16, conv_channels=(4, 8, 4))


def same_state(a: dict, b: dict) -> bool:
    return list(a) == list(b) and all(a[k].dtype == b[k].dtype and torch.equal(a[k], b[k]) for k in a)


@pytest.fixture
def pair(tmp_path):
    """A small teacher.pt and a whole HyperBones checkpoint built on it (a moving average kept,
    differing from the model in one of Module A's weights), in one folder."""
    torch.manual_seed(0)
    teacher = Teacher(TRUNK)
    joint = HyperBonesModel(HyperBonesConfig(TRUNK, RUNTIME))
    joint.teacher.load_state_dict(teacher.state_dict())
    model = joint.state_dict()
    some = next(name for name in model if name.startswith("runtime.") and model[name].is_floating_point())
    save_checkpoint(tmp_path / "teacher.pt", {"model": teacher.state_dict(), "step": 7,
                                              "config": TeacherTrainingConfig(model=TRUNK).as_dict()})
    whole = save_checkpoint(tmp_path / "whole.pt", {
        "model": model, "ema": {some: model[some] + 1}, "step": 9, "runtime_config": {"follow": 0.5},
        "config": HyperBonesTrainingConfig(model=TRUNK, runtime=RUNTIME).as_dict()})
    return tmp_path / "teacher.pt", whole


def slim_of(pair, name: str = "hyperbones.pt"):
    teacher, whole = pair
    return save_checkpoint(whole.with_name(name), without_teacher(load_checkpoint(whole), teacher))


def test_the_shipped_model_stores_its_teacher_once():
    raw = torch.load(SHIPPED_HYPERBONES, map_location="cpu", weights_only=True)
    assert raw[TEACHER_FROM]["file"] == SHIPPED_TEACHER.name
    assert not any(name.startswith("teacher.") for name in raw["model"])
    loaded = load_checkpoint(SHIPPED_HYPERBONES)
    teacher = load_checkpoint(SHIPPED_TEACHER)["model"]
    assert TEACHER_FROM not in loaded and set(loaded) == {"model", "config", "step", "runtime_config"}
    assert same_state({name[len("teacher."):]: value for name, value in loaded["model"].items()
                       if name.startswith("teacher.")}, teacher)
    stored = sum(value.numel() * value.element_size() for value in loaded["model"].values())
    assert SHIPPED_HYPERBONES.stat().st_size < stored - 0.9 * SHIPPED_TEACHER.stat().st_size


def test_a_checkpoint_without_its_teacher_loads_as_the_whole_one(pair):
    teacher, whole = pair
    slim = slim_of(pair)
    assert slim.stat().st_size < whole.stat().st_size
    raw = torch.load(slim, weights_only=True)
    assert not any(name.startswith("teacher.") for part in ("model", "ema") for name in raw[part])
    full, back = load_checkpoint(whole), load_checkpoint(slim)
    assert TEACHER_FROM not in back and list(back) == list(full)
    assert same_state(back["model"], full["model"]) and same_state(back["ema"], full["ema"])
    assert same_state(hyperbones_from_checkpoint(slim).state_dict(), hyperbones_from_checkpoint(whole).state_dict())
    assert same_state(load_module_a(slim).state_dict(), load_module_a(whole).state_dict())
    assert same_state(teacher_from_checkpoint(slim)[0].state_dict(), teacher_from_checkpoint(teacher)[0].state_dict())


def test_only_the_same_teacher_bit_for_bit_is_left_out(pair, tmp_path):
    teacher, whole = pair
    payload = load_checkpoint(whole)
    name = next(name for name in payload["model"] if name.startswith("teacher.") and "weight" in name)
    for changed in (torch.nextafter(payload["model"][name], torch.tensor(1.0)), payload["model"][name].double()):
        other = {**payload, "model": {**payload["model"], name: changed}}
        with pytest.raises(InputFileError, match=f"not the teacher of this model: 1 weight.*{name}"):
            without_teacher(other, teacher)
    with pytest.raises(ParameterError, match="a teacher checkpoint has no teacher to leave out"):
        without_teacher(load_checkpoint(teacher), teacher)


def _replace_teacher(pair, tmp_path):
    torch.manual_seed(1)
    save_checkpoint(pair[0], {"model": Teacher(TRUNK).state_dict(), "step": 7,
                              "config": TeacherTrainingConfig(model=TRUNK).as_dict()})


@pytest.mark.parametrize("change, message", [
    (lambda pair, tmp: pair[0].unlink(), "its teacher is read from teacher.pt beside it, which is missing"),
    (_replace_teacher, "which holds other weights than it was saved with"),
    (lambda pair, tmp: pair[1].replace(pair[0]), "which is not a teacher checkpoint"),
    (lambda pair, tmp: slim_of(pair, "teacher.pt"), "reads its own teacher from another file"),
])
def test_a_changed_teacher_file_is_refused(pair, tmp_path, change, message):
    slim = slim_of(pair)
    change(pair, tmp_path)
    with pytest.raises(InputFileError, match=message):
        load_checkpoint(slim)


@pytest.mark.parametrize("record", [None, "teacher.pt", {"file": "../teacher.pt", "sha256": "0"}, {"file": 3},
                                    {"file": "teacher.pt"}, {"file": "", "sha256": "0"}, {"file": "..", "sha256": "0"}])
def test_an_odd_teacher_record_is_refused(pair, record):
    slim = slim_of(pair)
    payload = torch.load(slim, weights_only=True)
    save_checkpoint(slim, {**payload, TEACHER_FROM: record})
    with pytest.raises(InputFileError, match=f"{slim}: its {TEACHER_FROM} record is not a file name beside it"):
        load_checkpoint(slim)


def test_export_shares_the_teacher_beside_it_when_asked(pair, tmp_path, capsys):
    teacher, whole = pair
    folder = tmp_path / "out"
    folder.mkdir()
    assert main(["export", str(whole), "--out", str(folder / "hyperbones.pt"), "--share-teacher"]) == 2
    assert "no teacher.pt beside" in capsys.readouterr().err and not (folder / "hyperbones.pt").exists()
    (folder / "teacher.pt").write_bytes(teacher.read_bytes())
    assert main(["export", str(whole), "--out", str(folder / "hyperbones.pt"), "--share-teacher"]) == 0
    assert main(["export", str(folder / "hyperbones.pt"), "--out", str(tmp_path / "again.pt")]) == 0
    assert TEACHER_FROM in torch.load(folder / "hyperbones.pt", weights_only=True)
    assert TEACHER_FROM not in torch.load(tmp_path / "again.pt", weights_only=True)  # a copy elsewhere is whole
    exported = load_checkpoint(whole)["ema"]
    assert same_state(load_checkpoint(folder / "hyperbones.pt")["model"], exported)
    assert same_state(load_checkpoint(tmp_path / "again.pt")["model"], exported)


def test_export_stores_the_shipped_runtime_settings_unless_told_otherwise(pair, tmp_path, capsys):
    """A training checkpoint stores no runtime settings; its export takes the shipped model's (so
    it runs and measures as the shipped one does), or another model's, or the defaults, with
    ``--runtime`` over them; a teacher takes none."""
    from dataclasses import replace

    from hyperbones.runtime.config import RuntimeConfig
    from hyperbones.runtime.simulator import runtime_config_of

    teacher, whole = pair
    training = save_checkpoint(tmp_path / "checkpoint.pt",
                               {key: value for key, value in load_checkpoint(whole).items() if key != "runtime_config"})
    shipped = runtime_config_of(load_checkpoint(SHIPPED_HYPERBONES))
    assert shipped != RuntimeConfig()

    def exported(*options):
        assert main(["export", str(training), "--out", str(tmp_path / "out.pt"), *options]) == 0
        return runtime_config_of(torch.load(tmp_path / "out.pt", weights_only=True))

    assert exported() == shipped
    assert f"proxy_vertices = {shipped.proxy_vertices}" in (tmp_path / "out.md").read_text()
    assert exported("--runtime", "follow=0.9") == replace(shipped, follow=0.9)
    assert exported("--runtime-from", "defaults") == RuntimeConfig()
    assert exported("--runtime-from", str(whole), "--runtime", "untangle=false") == \
        RuntimeConfig(follow=0.5, untangle=False)
    capsys.readouterr()
    assert main(["export", str(training), "--out", str(tmp_path / "bad.pt"), "--runtime-from", str(teacher)]) == 2
    assert f"{teacher}: stores no runtime settings" in capsys.readouterr().err
    assert main(["export", str(teacher), "--out", str(tmp_path / "t.pt"), "--runtime", "follow=0.9"]) == 2
    assert "a teacher has no runtime settings" in capsys.readouterr().err
    assert not (tmp_path / "bad.pt").exists() and not (tmp_path / "t.pt").exists()


def test_an_exported_model_exported_again_keeps_its_weights_and_its_training_record(pair, tmp_path, capsys):
    """Exporting an exported model changes only the runtime settings it stores: the weights,
    config and step stay bit for bit, and the training part of its summary (which a model that
    left its run has no log to rebuild from) is carried into the new summary."""
    from dataclasses import replace

    from hyperbones.runtime.simulator import runtime_config_of

    _, whole = pair
    assert main(["export", str(whole), "--out", str(tmp_path / "first.pt")]) == 0
    first_summary = (tmp_path / "first.md").read_text()
    # As a run with a TensorBoard log writes it (this fixture's run has none).
    record = "Training took 0.9 h of wall-clock time to this step.\n\nTraining log: | steps | loss |\n"
    (tmp_path / "first.md").write_text(first_summary.replace("(no TensorBoard log beside the checkpoint)\n", record))
    assert main(["export", str(tmp_path / "first.pt"), "--out", str(tmp_path / "again" / "second.pt"),
                 "--runtime", "uv_resolution=24", "--summary-from", str(tmp_path / "first.md")]) == 0
    first, second = (torch.load(tmp_path / name, weights_only=True) for name in ("first.pt", "again/second.pt"))
    assert same_state(first["model"], second["model"])
    assert (first["config"], first["step"]) == (second["config"], second["step"])
    assert runtime_config_of(second) == replace(runtime_config_of(first), uv_resolution=24)
    summary = (tmp_path / "again" / "second.md").read_text()
    assert "uv_resolution = 24" in summary and summary.endswith(record)
    assert f"Exported from {tmp_path / 'first.pt'}, itself an export" in summary
    # Without --summary-from, the summary beside the model is read.
    assert main(["export", str(tmp_path / "first.pt"), "--out", str(tmp_path / "third.pt")]) == 0
    assert (tmp_path / "third.md").read_text().endswith(record)

    capsys.readouterr()
    missing = tmp_path / "nowhere.md"
    assert main(["export", str(tmp_path / "first.pt"), "--out", str(tmp_path / "bad.pt"),
                 "--summary-from", str(missing)]) == 2
    assert f"{missing}: missing" in capsys.readouterr().err
    (tmp_path / "other.md").write_text("# notes\n")
    assert main(["export", str(tmp_path / "first.pt"), "--out", str(tmp_path / "bad.pt"),
                 "--summary-from", str(tmp_path / "other.md")]) == 2
    assert "holds no training summary" in capsys.readouterr().err
    assert main(["export", str(whole), "--out", str(tmp_path / "bad.pt"), "--summary-from", str(tmp_path / "first.md")]) == 2
    assert f"{whole}: --summary-from is for an exported HyperBones model" in capsys.readouterr().err
    assert not (tmp_path / "bad.pt").exists() and not (tmp_path / "bad.md").exists()
