"""Linear blend skinning as one readable function of explicit tensors."""

from __future__ import annotations

import torch


def linear_blend_skinning(
    rest_vertices: torch.Tensor,
    skin_weights: torch.Tensor,
    transforms: torch.Tensor,
    frames_per_chunk: int = 64,
) -> torch.Tensor:
    """Skin rest vertices with per-joint rigid transforms.

    Args:
        rest_vertices: (V,3) vertices in the rest pose.
        skin_weights: (V,K) dense weights, rows summing to 1.
        transforms: (T,K,4,4) transforms mapping the rest pose to the posed one
            (the skinning transforms, not the joints' world frames).
        frames_per_chunk: frames blended at once; bounds the (chunk,V,12) buffer.

    Returns:
        (T,V,3) posed vertices.

    The per-vertex blended 3x4 matrix is one (V,K) @ (K,12) product per frame, which
    is far faster on CPU than gathering a sparse top-k of joints per vertex.
    """
    num_frames = transforms.shape[0]
    rows = transforms[..., :3, :].reshape(num_frames, transforms.shape[1], 12)
    out = []
    for start in range(0, num_frames, frames_per_chunk):
        blended = torch.matmul(skin_weights, rows[start : start + frames_per_chunk])
        blended = blended.view(-1, rest_vertices.shape[0], 3, 4)
        posed = (blended[..., :3] @ rest_vertices.unsqueeze(-1)).squeeze(-1) + blended[..., 3]
        out.append(posed)
    return torch.cat(out, dim=0) if out else rest_vertices.new_zeros((0,) + rest_vertices.shape)
