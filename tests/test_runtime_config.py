"""RuntimeConfig: every setting of the per-frame runtime is a field, recorded with each run,
read by the runtime (no module constant), and overridable with ``--runtime``."""

import json
import math
from dataclasses import fields, replace

import pytest
import torch

from hyperbones.cli import main
from hyperbones.devices import runs_bfloat16_natively
from hyperbones.errors import ParameterError
from hyperbones.runtime.config import RuntimeConfig, parse_overrides

# A non-default value for every field, each one chosen so that it changes the walk below.
CHANGED = {
    "uv_resolution": 16,
    "conv_mlp": False,
    "bfloat16": True,
    "follow": 0.8,
    "loose_follow": 0.7,
    "carry_lag": 0.0,
    "follow_near": 0.0,
    "follow_far": 0.1,
    "contact": False,
    "contact_margin": 0.006,
    "query_distance": 0.01,
    "round_query_distance": 0.015,
    "round_search_gap": 0.008,
    "push_rounds": 1,
    "plane_reach": 0.01,
    "contact_rounds": 1,
    "untangle": False,
    "untangle_cosine": -0.5,
    "projection_iterations": 2,
    "projection_anchor": 0.2,
    "projection_stretch": 0.03,
    "projection_compression": 0.03,
    "proxy_vertices": 400,
    "proxy_sweeps": 5,
    "proxy_relaxation": 1.0,
    "proxy_push_reach": 0.001,
}
# Settings read only where a garment has a proxy: changed over a config with one.
PROXY_SETTINGS = {"proxy_sweeps", "proxy_relaxation", "proxy_push_reach"}


def test_every_field_has_a_changed_value_here():
    assert set(CHANGED) == {item.name for item in fields(RuntimeConfig)}
    for name, value in CHANGED.items():
        assert value != getattr(RuntimeConfig(), name), name


@pytest.fixture(scope="module")
def walk(body):
    """The shipped model's Module A on the dress (fitted, 1,000 vertices) and 12 frames of the
    built-in walk, posed."""
    from hyperbones.garment.templates import make_template
    from hyperbones.motion.load import load_motion
    from hyperbones.runtime.identity import encode_identity
    from hyperbones.models.loading import hyperbones_from_checkpoint

    model = hyperbones_from_checkpoint(None, "cpu")
    garment = make_template("dress", body, 1000)
    with torch.no_grad():
        identity = encode_identity(model, garment, body)
    motion = load_motion("walk", body).slice(0, 12)
    posed = body.pose(motion.joint_rotations, motion.root_translation)
    return model.runtime, identity, body, posed


def _run(walk, config: RuntimeConfig) -> torch.Tensor:
    from hyperbones.runtime.simulator import Simulator

    module_a, identity, body, posed = walk
    simulator = Simulator(module_a, [identity], body_faces=body.faces, config=config)
    roots = posed.joint_positions[:, 0]
    frames = []
    for t in range(posed.joint_rotations.shape[0]):
        bodies = posed.vertices[t:t + 1] if simulator.contact is not None else None
        frames.append(simulator.step(posed.joint_rotations[t:t + 1], roots[t:t + 1], bodies)[0])
    return torch.stack(frames)


@pytest.fixture(scope="module")
def default_walk(walk):
    return _run(walk, RuntimeConfig())


@pytest.fixture(scope="module")
def proxy_walk(walk):
    return _run(walk, RuntimeConfig(proxy_vertices=CHANGED["proxy_vertices"]))


@pytest.mark.parametrize("name", sorted(set(CHANGED) - {"push_rounds"}))
def test_each_setting_changes_the_output(walk, default_walk, proxy_walk, name):
    """The runtime reads each field: changing it alone changes the garment's motion."""
    base, reference = RuntimeConfig(), default_walk
    if name in PROXY_SETTINGS:
        base, reference = RuntimeConfig(proxy_vertices=CHANGED["proxy_vertices"]), proxy_walk
    if name == "proxy_push_reach":  # the sweeps' skin planes leave the final push-out nothing here
        base = RuntimeConfig(proxy_vertices=CHANGED["proxy_vertices"], proxy_sweeps=0)
        reference = _run(walk, base)
    changed = _run(walk, replace(base, **{name: CHANGED[name]}))
    if name == "bfloat16" and not runs_bfloat16_natively(torch.device("cpu")):
        # Emulated bfloat16 is slower than float32, so this CPU runs float32 either way.
        assert torch.equal(changed, reference)
        return
    assert float((changed - reference).abs().max()) > 1e-5, name


def test_push_rounds_change_the_output_in_creases(body):
    """Pushed off one face, a vertex in a crease can land inside the next: only the later
    push-outs (``push_rounds`` > 1) bring it out. Points under the skin all over the body
    (fingers, armpits, crotch included) show it."""
    from hyperbones.geometry.proximity import BodyProximity
    from hyperbones.runtime.push_out import BodyContact

    vertices, faces = body.rest_vertices, body.faces
    proximity = BodyProximity(faces)
    proximity.update(vertices)
    points = vertices[::3] - 0.008 * proximity.query(vertices[::3], max_distance=0.1).normal
    pushed = {rounds: BodyContact(faces, 1, config=RuntimeConfig(push_rounds=rounds))([points], vertices[None])[0]
              for rounds in (1, RuntimeConfig().push_rounds)}
    inside = {rounds: int((proximity.query(out, max_distance=0.1).signed_distance < 0).sum())
              for rounds, out in pushed.items()}
    assert inside[RuntimeConfig().push_rounds] < inside[1]


