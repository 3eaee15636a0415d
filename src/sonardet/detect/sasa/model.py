"""The SASA detector: backbone + vote head + box coder + losses + post-processing (reference ``Point3DSSD``).

``SASADetector(params)`` maps a batch ``{"xyz": (B, N, 3) m, "features": (B, N, 1) height above ground
(m)}`` to the backbone and head outputs; ``loss(out, batch)`` gives the training loss and
``predict(out)`` the post-processed boxes per scene (local frame).
"""

from __future__ import annotations

import torch
from torch import nn

from .backbone import SASABackbone
from .box_coder import PointBinResidualCoder
from .head import VoteHead
from .losses import SASALoss
from .ops import iou3d_rotated, nms_bev_rotated

__all__ = ["SASADetector", "nms"]


def nms(boxes: torch.Tensor, scores: torch.Tensor, mode: str, iou: float, pre_max: int | None = None,
        post_max: int | None = None) -> torch.Tensor:
    """Greedy class-agnostic NMS; returns kept indices (descending score).

    mode "bev": rotated BEV IoU (ops.nms_bev_rotated, the reference ``nms_gpu``); "3d": rotated BEV
    overlap x vertical overlap (3-D IoU, ops.iou3d_rotated), so stacked elements survive.
    Args: boxes (K, 7) [x, y, z, l, w, h, yaw] (m, rad); scores (K,); iou threshold in [0, 1].
    """
    if mode == "bev":
        return nms_bev_rotated(boxes, scores, iou, pre_max, post_max)
    order = torch.sort(scores, descending=True, stable=True).indices
    if pre_max is not None:
        order = order[:pre_max]
    if order.numel() == 0:
        return order
    b = boxes[order].detach()
    ious = iou3d_rotated(b, b).cpu()
    K = order.numel()
    removed = torch.zeros(K, dtype=torch.bool)
    keep = []
    limit = K if post_max is None else int(post_max)
    for i in range(K):
        if removed[i]:
            continue
        keep.append(i)
        if len(keep) >= limit:
            break
        removed |= ious[i] > iou
    return order[torch.as_tensor(keep, dtype=torch.long, device=order.device)]


class SASADetector(nn.Module):
    """3DSSD + SASA single-stage point detector (sonar adaptation, see config.py).

    Args:
        params: resolved parameters (``config.resolve_params``).
        in_features: per-point input channels besides xyz (1: height above ground).
    """

    def __init__(self, params: dict, in_features: int = 1):
        super().__init__()
        self.params = params
        self.classes = list(params["classes"])
        self.coder = PointBinResidualCoder(params["angle_bins"],
                                           [params["symmetry_orders"][c] for c in self.classes])
        self.backbone = SASABackbone(params, in_features)
        self.head = VoteHead(self.backbone.out_ch, len(self.classes), self.coder.code_size,
                             self.backbone.n_candidates, params)
        self.criterion = SASALoss(params, self.coder)

    def forward(self, batch: dict) -> dict:
        """batch: xyz (B, N, 3), features (B, N, C0) channel-last. Returns {"backbone": ..., "head": ...} (see modules)."""
        bb = self.backbone(batch["xyz"], batch["features"])
        head = self.head(bb["out_xyz"], bb["out_features"])
        return {"backbone": bb, "head": head}

    def loss(self, out: dict, batch: dict):
        """(total loss, dict of components) for a batch with gt_boxes (B, K, 7) and gt_cls (B, K) (-1 = pad)."""
        return self.criterion(out, batch)

    @torch.no_grad()
    def predict(self, out: dict, score_thresh: float | None = None, nms_mode: str | None = None,
                nms_iou: float | None = None, pre_max: int | None = None, post_max: int | None = None):
        """Post-processing: sigmoid scores, max over classes, threshold, NMS.

        Returns a list (one per scene) of dicts with ``boxes`` (K, 7) local frame (m, rad), ``scores``
        (K,), ``labels`` (K,) class indices and ``class_scores`` (K, C).
        """
        p = self.params
        score_thresh = p["score_thresh"] if score_thresh is None else score_thresh
        nms_mode = p["nms_mode"] if nms_mode is None else nms_mode
        nms_iou = p["nms_iou"] if nms_iou is None else nms_iou
        pre_max = p["nms_pre_max"] if pre_max is None else pre_max
        post_max = p["nms_post_max"] if post_max is None else post_max
        head = out["head"]
        probs = torch.sigmoid(head["cls_logits"])  # (B, Mc, C)
        scores, labels = probs.max(dim=-1)
        boxes = self.coder.decode(head["box_codes"], head["votes"], labels)
        res = []
        for b in range(boxes.shape[0]):
            m = scores[b] >= score_thresh
            bx, sc, lb, cp = boxes[b][m], scores[b][m], labels[b][m], probs[b][m]
            keep = nms(bx, sc, nms_mode, nms_iou, pre_max, post_max)
            res.append({"boxes": bx[keep], "scores": sc[keep], "labels": lb[keep], "class_scores": cp[keep]})
        return res
