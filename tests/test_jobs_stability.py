"""Kinetic energy, vertex speeds and the check teacher tables (run on the LBS method)."""

import torch

from hyperbones.cli import main
from hyperbones.physics.sequence_metrics import kinetic_energy, vertex_speeds


def test_kinetic_energy_of_uniform_motion():
    masses = torch.tensor([1.0, 2.0, 3.0])
    start = torch.randn(3, 3)
    velocity = torch.tensor([0.3, -0.4, 0.0])  # 0.5 m/s
    frames = torch.stack([start + t * velocity / 30.0 for t in range(5)])
    assert torch.allclose(kinetic_energy(frames, masses, 1 / 30), torch.full((4,), 0.5 * 6.0 * 0.25))
    assert torch.allclose(vertex_speeds(frames, 1 / 30), torch.full((4, 3), 0.5))


def test_check_teacher_tables_on_lbs(body, capsys):
    assert main(["check", "teacher", "--method", "lbs", "--garments", "tshirt", "--vertices", "1000", "--frames", "60",
                 "--hold", "1", "--quiet"]) == 0
    out = capsys.readouterr().out
    stability = next(line for line in out.splitlines() if line.startswith("| tshirt | walk |"))
    cells = [c.strip() for c in stability.strip("|").split("|")]
    assert cells[2] == "60" and cells[3] == "True" and cells[5] == "no"
    # LBS has no dynamics: once the body stops, the garment stops at once.
    settling = [line for line in out.splitlines() if line.startswith("| tshirt |")][-1]
    cells = [c.strip() for c in settling.strip("|").split("|")]
    assert float(cells[1]) > 0 and float(cells[3]) == 0.0 and float(cells[5]) == 0.0
