"""Times ``hyperbones view``'s scenes: the first, then a body-shape, a fabric and two method
changes made through viser's handles (as a user's drag makes them), and counts the frames
the player shows in 3 s. Prints one line each (docs/experiments/2026-11-29-gltf-and-viewer.md).

usage: python scripts/viewer_timings.py [--vertices N]
"""

from __future__ import annotations

import argparse
import socket
import time

from hyperbones.viewer.app import Viewer
from hyperbones.viewer.choice import Choice


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vertices", type=int, default=5000)
    vertices = parser.parse_args().vertices
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    start = time.time()
    viewer = Viewer(Choice(vertices=vertices), ["tshirt"], ["walk"], port=port, playing=True)
    try:
        viewer.wait_ready()
        print(f"first scene: {time.time() - start:.1f} s; {viewer.metrics.content}")
        shown, start = viewer._frame, time.perf_counter()
        time.sleep(3.0)
        frames = viewer.result.body_vertices.shape[0]
        print(f"player: {(viewer._frame - shown) % frames / (time.perf_counter() - start):.1f} frames a second")
        for change, control, value in [("body weight 0.8", viewer.body["weight"], 0.8),
                                       ("fabric stretch x2", viewer.fabric["stretch"], 2.0),
                                       ("method LBS", viewer.method, "LBS (skinning only)"),
                                       ("method HyperBones", viewer.method, "HyperBones")]:
            start = time.time()
            control.value = value
            viewer.wait_ready()
            print(f"{change}: {time.time() - start:.1f} s; {viewer.metrics.content}")
    finally:
        viewer.close()


if __name__ == "__main__":
    main()