def test_the_run_records_every_setting(tmp_path):
    """simulate --runtime with every field changed: metrics.json records the config it ran with."""
    text = ",".join(f"{key}={value}" for key, value in CHANGED.items())
    out = tmp_path / "run"
    assert main(["simulate", "--garment", "tshirt", "--vertices", "1000", "--frames", "3", "--device", "cpu",
                 "--runtime", text, "--no-preview", "--quiet", "--out", str(out)]) == 0
    recorded = json.loads((out / "metrics.json").read_text())["runtime"]
    assert recorded == {**RuntimeConfig().as_dict(), **CHANGED}
    lbs = tmp_path / "lbs"
    assert main(["simulate", "--method", "lbs", "--garment", "tshirt", "--vertices", "1000", "--frames", "3",
                 "--no-preview", "--quiet", "--out", str(lbs)]) == 0
    assert json.loads((lbs / "metrics.json").read_text())["runtime"] is None


def test_the_shipped_model_carries_its_runtime_config():
    from hyperbones.errors import InputFileError
    from hyperbones.models.loading import hyperbones_payload
    from hyperbones.runtime.simulator import runtime_config_of

    payload = hyperbones_payload()
    # the validated choices: docs/experiments/*-realtime-runtime*.md, *-conv-mlp-24.md
    assert runtime_config_of(payload) == RuntimeConfig(uv_resolution=24, bfloat16=True, projection_iterations=4,
                                                       round_search_gap=0.003, proxy_vertices=1000)
    for bad in ({**payload["runtime_config"], "speed": 2}, {"follow": "fast"}, [0.6]):
        with pytest.raises(InputFileError, match="model.pt: .*runtime_config") as error:
            runtime_config_of({**payload, "runtime_config": bad}, "model.pt")
        assert "\n" not in str(error.value)


def test_overrides_parse_and_bad_ones_are_one_line_errors():
    assert parse_overrides("follow=0.5, untangle=false,push_rounds=2") == {"follow": 0.5, "untangle": False,
                                                                           "push_rounds": 2}
    assert RuntimeConfig().with_overrides("contact=off") == RuntimeConfig(contact=False)
    assert parse_overrides(None) == {} and parse_overrides({"follow": 0.5}) == {"follow": 0.5}
    for text, problem in [("follow", "expected key=value"), ("speed=2", "unknown setting 'speed'"),
                          ("follow=fast", "not a number"), ("follow=0", r"\(0, 1\]"),
                          ("untangle=maybe", "true or false"), ("push_rounds=1.5", "whole number"),
                          ("follow=0.5,follow=0.6", "given twice"), ("follow_near=0.05", "follow_near < follow_far"),
                          ("push_rounds=1e9", r"push_rounds=1000000000 must be in \[1, 64\]"),
                          ("projection_iterations=5000", r"must be in \[0, 1000\]")]:
        with pytest.raises(ParameterError, match=problem) as error:
            parse_overrides(text)
        assert "\n" not in str(error.value) and str(error.value).startswith("--runtime: ")
    with pytest.raises(ParameterError, match="unknown runtime setting"):
        RuntimeConfig.from_dict({"follow": 0.6, "bogus": 1})


def test_cli_refuses_a_bad_runtime_before_any_work(capsys):
    assert main(["eval", "--methods", "hyperbones", "--runtime", "contact_rounds=-1", "--out", "/nonexistent/x"]) == 2
    assert "hyperbones: error: --runtime: runtime contact_rounds=-1 must be in [0, 64]" in capsys.readouterr().err


def test_searching_again_only_where_it_matters_is_searching_everywhere(walk, default_walk, monkeypatch):
    """After a projection round the runtime searches only the vertices that may lie within range
    (``BodyContact._search_again``); searching every vertex gives the same garment, bit for bit."""
    from hyperbones.runtime.push_out import BodyContact

    original = BodyContact._search_again
    skipped = []

    def counted(self, proximity, garment, nearest, queried_at, floor):
        clear = floor - (garment - queried_at).norm(dim=1)
        skipped.append(int((clear > self.config.round_query_distance).sum()))
        return original(self, proximity, garment, nearest, queried_at, floor)

    monkeypatch.setattr(BodyContact, "_search_again", counted)
    assert torch.equal(_run(walk, RuntimeConfig()), default_walk)
    assert sum(skipped) > 0  # the dress's loose skirt is skipped somewhere

    def everywhere(self, proximity, garment, nearest, queried_at, floor):
        return original(self, proximity, garment, nearest, queried_at, torch.full_like(floor, -math.inf))

    monkeypatch.setattr(BodyContact, "_search_again", everywhere)
    assert torch.equal(_run(walk, RuntimeConfig()), default_walk)
