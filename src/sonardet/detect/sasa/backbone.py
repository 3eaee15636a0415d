"""PointNet++ backbone with SASA sampling (reference ``PointNet2FSMSG`` + ``PointnetSAModuleFSMSG``).

Three set-abstraction layers (see config.py for the sonar hyper-parameters):

* SA1: D-FPS over all input points;
* SA2: S-FPS (driven by the SA1 segmentation logits) + D-FPS, both over all SA1 points;
* SA3: S-FPS over the S-FPS half of SA2 (SA2 logits) + D-FPS over the D-FPS half.

Each layer: sample centres -> multi-scale (dilated shell) ball query -> [relative xyz (m), features]
-> shared MLP (linear, no bias, BN, ReLU) -> zero empty groups -> max-pool -> concat -> aggregation
(linear, BN, ReLU) -> optional segmentation branch (linear/BN/ReLU ... -> 1 logit). Sampling and ball
queries use :mod:`sonardet.detect.sasa.ops` (no gradients through indices).

CPU-oriented implementation (same function as the reference's 1x1 convolutions):

* features are channel-last, (B, N, C), and the shared MLPs are ``nn.Linear`` layers on the last
  dimension (a GEMM; ~1.5-2x faster than a 1x1 ``Conv2d`` on CPU);
* the first layer of a grouped MLP is linear in ``[x_j - c, f_j]``, so ``W [x_j - c; f_j] =
  W_xyz (x_j - c) + (W_f f)_j``: ``W_f f`` is computed once per input point and gathered, instead of
  once per (centre, neighbour) pair -- exact, and it removes most of the cost of SA3 and the vote SA.
"""

from __future__ import annotations

from contextlib import contextmanager

import torch
from torch import nn

from .ops import ball_query_shells, furthest_point_sample, index_points, semantic_furthest_point_sample

__all__ = ["MLP", "GroupedMLP", "SALayer", "SASABackbone", "shared_mlp1d", "limit_threads"]


@contextmanager
def limit_threads(n: int | None):
    """Run the enclosed torch CPU ops with at most ``n`` intra-op threads (None/0: unchanged).

    FPS and ball query issue thousands of small ops; on CPU their threading overhead dominates (a
    2048-step D-FPS on 4 x 8192 points: 0.25 s on 1 thread, 3-4 s on 2 threads of a busy 2-core
    machine), while the convolutions gain from every thread. Sampling therefore runs single-threaded.
    """
    old = torch.get_num_threads()
    if not n or n >= old:
        yield
        return
    torch.set_num_threads(int(n))
    try:
        yield
    finally:
        torch.set_num_threads(old)


