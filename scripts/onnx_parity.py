"""The exported runtime (ONNX, onnxruntime on the CPU) against the torch runtime without
contact, frame by frame over 300 frames of the walk on the default body: prints the largest
vertex difference, the mean of each frame's largest, and the graph's size.
(README, "Running the runtime in an engine"; tests/test_runtime_onnx.py asserts 0.1 mm.)

usage: python scripts/onnx_parity.py GARMENT VERTICES      e.g. tshirt 1500, dress 5000
"""
import sys
import tempfile
from pathlib import Path

import numpy as np
import onnxruntime

from hyperbones.body.anny_body import body_for
from hyperbones.body.shape import BodyShape
from hyperbones.garment.draped import draped_garment
from hyperbones.jobs.export_onnx import runtime_frame
from hyperbones.motion.load import load_motion
from hyperbones.runtime.onnx_frame import INPUTS, ONNX_OVERRIDES, write_onnx
from hyperbones.runtime.simulator import Simulator
garment_name, vertices = sys.argv[1], int(sys.argv[2])
frame, draped = runtime_frame(garment_name, vertices=vertices)
path = write_onnx(frame, Path(tempfile.mkdtemp()) / "runtime.onnx")
session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
body = body_for(BodyShape()); motion = load_motion("walk", body)
motion = motion.with_hold(300 - motion.num_frames).slice(0, 300)
posed = body.pose(motion.joint_rotations, motion.root_translation)
garment, rest = draped_garment(garment_name, body, vertices=vertices)
sim = Simulator.load([(garment, body)], overrides=ONNX_OVERRIDES, rest_vertices=[rest])
rot, roots = posed.joint_rotations.float(), posed.joint_positions[:, 0].float()
state = [v.numpy() for v in frame.initial_state().values()]; d = []
for t in range(300):
    e = sim.step(rot[t:t+1], roots[t:t+1])[0].numpy()
    o = session.run(None, dict(zip(INPUTS, [rot[t].numpy(), roots[t].numpy(), *state]))); state = o[1:]
    d.append(np.abs(o[0] - e).max())
print(f"{garment_name} {frame.num_vertices} v: 300 frames, largest difference {max(d):.3g} m, mean of per-frame max {np.mean(d):.3g} m; file {path.stat().st_size/1e6:.1f} MB")
