"""A small one-stage vehicle detector in plain PyTorch ("objects as points").

The network (:class:`PointDetector`) reads an RGB image (optionally inverse depth as a fourth
channel) and predicts, on a grid of stride 4:

* a **centre heatmap**: the probability that a vehicle's visible box is centred at a cell
  (Zhou, Wang & Kraehenbuehl 2019, "Objects as Points", CenterNet);
* at every cell, the **distances from the cell to the box's four edges** ``l, t, r, b`` [px],
  as in TTFNet (Liu et al. 2020, "Training-Time-Friendly Network"), which trains the box with
  a GIoU loss at all cells near the centre, not only at the centre: it converges in far fewer
  steps, which is what a CPU training run needs.

Decoding needs no NMS: local maxima of the heatmap (3 x 3 max pooling) are the detections.

Backbone: five stride-2 stages of 3 x 3 conv + batch norm + ReLU (strides 2 to 32), a
top-down path (FPN-like, nearest upsampling and 1 x 1 lateral convs) back to stride 4, two
3 x 3 convs, then two 1 x 1 outputs. About 0.5 M parameters, 2 MB of weights.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

STRIDE = 4
"""Output grid stride [px]"""
PAD_TO = 32
"""Input height and width are padded to a multiple of this (the deepest stage's stride)"""
INV_DEPTH_NEAR_M = 2.0
"""Depth channel: ``min(1, INV_DEPTH_NEAR_M / depth)``, inverse depth, 1 up to 2 m [m]"""
BOX_SCALE_PX = 8.0
"""Edge distances are ``softplus(raw) * BOX_SCALE_PX`` [px]"""
GAUSS_ALPHA = 0.54
"""TTFNet's alpha: the centre Gaussian's sigma is ``alpha * size / 6`` per axis"""
MEAN = torch.tensor([0.45, 0.45, 0.45, 0.5]).view(1, 4, 1, 1)
STD = torch.tensor([0.25, 0.25, 0.25, 0.3]).view(1, 4, 1, 1)


@dataclass(frozen=True)
class Architecture:
    """Shape of a :class:`PointDetector` (stored with the weights).

    :param width_px: input image width [px]
    :param height_px: input image height [px]
    :param depth: inverse depth as a fourth input channel
    :param channels: channels of the stride 2, 4, 8, 16, 32 stages
    :param features: channels of the top-down path and the head
    """

    width_px: int = 320
    height_px: int = 180
    depth: bool = False
    channels: tuple[int, ...] = (16, 32, 64, 96, 128)
    features: int = 32

    @property
    def in_channels(self) -> int:
        """Input channels (3, or 4 with depth)."""
        return 4 if self.depth else 3

    @property
    def padded(self) -> tuple[int, int]:
        """Input ``(height, width)`` after padding to a multiple of :data:`PAD_TO` [px]."""
        return (-(-self.height_px // PAD_TO) * PAD_TO, -(-self.width_px // PAD_TO) * PAD_TO)

    def to_dict(self) -> dict:
        """A dict of plain values (safe for ``torch.load(weights_only=True)``).

        :return: the fields by name, ``channels`` as a list
        """
        d = asdict(self)
        d["channels"] = list(self.channels)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Architecture:
        """Inverse of :meth:`to_dict`.

        :param d: a dict as :meth:`to_dict` makes it
        :return: the architecture
        """
        d = dict(d)
        d["channels"] = tuple(int(c) for c in d["channels"])
        return cls(**d)


def _cbr(c_in: int, c_out: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, 3, stride, 1, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True))


class PointDetector(nn.Module):
    """The network: image in, ``(heatmap logits (B, 1, h, w), edge distances (B, 4, h, w) [px])`` out.

    :param arch: its shape
    """

    def __init__(self, arch: Architecture = Architecture()) -> None:
        super().__init__()
        if len(arch.channels) != 5:
            raise ValueError(f"channels must list 5 stages (got {len(arch.channels)})")
        self.arch = arch
        c, f = arch.channels, arch.features
        self.stem = _cbr(arch.in_channels, c[0], 2)
        self.s4 = nn.Sequential(_cbr(c[0], c[1], 2), _cbr(c[1], c[1]))
        self.s8 = nn.Sequential(_cbr(c[1], c[2], 2), _cbr(c[2], c[2]))
        self.s16 = nn.Sequential(_cbr(c[2], c[3], 2), _cbr(c[3], c[3]))
        self.s32 = nn.Sequential(_cbr(c[3], c[4], 2), _cbr(c[4], c[4]))
        self.lat = nn.ModuleList([nn.Conv2d(ci, f, 1) for ci in (c[1], c[2], c[3], c[4])])
        self.head = nn.Sequential(_cbr(f, f), _cbr(f, f))
        self.heat = nn.Conv2d(f, 1, 1)
        self.box = nn.Conv2d(f, 4, 1)
        # CenterNet's prior: start with heatmap probabilities of about 0.01
        bias = self.heat.bias
        assert bias is not None  # nn.Conv2d's default bias=True
        nn.init.constant_(bias, -math.log((1 - 0.01) / 0.01))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Run the network on a batch of images.

        :param x: ``(B, C, H, W)`` normalised input (see :func:`to_input`), H and W multiples of 32.

        :return: heatmap logits ``(B, 1, H / 4, W / 4)`` and edge distances ``(B, 4, H / 4, W / 4)`` [px]
        """
        x4 = self.s4(self.stem(x))
        x8 = self.s8(x4)
        x16 = self.s16(x8)
        x32 = self.s32(x16)
        p = self.lat[3](x32)
        for lat, skip in ((self.lat[2], x16), (self.lat[1], x8), (self.lat[0], x4)):
            p = F.interpolate(p, scale_factor=2.0, mode="nearest") + lat(skip)
        h = self.head(p)
        return self.heat(h), F.softplus(self.box(h)) * BOX_SCALE_PX


def to_input(rgb: torch.Tensor, arch: Architecture, inv_depth: torch.Tensor | None = None) -> torch.Tensor:
    """Normalise and pad a batch for the network.

    :param rgb: ``uint8 (B, H, W, 3)`` images (any size: the network is fully convolutional)
    :param arch: the architecture
    :param inv_depth: ``float (B, H, W)`` inverse depth channel in ``[0, 1]`` (depth models)
    :return: ``float32 (B, C, H', W')`` padded with zeros (channels-last memory)
    """
    x = rgb.permute(0, 3, 1, 2).float().div_(255.0)
    if arch.depth:
        if inv_depth is None:
            raise ValueError("this detector reads depth: give the frame's depth image")
        x = torch.cat([x, inv_depth[:, None].float()], dim=1)
    c = x.shape[1]
    x = (x - MEAN[:, :c]) / STD[:, :c]
    hp, wp = -(-x.shape[2] // PAD_TO) * PAD_TO, -(-x.shape[3] // PAD_TO) * PAD_TO
    x = F.pad(x, (0, wp - x.shape[3], 0, hp - x.shape[2]))
    return x.contiguous(memory_format=torch.channels_last)


def inverse_depth(depth_m: np.ndarray) -> np.ndarray:
    """The depth channel: ``min(1, 2 m / depth)`` (near things large, the sky near 0).

    :param depth_m: planar depth image [m]
    :return: ``float32`` inverse depth in ``[0, 1]``, same shape
    """
    return np.minimum(1.0, INV_DEPTH_NEAR_M / np.maximum(depth_m, 1e-3)).astype(np.float32)


def cell_centres(h: int, w: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixel coordinates ``(x (w,), y (h,))`` of the output cells' centres [px].

    Cell ``j`` covers input pixels ``4j .. 4j + 3`` whose centres are at integers, so its
    centre is ``4j + 1.5``.

    :param h: output grid height [cells]
    :param w: output grid width [cells]
    :return: the centres' ``x`` ``(w,)`` and ``y`` ``(h,)`` [px]
    """
    return torch.arange(w) * STRIDE + (STRIDE - 1) / 2.0, torch.arange(h) * STRIDE + (STRIDE - 1) / 2.0


# ----------------------------------------------------------------------------- targets and loss
def make_targets(boxes: np.ndarray, grid_hw: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Training targets of one image (TTFNet's): heatmap, box per cell and box weight per cell.

    :param boxes: ``(N, 4)`` visible boxes [px]
    :param grid_hw: output grid ``(h, w)``
    :return: ``heat (1, h, w)`` Gaussian peaks (1 at each box's centre cell), ``box (4, h, w)``
        target box ``x1, y1, x2, y2`` [px] of each cell, ``weight (1, h, w)`` [-] (0: no box)
    """
    gh, gw = grid_hw
    heat = np.zeros((gh, gw), dtype=np.float32)
    box = np.zeros((4, gh, gw), dtype=np.float32)
    weight = np.zeros((gh, gw), dtype=np.float32)
    if len(boxes) == 0:
        return heat[None], box, weight[None]
    xs = np.arange(gw) * STRIDE + (STRIDE - 1) / 2.0
    ys = np.arange(gh) * STRIDE + (STRIDE - 1) / 2.0
    area = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    # large boxes first: a smaller box in front wins the cells they share
    for i in np.argsort(-area):
        x1, y1, x2, y2 = boxes[i]
        cx, cy = (x1 + x2) / 2.0, (y1 + y2) / 2.0
        sx = max(GAUSS_ALPHA * (x2 - x1) / 6.0, 0.5 * STRIDE / 3.0)
        sy = max(GAUSS_ALPHA * (y2 - y1) / 6.0, 0.5 * STRIDE / 3.0)
        # the centre cell gets exactly 1
        ci = int(np.clip(np.floor((cx + 0.5) / STRIDE), 0, gw - 1))
        cj = int(np.clip(np.floor((cy + 0.5) / STRIDE), 0, gh - 1))
        gx = np.exp(-((xs - xs[ci]) ** 2) / (2 * sx * sx))
        gy = np.exp(-((ys - ys[cj]) ** 2) / (2 * sy * sy))
        g = (gy[:, None] * gx[None, :]).astype(np.float32)
        np.maximum(heat, g, out=heat)
        # box targets on the cells of the Gaussian's core that lie inside the box
        inside = (xs[None, :] >= x1) & (xs[None, :] <= x2) & (ys[:, None] >= y1) & (ys[:, None] <= y2)
        core = (g > 0.3) & inside
        core[cj, ci] = True
        w = g * np.log(max(area[i], 2.0))
        w = w / max(float(w[core].sum()), 1e-6) * np.log(max(area[i], 2.0))
        box[:, core] = boxes[i][:, None].astype(np.float32)
        weight[core] = w[core]
    return heat[None], box, weight[None]


def focal_loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """CenterNet's penalty-reduced focal loss (alpha 2, beta 4), summed over cells and divided by the peak count.

    :param logits: heatmap logits ``(B, 1, h, w)``
    :param target: target heatmap ``(B, 1, h, w)`` in ``[0, 1]``, 1 at the peaks (:func:`make_targets`)
    :return: the loss, a scalar tensor
    """
    p = torch.sigmoid(logits).clamp(1e-4, 1 - 1e-4)
    pos = target.eq(1.0).float()
    neg = 1.0 - pos
    pos_loss = torch.log(p) * (1 - p) ** 2 * pos
    neg_loss = torch.log(1 - p) * p**2 * (1 - target) ** 4 * neg
    n = pos.sum().clamp(min=1.0)
    return -(pos_loss.sum() + neg_loss.sum()) / n


def decode_boxes(dist: torch.Tensor) -> torch.Tensor:
    """Edge distances ``(B, 4, h, w)`` [px] to boxes ``(B, 4, h, w)`` ``x1, y1, x2, y2`` [px].

    :param dist: each cell's distances from its centre to the left, top, right and bottom edge ``(B, 4, h, w)`` [px]
    :return: each cell's box ``(B, 4, h, w)`` ``x1, y1, x2, y2`` [px]
    """
    xs, ys = cell_centres(dist.shape[2], dist.shape[3])
    xs, ys = xs.to(dist)[None, :], ys.to(dist)[:, None]
    return torch.stack([xs - dist[:, 0], ys - dist[:, 1], xs + dist[:, 2], ys + dist[:, 3]], dim=1)


def giou_loss(pred: torch.Tensor, target: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Generalised-IoU loss (Rezatofighi et al. 2019) of boxes ``(B, 4, h, w)``, weighted per cell.

    :param pred: predicted boxes ``(B, 4, h, w)`` ``x1, y1, x2, y2`` [px] (:func:`decode_boxes`)
    :param target: target boxes ``(B, 4, h, w)`` [px]
    :param weight: box weight per cell ``(B, 1, h, w)`` [-] (0: no box)
    :return: 5 times the weighted mean of ``1 - GIoU`` over the cells with a weight (0 when none), a scalar tensor
    """
    m = weight[:, 0] > 0
    if not bool(m.any()):
        return pred.sum() * 0.0
    p = pred.permute(0, 2, 3, 1)[m]
    t = target.permute(0, 2, 3, 1)[m]
    w = weight[:, 0][m]
    ix1, iy1 = torch.maximum(p[:, 0], t[:, 0]), torch.maximum(p[:, 1], t[:, 1])
    ix2, iy2 = torch.minimum(p[:, 2], t[:, 2]), torch.minimum(p[:, 3], t[:, 3])
    inter = (ix2 - ix1).clamp(min=0) * (iy2 - iy1).clamp(min=0)
    area_p = (p[:, 2] - p[:, 0]) * (p[:, 3] - p[:, 1])
    area_t = (t[:, 2] - t[:, 0]) * (t[:, 3] - t[:, 1])
    union = area_p + area_t - inter
    iou = inter / union.clamp(min=1e-6)
    ex1, ey1 = torch.minimum(p[:, 0], t[:, 0]), torch.minimum(p[:, 1], t[:, 1])
    ex2, ey2 = torch.maximum(p[:, 2], t[:, 2]), torch.maximum(p[:, 3], t[:, 3])
    enclose = ((ex2 - ex1) * (ey2 - ey1)).clamp(min=1e-6)
    giou = iou - (enclose - union) / enclose
    return ((1 - giou) * w).sum() / w.sum().clamp(min=1e-6) * 5.0


# ----------------------------------------------------------------------------- decoding
def peaks(heat_logits: torch.Tensor, dist: torch.Tensor, max_detections: int = 100,
          min_score: float = 0.05) -> list[tuple[np.ndarray, np.ndarray]]:
    """Detections from the network's outputs: local maxima of the heatmap, no NMS.

    :param heat_logits: ``(B, 1, h, w)``
    :param dist: ``(B, 4, h, w)`` edge distances [px]
    :param max_detections: most detections per image
    :param min_score: least score kept [-]
    :return: per image ``(boxes (N, 4) [px] in the network's input frame, scores (N,))``
    """
    heat = torch.sigmoid(heat_logits)
    keep = heat == F.max_pool2d(heat, 3, 1, 1)
    heat = heat * keep
    b, _, h, w = heat.shape
    k = min(max_detections, h * w)
    scores, idx = heat.view(b, -1).topk(k)
    boxes = decode_boxes(dist).view(b, 4, -1)
    out = []
    for i in range(b):
        ok = (scores[i] >= min_score) & (scores[i] > 0)  # cells suppressed by the pooling score 0
        sel = idx[i][ok]
        out.append((boxes[i][:, sel].T.numpy().astype(float), scores[i][ok].numpy().astype(float)))
    return out
