"""Targets and losses of the SASA detector (reference ``PointHeadVote.get_loss`` + ``PointSASALoss``).

All losses are computed per batch and normalised as the reference does:

* **segmentation** (SASA): for SA1 and SA2 points, label 1 inside any gt box, ignored inside the box
  grown by ``seg_extra_width_m`` (total) but not in it, 0 elsewhere; BCE-with-logits summed over
  the non-ignored points / their number, times ``seg_layer_weights[l]``.
* **vote**: candidates inside a gt box grown by ``vote_extra_width_m`` (total) regress their vote to
  that box's centre; smooth-L1 (beta 1/9) summed over x, y, z, divided by the number of such
  candidates.
* **classification**: a vote inside a gt box and within ``gt_central_radius_m`` of its centre is a
  positive of that class, inside-but-farther is ignored, the rest negative; BCE-with-logits against
  one-hot x centerness (cube root of the product over l, w, h of min/max distances to opposite faces),
  summed over classes (the reference averages over classes; with 4 classes the sum keeps the 1-class
  KITTI balance), divided by the number of non-ignored votes.
* **box** (positives, divided by their number): smooth-L1 (beta 1/9) on the centre offsets and log
  sizes, cross entropy on the yaw bins and smooth-L1 on the gt-bin residual (masked for yaw-free
  classes), a corner loss (huber, delta 1, of the 8 corner distances, averaged) taking the minimum
  over the box's equivalent yaws (theta + pi and theta + 2 pi j / k; yaw-free classes use the gt
  yaw), and 1 - axis-aligned 3-D IoU of the decoded boxes.

A point inside several boxes (stacked elements) is assigned to the box with the nearest centre.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from .box_coder import PointBinResidualCoder

__all__ = ["points_in_boxes", "assign_points", "centerness", "box_corners", "SASALoss"]


def _box_coords(points: torch.Tensor, boxes: torch.Tensor):
    """Points (B, M, 3) in the frame of every box (B, K, 7): the distances (|u|, |v|, |w|), each
    (B, M, K), from the box's centre along its length, width and height axes (m)."""
    dx = points[:, :, None, 0] - boxes[:, None, :, 0]
    dy = points[:, :, None, 1] - boxes[:, None, :, 1]
    w = points[:, :, None, 2] - boxes[:, None, :, 2]
    c = torch.cos(boxes[:, None, :, 6])
    s = torch.sin(boxes[:, None, :, 6])
    return (dx * c + dy * s).abs(), (-dx * s + dy * c).abs(), w.abs()


def _inside(coords, boxes: torch.Tensor, valid: torch.Tensor, extra_m: float = 0.0) -> torch.Tensor:
    """(B, M, K) bool: the points whose box-frame distances are `coords` (``_box_coords``) lie inside
    box k grown by ``extra_m`` in total per extent; padded boxes (``valid`` False) contain nothing.
    Three comparisons joined by ``&``: the same booleans as ``.all(-1)`` over a stacked (B, M, K, 3)
    tensor, without stacking it (a reduction over a last axis of 3 is slow in PyTorch on CPU)."""
    u, v, w = coords
    lim = 0.5 * (boxes[:, None, :, 3:6] + extra_m) + 1e-5
    return (u <= lim[..., 0]) & (v <= lim[..., 1]) & (w <= lim[..., 2]) & valid[:, None, :]


def points_in_boxes(points: torch.Tensor, boxes: torch.Tensor, valid: torch.Tensor, extra_m: float = 0.0):
    """(B, M, K) bool: point m inside box k grown by ``extra_m`` in total per extent (``extra_m / 2`` per
    side, as reference ``enlarge_box3d``); padded boxes (``valid`` False) contain nothing."""
    return _inside(_box_coords(points, boxes), boxes, valid, extra_m)


