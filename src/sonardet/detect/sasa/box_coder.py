"""Symmetry-aware point bin-residual box coder (reference ``PointBinResidualCoder``, no mean size).

A box ``[x, y, z, l, w, h, yaw]`` (m, rad) is encoded relative to an anchor point ``a`` (the vote):

    code = [x - ax, y - ay, z - az, log l, log w, log h, bin logits (nb), bin residuals (nb)]

The angle is *folded* by the class's symmetry order k (yaw repeats every 2 pi / k): ``phi = k * yaw``
is binned over 2 pi with ``nb`` bins centred at ``j * 2 pi / nb`` (reference binning); the residual is
``(phi + D/2) mod 2 pi - bin * D - D/2`` divided by the bin width ``D``, in [-0.5, 0.5). Decoding
gives ``yaw = wrap(phi) / k`` in [-pi/k, pi/k) -- for tetrapods (k = 3) the convention of the scene
boxes. Classes with k = 0 (rotationally symmetric) have no yaw: it decodes as 0 and their angle
targets are masked (``angle_mask`` False).
"""

from __future__ import annotations

import math

import torch

__all__ = ["PointBinResidualCoder"]


class PointBinResidualCoder:
    """Encode/decode boxes around anchor points.

    Args:
        num_bins: angle bins over the folded angle (reference ``angle_bin_num`` 12).
        symmetry_orders: per class index, 0 (no yaw) or k >= 1 (yaw period 2 pi / k).
    """

    def __init__(self, num_bins: int, symmetry_orders):
        self.num_bins = int(num_bins)
        self.bin_size = 2 * math.pi / self.num_bins
        self.symmetry_orders = torch.as_tensor([int(k) for k in symmetry_orders], dtype=torch.long)
        self.code_size = 6 + 2 * self.num_bins

    def _order(self, labels: torch.Tensor) -> torch.Tensor:
        return self.symmetry_orders.to(labels.device)[labels.long().clamp(min=0)]

    def encode(self, boxes: torch.Tensor, points: torch.Tensor, labels: torch.Tensor):
        """Targets of gt boxes (K, 7) for anchors (K, 3) of classes ``labels`` (K,) (0-based).

        Returns (reg (K, 6) centre offsets (m) and log sizes, bin (K,) int64, res (K,) in [-0.5, 0.5),
        angle_mask (K,) bool: False for yaw-free classes).
        """
        k = self._order(labels)
        off = boxes[:, :3] - points
        size = torch.log(boxes[:, 3:6].clamp(min=1e-5))
        phi = boxes[:, 6] * k.to(boxes.dtype).clamp(min=1)
        shifted = torch.remainder(phi + 0.5 * self.bin_size, 2 * math.pi)
        bin_id = torch.floor(shifted / self.bin_size).long().clamp(0, self.num_bins - 1)
        res = (shifted - bin_id.to(shifted.dtype) * self.bin_size - 0.5 * self.bin_size) / self.bin_size
        return torch.cat([off, size], dim=-1), bin_id, res, k > 0

    def decode(self, codes: torch.Tensor, points: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
        """Boxes (..., 7) from codes (..., code_size), anchors (..., 3) and class indices (...).

        Yaw: argmax bin + its residual, unfolded by the class's symmetry order; 0 for k = 0.
        Differentiable w.r.t. the offsets, sizes and the residual of the chosen bin.
        """
        nb = self.num_bins
        centre = points + codes[..., 0:3]
        size = torch.exp(codes[..., 3:6].clamp(max=6.0))
        bins = codes[..., 6:6 + nb]
        res = codes[..., 6 + nb:6 + 2 * nb]
        bin_id = bins.argmax(dim=-1, keepdim=True)
        r = torch.gather(res, -1, bin_id).squeeze(-1)
        phi = (bin_id.squeeze(-1).to(codes.dtype) + r) * self.bin_size
        phi = torch.remainder(phi + math.pi, 2 * math.pi) - math.pi
        k = self._order(labels).to(codes.dtype)
        yaw = torch.where(k > 0, phi / k.clamp(min=1), torch.zeros_like(phi))
        return torch.cat([centre, size, yaw.unsqueeze(-1)], dim=-1)
