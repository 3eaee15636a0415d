"""3DSSD-style vote head (reference ``PointHeadVote``).

Candidates are the S-FPS half of the SA3 points. Each predicts an offset (clamped to
``vote_range_m``) -> vote = candidate + offset; an SA module groups the SA3 points and features around
every vote (plain balls ``vote_radii_m``) -> shared FC -> per-class logits (sigmoid, no background)
and box codes (:class:`~.box_coder.PointBinResidualCoder`) relative to the vote.
"""

from __future__ import annotations

import torch
from torch import nn

from .backbone import GroupedMLP, limit_threads, shared_mlp1d
from .ops import ball_query_shells

__all__ = ["VoteHead"]


class VoteHead(nn.Module):
    """Vote layer + vote SA + classification / regression branches (channel-last).

    Args:
        in_ch: SA3 feature channels; num_classes: C; code_size: box code length; n_candidates: the
        first ``n_candidates`` SA3 points (the S-FPS half) vote; params: see config.py.

    ``forward(xyz (B, M3, 3), features (B, M3, C3))`` returns a dict with ``candidates`` (B, Mc, 3),
    ``votes`` (B, Mc, 3) (m), ``cls_logits`` (B, Mc, C) and ``box_codes`` (B, Mc, code_size).
    """

    def __init__(self, in_ch: int, num_classes: int, code_size: int, n_candidates: int, params: dict):
        super().__init__()
        self.n_candidates = int(n_candidates)
        self.sampling_threads = params.get("sampling_threads", 1)
        body, c = shared_mlp1d(in_ch, params["vote_mlp"])
        self.vote_layer = nn.Sequential(body, nn.Linear(c, 3, bias=True))
        self.register_buffer("vote_range", torch.tensor(params["vote_range_m"], dtype=torch.float32), persistent=False)
        self.radii = [float(r) for r in params["vote_radii_m"]]
        self.nsamples = [int(s) for s in params["vote_nsamples"]]
        compact = params.get("compact_groups", True)
        self.vote_mlps = nn.ModuleList(GroupedMLP(in_ch, widths, compact) for widths in params["vote_mlps"])
        out = sum(m.out_ch for m in self.vote_mlps)
        self.shared_fc, c = shared_mlp1d(out, params["head_shared_fc"])
        cls_body, cc = shared_mlp1d(c, params["head_cls_fc"])
        self.cls_layers = nn.Sequential(cls_body, nn.Linear(cc, num_classes, bias=True))
        reg_body, cr = shared_mlp1d(c, params["head_reg_fc"])
        self.reg_layers = nn.Sequential(reg_body, nn.Linear(cr, code_size, bias=True))
        self._init_weights()

    def _init_weights(self) -> None:
        """Reference init: xavier-normal weights, zero biases (the head and its SA module); the class
        logits start at -2 (sigmoid 0.12) so the early BCE of the many background votes stays small."""
        for m in self.modules():
            if isinstance(m, nn.Linear):
                nn.init.xavier_normal_(m.weight)
                if m.bias is not None:
                    nn.init.zeros_(m.bias)
        nn.init.constant_(self.cls_layers[-1].bias, -2.0)

    def forward(self, xyz: torch.Tensor, features: torch.Tensor) -> dict:
        """Votes, classification logits and box codes of the candidates (see the class docstring)."""
        mc = self.n_candidates
        cand = xyz[:, :mc].contiguous()
        offset = self.vote_layer(features[:, :mc])  # (B, Mc, 3)
        rng = self.vote_range.to(offset.dtype)
        offset = torch.maximum(torch.minimum(offset, rng), -rng)
        votes = cand + offset
        with limit_threads(self.sampling_threads if xyz.device.type == "cpu" else None):
            groups = ball_query_shells(self.radii, self.nsamples, xyz, votes.detach(), dilated=False)
        outs = [mlp(xyz, votes, features, gidx, cnt) for (cnt, gidx), mlp in zip(groups, self.vote_mlps)]
        f = self.shared_fc(torch.cat(outs, dim=-1))
        return {
            "candidates": cand,
            "votes": votes,
            "cls_logits": self.cls_layers(f),
            "box_codes": self.reg_layers(f),
        }