class MLP(nn.Module):
    """Channel-last shared MLP: (Linear no bias -> BatchNorm1d -> ReLU) per width on the last dim."""

    def __init__(self, in_ch: int, widths):
        super().__init__()
        self.linears = nn.ModuleList()
        self.norms = nn.ModuleList()
        c = in_ch
        for w in widths:
            self.linears.append(nn.Linear(c, w, bias=False))
            self.norms.append(nn.BatchNorm1d(w))
            c = w
        self.out_ch = c

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(..., in_ch) -> (..., widths[-1])."""
        shape = x.shape[:-1]
        for lin, bn in zip(self.linears, self.norms):
            x = torch.relu(bn(lin(x).reshape(-1, lin.out_features))).reshape(*shape, lin.out_features)
        return x


def shared_mlp1d(in_ch: int, widths) -> tuple[MLP, int]:
    """Channel-last MLP of ``widths`` (may be empty: identity); returns (module, out channels)."""
    m = MLP(in_ch, widths)
    return m, m.out_ch


class GroupedMLP(nn.Module):
    """PointNet++ grouped MLP with a decomposed first layer (see module docstring).

    ``forward(xyz (B, N, 3), new_xyz (B, M, 3), features (B, N, C), idx (B, M, K), cnt (B, M))`` returns
    (B, M, w_last): max over the K neighbours of MLP([x_j - c, f_j]), zero for empty groups.
    """

    def __init__(self, in_ch: int, widths):
        super().__init__()
        widths = list(widths)
        if not widths:
            raise ValueError("a grouped MLP needs at least one layer")
        self.w_xyz = nn.Linear(3, widths[0], bias=False)
        self.w_feat = nn.Linear(in_ch, widths[0], bias=False) if in_ch > 0 else None
        self.bn0 = nn.BatchNorm1d(widths[0])
        self.rest = MLP(widths[0], widths[1:])
        self.out_ch = self.rest.out_ch

    def forward(self, xyz, new_xyz, features, idx, cnt):
        """Grouped features (B, M, w_last) of the centres (see the class docstring)."""
        rel = index_points(xyz, idx) - new_xyz.unsqueeze(2)  # (B, M, K, 3), metres
        h = self.w_xyz(rel)
        if self.w_feat is not None and features is not None:
            h = h + index_points(self.w_feat(features), idx)
        shape = h.shape
        h = torch.relu(self.bn0(h.reshape(-1, shape[-1]))).reshape(shape)
        h = self.rest(h)
        h = h * (cnt > 0).to(h.dtype)[:, :, None, None]
        return h.max(dim=2).values


class SALayer(nn.Module):
    """One set-abstraction layer with several sampling segments and multi-scale grouping.

    Args:
        in_ch: per-point feature channels C of the input (xyz not counted).
        segments: list of (npoint, lo, hi, method) with method "D-FPS" or "S-FPS": sample ``npoint``
            centres among input points [lo, hi) (hi None = all); centres are concatenated in order.
        radii: shell outer radii (m); nsamples: neighbours per shell; mlps: widths per shell.
        aggregation: output width (0: no aggregation MLP, output = concat of shells).
        confidence: segmentation branch widths (None: no branch).
        dilated: shells r_{i-1} <= d < r_i (reference DILATED_RADIUS_GROUP).
        gamma: S-FPS weight exponent.
        sampling_threads: CPU threads for sampling and ball query (see :func:`limit_threads`).
    """

    def __init__(self, in_ch: int, segments, radii, nsamples, mlps, aggregation: int, confidence=None,
                 dilated: bool = True, gamma: float = 1.0, sampling_threads: int | None = 1):
        super().__init__()
        self.sampling_threads = sampling_threads
        self.segments = [(int(n), int(lo), None if hi is None else int(hi), str(m)) for n, lo, hi, m in segments]
        self.radii = [float(r) for r in radii]
        self.nsamples = [int(s) for s in nsamples]
        self.dilated = bool(dilated)
        self.gamma = float(gamma)
        self.mlps = nn.ModuleList(GroupedMLP(in_ch, widths) for widths in mlps)
        out = sum(m.out_ch for m in self.mlps)
        if aggregation:
            self.aggregation, out = shared_mlp1d(out, [aggregation])
        else:
            self.aggregation = None
        self.out_ch = out
        if confidence is not None:
            body, c = shared_mlp1d(out, confidence)
            self.confidence = nn.Sequential(body, nn.Linear(c, 1, bias=True))
        else:
            self.confidence = None

    @property
    def npoint(self) -> int:
        """Centres this layer samples (all segments together)."""
        return sum(s[0] for s in self.segments)

    def sample(self, xyz: torch.Tensor, scores: torch.Tensor | None) -> torch.Tensor:
        """Centre indices (B, M) into the N input points."""
        parts = []
        for n, lo, hi, method in self.segments:
            hi_ = xyz.shape[1] if hi is None else hi
            sub = xyz[:, lo:hi_].contiguous()
            if method == "S-FPS":
                if scores is None:
                    raise ValueError("S-FPS needs the segmentation logits of the previous layer")
                idx = semantic_furthest_point_sample(sub, scores[:, lo:hi_].contiguous(), n, self.gamma)
            elif method == "D-FPS":
                idx = furthest_point_sample(sub, n)
            else:
                raise ValueError(f"unknown sampling method {method!r}")
            parts.append(idx + lo)
        return torch.cat(parts, dim=1)

    def forward(self, xyz: torch.Tensor, features: torch.Tensor | None, scores: torch.Tensor | None = None):
        """
        Args:
            xyz: (B, N, 3) point coordinates (m); features: (B, N, C) channel-last or None; scores:
                (B, N) logits of the previous layer (needed for S-FPS segments).
        Returns:
            new_xyz (B, M, 3), new_features (B, M, C_out), logits (B, M) or None, idx (B, M).
        """
        with limit_threads(self.sampling_threads if xyz.device.type == "cpu" else None):
            idx = self.sample(xyz, scores)
            new_xyz = index_points(xyz, idx)
            groups = ball_query_shells(self.radii, self.nsamples, xyz, new_xyz, dilated=self.dilated)
        outs = [mlp(xyz, new_xyz, features, gidx, cnt) for (cnt, gidx), mlp in zip(groups, self.mlps)]
        new_features = torch.cat(outs, dim=-1)
        if self.aggregation is not None:
            new_features = self.aggregation(new_features)
        logits = self.confidence(new_features).squeeze(-1) if self.confidence is not None else None
        return new_xyz, new_features, logits, idx


class SASABackbone(nn.Module):
    """The three SASA layers. ``forward(xyz (B, N, 3), features (B, N, C0))`` returns a dict:

    ``xyz`` list of (B, M_l, 3) per layer, ``features`` list of (B, M_l, C_l), ``logits`` list of
    (B, M_l) or None (SA3), ``idx`` list of (B, M_l) indices into the previous layer's points, and
    ``out_xyz`` / ``out_features`` = SA3's (B, M3, 3) / (B, M3, C3).
    """

    def __init__(self, params: dict, in_features: int = 1):
        super().__init__()
        n1, n2, n3 = (int(v) for v in params["sa_npoints"])
        segs = [
            [(n1, 0, None, "D-FPS")],
            [(n2 // 2, 0, None, "S-FPS"), (n2 // 2, 0, None, "D-FPS")],
            [(n3 // 2, 0, n2 // 2, "S-FPS"), (n3 // 2, n2 // 2, n2, "D-FPS")],
        ]
        conf = list(params["sa_confidence_mlps"]) + [None]
        self.layers = nn.ModuleList()
        c = in_features
        for li in range(3):
            layer = SALayer(c, segs[li], params["sa_radii_m"][li], params["sa_nsamples"][li], params["sa_mlps"][li],
                            int(params["sa_aggregation"][li]), conf[li], params["dilated_groups"],
                            params["sfps_gamma"], params.get("sampling_threads", 1))
            self.layers.append(layer)
            c = layer.out_ch
        self.out_ch = c
        self.n_candidates = n3 // 2

    def forward(self, xyz: torch.Tensor, features: torch.Tensor | None) -> dict:
        """Run the SA layers in turn (see the class docstring for the returned dict)."""
        xyzs, feats, logits, idxs = [], [], [], []
        scores = None
        for layer in self.layers:
            xyz, features, scores, idx = layer(xyz, features, scores)
            xyzs.append(xyz)
            feats.append(features)
            logits.append(scores)
            idxs.append(idx)
        return {"xyz": xyzs, "features": feats, "logits": logits, "idx": idxs, "out_xyz": xyz,
                "out_features": features}
