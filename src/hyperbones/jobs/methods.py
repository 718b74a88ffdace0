"""The simulation methods by name, as ``simulate``, ``eval`` and ``bench`` offer them.

Each constructor takes (garment, body, rest_vertices=, material=, checkpoint=, device=,
progress=) and the hyperbones ones also uv_resolution= and runtime=; the result's
``run(posed_body)`` returns (T,V,3) garment positions and ``frames(posed_body)`` yields them
one by one. Each library is imported only when its method is built, so naming the methods
(``--help``) stays cheap.
"""

from __future__ import annotations


def _lbs(*args, **kwargs):
    from hyperbones.rig.garment_skinning import LbsMethod

    return LbsMethod(*args, **kwargs)


def _teacher(*args, **kwargs):
    from hyperbones.runtime.teacher_method import TeacherMethod

    return TeacherMethod(*args, **kwargs)


def _hyperbones(*args, **kwargs):
    from hyperbones.runtime.hyperbones_method import HyperBonesMethod

    return HyperBonesMethod(*args, **kwargs)


def _hyperbones_raw(*args, **kwargs):
    from hyperbones.runtime.hyperbones_method import HyperBonesMethod

    return HyperBonesMethod(*args, raw=True, **kwargs)


def _hyperbones_onnx(*args, **kwargs):
    from hyperbones.runtime.onnx_method import OnnxRuntimeMethod

    return OnnxRuntimeMethod(*args, **kwargs)


def _physics(*args, **kwargs):
    from hyperbones.training.physics_method import PhysicsMethod

    return PhysicsMethod(*args, **kwargs)


METHODS = {"lbs": _lbs, "teacher": _teacher, "hyperbones": _hyperbones, "hyperbones-raw": _hyperbones_raw,
           "hyperbones-onnx": _hyperbones_onnx, "physics": _physics}
"""Method name -> constructor: lbs (skinning), teacher (Module C), hyperbones (the per-frame
runtime), hyperbones-raw (Module A alone), hyperbones-onnx (the runtime's exported graph,
no body contact, in onnxruntime), physics (per-frame energy minimisation)."""
