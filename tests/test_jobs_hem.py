"""check hem: the hem after the body stops, for LBS (which stops with the body)."""

import torch
from PIL import Image

from hyperbones.cli import main
from hyperbones.jobs.hem import HemCurve, hem_curves


def test_curve_measures():
    times = torch.arange(10, dtype=torch.float64) / 10
    curve = HemCurve("x", times, torch.linspace(0.05, 0.0, 10, dtype=torch.float64),
                     torch.tensor([0.0, 0.5, 0.3, 0.1, 0.03, 0.01, 0.01, 0.0, 0.0, 0.0], dtype=torch.float64))
    assert curve.moving_for == 0.4  # the last frame above 2 cm/s
    assert curve.displacement_at(0.0) == 0.05 and curve.displacement_at(99.0) == 0.0


def test_lbs_hem_stops_with_the_body(tmp_path, capsys):
    (curve,) = hem_curves(["lbs"], "dress", "walk", hold=1.0, vertices=1000)
    assert curve.times[-1] > 0.9 and curve.moving_for <= 1 / 30 + 1e-9
    out = tmp_path / "hem.png"
    assert main(["check", "hem", "--methods", "lbs", "--vertices", "1000", "--hold", "1", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "| lbs |" in printed and str(out.resolve()) in printed
    assert Image.open(out).size == (840, 480)