def assign_points(points: torch.Tensor, boxes: torch.Tensor, valid: torch.Tensor, extra_m: float = 0.0,
                  coords=None):
    """Box index (B, M) of the nearest-centre box containing each point, -1 for none; also the (B, M, K) mask.
    coords: the points' ``_box_coords`` when the caller has them already."""
    inside = _inside(_box_coords(points, boxes) if coords is None else coords, boxes, valid, extra_m)
    d2 = ((points[:, :, None, :] - boxes[:, None, :, :3]) ** 2).sum(-1)
    d2 = torch.where(inside, d2, torch.full_like(d2, float("inf")))
    best = d2.argmin(dim=-1)
    has = inside.any(dim=-1)
    return torch.where(has, best, torch.full_like(best, -1)), inside


def centerness(points: torch.Tensor, boxes: torch.Tensor) -> torch.Tensor:
    """Centerness (K,) in [0, 1] of points (K, 3) w.r.t. their boxes (K, 7) (reference definition)."""
    d = points - boxes[:, :3]
    c, s = torch.cos(boxes[:, 6]), torch.sin(boxes[:, 6])
    loc = torch.stack([d[:, 0] * c + d[:, 1] * s, -d[:, 0] * s + d[:, 1] * c, d[:, 2]], dim=-1)
    half = 0.5 * boxes[:, 3:6]
    front = (half - loc).clamp(min=0)
    back = (half + loc).clamp(min=0)
    ratio = torch.minimum(front, back) / torch.maximum(front, back).clamp(min=1e-6)
    return ratio.prod(dim=-1).clamp(min=1e-6) ** (1.0 / 3.0)


def box_corners(boxes: torch.Tensor) -> torch.Tensor:
    """The 8 corners (..., 8, 3) of boxes (..., 7); bottom four first (same order as geometry.box_corners)."""
    x, y, z, l, w, h, yaw = boxes.unbind(-1)
    du = torch.tensor([0.5, -0.5, -0.5, 0.5] * 2, dtype=boxes.dtype, device=boxes.device)
    dv = torch.tensor([0.5, 0.5, -0.5, -0.5] * 2, dtype=boxes.dtype, device=boxes.device)
    dz = torch.tensor([-0.5] * 4 + [0.5] * 4, dtype=boxes.dtype, device=boxes.device)
    c, s = torch.cos(yaw)[..., None], torch.sin(yaw)[..., None]
    u, v = du * l[..., None], dv * w[..., None]
    return torch.stack([x[..., None] + u * c - v * s, y[..., None] + u * s + v * c, z[..., None] + dz * h[..., None]],
                       dim=-1)


def _aligned_iou3d(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Axis-aligned 3-D IoU (K,) of box pairs (K, 7) (yaw ignored)."""
    lo = torch.maximum(a[:, :3] - 0.5 * a[:, 3:6], b[:, :3] - 0.5 * b[:, 3:6])
    hi = torch.minimum(a[:, :3] + 0.5 * a[:, 3:6], b[:, :3] + 0.5 * b[:, 3:6])
    inter = (hi - lo).clamp(min=0).prod(-1)
    va, vb = a[:, 3:6].prod(-1), b[:, 3:6].prod(-1)
    return inter / (va + vb - inter).clamp(min=1e-6)


def _smooth_l1(x: torch.Tensor, beta: float) -> torch.Tensor:
    ax = x.abs()
    return torch.where(ax < beta, 0.5 * ax * ax / beta, ax - 0.5 * beta)


class SASALoss:
    """Callable computing every loss from a model output and a batch.

    Args:
        params: resolved parameters (config.py); coder: the box coder of the model.
    ``__call__(out, batch)`` returns (total loss tensor, dict of float components and diagnostics).
    """

    def __init__(self, params: dict, coder: PointBinResidualCoder):
        self.p = params
        self.coder = coder
        self.num_classes = len(params["classes"])
        orders = [int(params["symmetry_orders"][c]) for c in params["classes"]]
        # equivalent yaw offsets per class for the corner loss
        self.yaw_offsets = []
        for k in orders:
            if k == 0:
                self.yaw_offsets.append(None)
            else:
                offs = sorted({round((2 * math.pi * j / k + f * math.pi) % (2 * math.pi), 9)
                               for j in range(k) for f in (0, 1)})
                self.yaw_offsets.append(offs)

    # ------------------------------------------------------------------ segmentation (SASA)
    def segmentation_loss(self, xyzs, logits, boxes, valid):
        """Foreground segmentation loss of the SA layers with logits: per layer, binary cross-entropy of
        "inside a ground-truth box" (points in the margin `seg_extra_width_m` around a box ignored),
        weighted by `seg_layer_weights`. Returns (total loss tensor, {segN, segN_recall} floats)."""
        total = boxes.new_zeros(())
        parts = {}
        for li, (xyz, lg) in enumerate(zip(xyzs, logits)):
            if lg is None or li >= len(self.p["seg_layer_weights"]):
                continue
            w = float(self.p["seg_layer_weights"][li])
            if w == 0:
                continue
            coords = _box_coords(xyz, boxes)  # one frame change for both masks
            inside = _inside(coords, boxes, valid).any(-1)
            grown = _inside(coords, boxes, valid, float(self.p["seg_extra_width_m"])).any(-1)
            weight = (~(grown & ~inside)).to(lg.dtype)
            bce = F.binary_cross_entropy_with_logits(lg, inside.to(lg.dtype), reduction="none")
            l = (bce * weight).sum() / weight.sum().clamp(min=1.0)
            parts[f"seg{li + 1}"] = float(l.detach())
            with torch.no_grad():
                pred = lg > 0
                tp = (pred & inside).sum()
                parts[f"seg{li + 1}_recall"] = float(tp / inside.sum().clamp(min=1))
            total = total + w * l
        return total, parts

    # ------------------------------------------------------------------ head
    def __call__(self, out: dict, batch: dict):
        p = self.p
        boxes, gcls = batch["gt_boxes"], batch["gt_cls"]
        valid = gcls >= 0
        bb, head = out["backbone"], out["head"]
        seg_loss, parts = self.segmentation_loss(bb["xyz"], bb["logits"], boxes, valid)

        # vote loss
        cand, votes = head["candidates"], head["votes"]
        cand_coords = _box_coords(cand, boxes)  # also for the recall of the candidates below
        vidx, _ = assign_points(cand, boxes, valid, float(p["vote_extra_width_m"]), coords=cand_coords)
        vpos = vidx >= 0
        n_vpos = vpos.sum()
        tgt = torch.gather(boxes[..., :3], 1, vidx.clamp(min=0)[..., None].expand(-1, -1, 3))
        vl = _smooth_l1(votes - tgt, 1.0 / 9.0).sum(-1)
        vote_loss = (vl * vpos).sum() / n_vpos.clamp(min=1)

        # classification targets on (detached) votes
        v = votes.detach()
        bidx, inside = assign_points(v, boxes, valid)
        has = bidx >= 0
        b_sel = torch.gather(boxes, 1, bidx.clamp(min=0)[..., None].expand(-1, -1, 7))  # (B, Mc, 7)
        dist = (v - b_sel[..., :3]).norm(dim=-1)
        pos = has & (dist <= float(p["gt_central_radius_m"]))
        ignore = has & ~pos
        cls_idx = torch.gather(gcls, 1, bidx.clamp(min=0))
        logits = head["cls_logits"]
        onehot = torch.zeros_like(logits)
        if pos.any():
            ctr = centerness(v[pos], b_sel[pos])
            onehot[pos] = F.one_hot(cls_idx[pos], self.num_classes).to(logits.dtype) * ctr[:, None]
        cw = (~ignore).to(logits.dtype)
        bce = F.binary_cross_entropy_with_logits(logits, onehot, reduction="none").sum(-1)
        cls_loss = (bce * cw).sum() / cw.sum().clamp(min=1.0)

        # box losses on positives
        n_pos = pos.sum()
        codes = head["box_codes"]
        zero = codes.sum() * 0.0
        reg_loss = dir_cls_loss = dir_res_loss = corner_loss = iou_loss = zero
        if n_pos > 0:
            c = codes[pos]
            gt = b_sel[pos]
            lab = cls_idx[pos]
            anchors = votes[pos]
            reg_t, bin_t, res_t, amask = self.coder.encode(gt, anchors.detach(), lab)
            reg_loss = _smooth_l1(c[:, :6] - reg_t, 1.0 / 9.0).sum(-1).sum() / n_pos
            nb = self.coder.num_bins
            if amask.any():
                ce = F.cross_entropy(c[amask, 6:6 + nb], bin_t[amask], reduction="sum")
                res_pred = torch.gather(c[amask, 6 + nb:6 + 2 * nb], 1, bin_t[amask][:, None]).squeeze(1)
                rl = _smooth_l1(res_pred - res_t[amask], 1.0 / 9.0).sum()
                dir_cls_loss = ce / n_pos
                dir_res_loss = rl / n_pos
            pred_boxes = self.coder.decode(c, anchors, lab)
            corner_loss = self._corner_loss(pred_boxes, gt, lab) / n_pos
            iou_loss = (1.0 - _aligned_iou3d(pred_boxes, gt)).sum() / n_pos

        total = (seg_loss + p["loss_vote"] * vote_loss + p["loss_cls"] * cls_loss + p["loss_reg"] * reg_loss
                 + p["loss_dir_cls"] * dir_cls_loss + p["loss_dir_res"] * dir_res_loss
                 + p["loss_corner"] * corner_loss + p["loss_iou"] * iou_loss)
        parts.update(
            loss=float(total.detach()), seg=float(seg_loss.detach()), vote=float(vote_loss.detach()),
            cls=float(cls_loss.detach()), reg=float(reg_loss.detach()), dir_cls=float(dir_cls_loss.detach()),
            dir_res=float(dir_res_loss.detach()), corner=float(corner_loss.detach()), iou=float(iou_loss.detach()),
            n_pos=int(n_pos), n_vote_pos=int(n_vpos),
        )
        with torch.no_grad():  # share of gt boxes that hold at least one candidate / positive vote
            n_gt = valid.sum().clamp(min=1)
            cand_in = _inside(cand_coords, boxes, valid).any(1)
            parts["recall_candidates"] = float(cand_in.sum() / n_gt)
            hit = torch.zeros_like(valid)
            if pos.any():
                bi = torch.nonzero(pos, as_tuple=True)
                hit[bi[0], bidx[pos]] = True
            parts["recall_votes"] = float(hit.sum() / n_gt)
        return total, parts

    def _corner_loss(self, pred: torch.Tensor, gt: torch.Tensor, lab: torch.Tensor) -> torch.Tensor:
        """Sum over boxes of the mean huber(delta 1) corner distance, min over equivalent gt yaws."""
        total = pred.new_zeros(())
        for k_cls, offs in enumerate(self.yaw_offsets):
            m = lab == k_cls
            if not m.any():
                continue
            pb, gb = pred[m], gt[m]
            if offs is None:  # yaw-free: compare centre and size only
                pb = torch.cat([pb[:, :6], gb[:, 6:7]], dim=1)
                offs = [0.0]
            pc = box_corners(pb)  # (n, 8, 3)
            best = None
            for o in offs:
                g = gb.clone()
                g[:, 6] = g[:, 6] + o
                d = (pc - box_corners(g)).norm(dim=-1)  # (n, 8)
                l = torch.where(d < 1.0, 0.5 * d * d, d - 0.5).mean(-1)
                best = l if best is None else torch.minimum(best, l)
            total = total + best.sum()
        return total
