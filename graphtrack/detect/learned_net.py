"""The learned detector's network: a tiny fully-convolutional line / junction net.

``LineNet`` maps an RGB image at reduced resolution (the detector feeds it the
undistorted frame resized by 1/4, 540x960 -> 135x240) to two maps of the same
size, as logits:

    channel 0: the line heatmap (sigmoid -> H in [0, 1]): 1 on the shaft's
               silhouette edges, 0 elsewhere;
    channel 1: the junction heatmap: 1 at segment endpoints (the shaft end
               near the wrist, and where an edge leaves the image).

Architecture (a small U-Net of depthwise-separable blocks, ~25k parameters,
~0.1 GMAC at 135x240, so it runs in a few ms on one CPU core):

    stem   3x3 conv 3->C0                 full (of the reduced) resolution
    down1  dw-sep stride 2 C0->2C,  dw-sep 2C->2C                   1/2
    down2  dw-sep stride 2 2C->4C, dw-sep dilated 2 and 4 (context)  1/4
    up1    1x1 4C->2C, bilinear x2, + down1, dw-sep                 1/2
    up2    1x1 2C->C0, bilinear x2, + stem,  dw-sep                 full
    head   1x1 C0->2

with C = ``width`` (16), C0 = ``stem`` (8): few channels at the largest
resolution, where the time goes. BatchNorm + ReLU after every conv but the
head; :meth:`LineNet.fused` folds the BatchNorms for inference.
Inputs: float (B, 3, h, w) RGB in [0, 1]; any h, w >= 4 (the decoder
resizes to the skip connections' sizes, so no padding is needed).
"""
from __future__ import annotations

import copy

import torch
import torch.nn.functional as F
from torch import nn

#: Version tag stored with the weights; bump when the architecture changes.
ARCH = "linenet-v1"


class ConvBNReLU(nn.Sequential):
    def __init__(self, cin: int, cout: int, k: int = 3, stride: int = 1, dilation: int = 1,
                 groups: int = 1):
        pad = dilation * (k // 2)
        super().__init__(nn.Conv2d(cin, cout, k, stride, pad, dilation=dilation, groups=groups, bias=False),
                         nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class DWSep(nn.Sequential):
    """Depthwise 3x3 (stride / dilation) then pointwise 1x1, each with BN + ReLU."""

    def __init__(self, cin: int, cout: int, stride: int = 1, dilation: int = 1):
        super().__init__(ConvBNReLU(cin, cin, 3, stride, dilation, groups=cin), ConvBNReLU(cin, cout, 1))


class Pointwise(nn.Module):
    """A 1x1 convolution (groups 1) as one matrix product over the pixels:
    y[n, :, i, j] = W x[n, :, i, j] + b, with X the (N h w, C_in) pixel matrix, computed as

    - X W^T + b (default): on channels-last (NHWC) input X is a view and the output comes
      back channels-last; on this net's wider 1x1 layers it is faster on one core than the
      convolution kernels, which copy the input;
    - W X^T + b (``transposed``): the output is NCHW. Where C_out is small (the net's 8- and
      2-channel layers) this orientation is 3-4x faster on one core (a (32400, 8) x (8, 2)
      product 277 us, its transpose 107 us); ``channels_last`` converts the output back
      for a following convolution (docs/decisions/stereo-detection.md).

    Inference only: the bias is added in place."""

    def __init__(self, conv: nn.Conv2d, transposed: bool = False, channels_last: bool = False):
        super().__init__()
        cout, cin = conv.weight.shape[:2]
        self.transposed, self.channels_last = bool(transposed), bool(channels_last)
        w = conv.weight.detach().reshape(cout, cin)
        # the operand of this orientation's product: W (cout, cin) for W X^T, W^T (cin, cout) for X W^T
        self.register_buffer("weight", w.clone() if self.transposed else w.t().contiguous())
        bias = conv.bias.detach() if conv.bias is not None else torch.zeros(cout)
        self.register_buffer("bias", bias.clone())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        n, c, h, w = x.shape
        if self.transposed:
            y = torch.mm(self.weight, x.permute(1, 0, 2, 3).reshape(c, -1))   # (cout, N h w)
            y += self.bias[:, None]
            y = y.view(-1, n, h, w).permute(1, 0, 2, 3)
            return y.contiguous(memory_format=torch.channels_last) if self.channels_last else y
        y = torch.mm(x.permute(0, 2, 3, 1).reshape(-1, c), self.weight)
        y += self.bias      # in place: a frozen trace runs addmm as mm + add, which allocates
        return y.view(n, h, w, -1).permute(0, 3, 1, 2)


#: a 1x1 layer with at most this many outputs runs as W X^T (:class:`Pointwise`)
NARROW = 8


def _is_pointwise(m: nn.Module) -> bool:
    return (isinstance(m, nn.Conv2d) and m.kernel_size == (1, 1) and m.stride == (1, 1) and m.groups == 1
            and m.padding in ((0, 0), 0))


class LineNet(nn.Module):
    def __init__(self, width: int = 16, stem: int = 8):
        super().__init__()
        c, c0 = int(width), int(stem)
        self.width, self.stem_width = c, c0
        self.stem = ConvBNReLU(3, c0, 3)
        self.down1 = nn.Sequential(DWSep(c0, 2 * c, stride=2), DWSep(2 * c, 2 * c))
        self.down2 = nn.Sequential(DWSep(2 * c, 4 * c, stride=2), DWSep(4 * c, 4 * c, dilation=2),
                                   DWSep(4 * c, 4 * c, dilation=4))
        self.lat1 = ConvBNReLU(4 * c, 2 * c, 1)
        self.up1 = DWSep(2 * c, 2 * c)
        self.lat2 = ConvBNReLU(2 * c, c0, 1)
        self.up2 = DWSep(c0, c0)
        self.head = nn.Conv2d(c0, 2, 1)
        self.register_buffer("mean", torch.tensor([0.45, 0.40, 0.40]).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor([0.25, 0.25, 0.25]).view(1, 3, 1, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = (x - self.mean) / self.std
        s0 = self.stem(x)
        s1 = self.down1(s0)
        s2 = self.down2(s1)
        u1 = F.interpolate(self.lat1(s2), size=s1.shape[-2:], mode="bilinear", align_corners=False)
        u1 = self.up1(u1 + s1)
        u2 = F.interpolate(self.lat2(u1), size=s0.shape[-2:], mode="bilinear", align_corners=False)
        u2 = self.up2(u2 + s0)
        return self.head(u2)

    @torch.no_grad()
    def fused(self) -> "LineNet":
        """An inference copy with every BatchNorm folded into its conv and every 1x1
        convolution a :class:`Pointwise` product (eval only; the layers with at most
        ``NARROW`` outputs transposed, so the logits come out NCHW)."""
        net = copy.deepcopy(self).eval()
        for m in net.modules():
            if isinstance(m, ConvBNReLU) and isinstance(m[1], nn.BatchNorm2d):
                conv, bn = m[0], m[1]
                scale = bn.weight / torch.sqrt(bn.running_var + bn.eps)
                fconv = nn.Conv2d(conv.in_channels, conv.out_channels, conv.kernel_size, conv.stride,
                                  conv.padding, conv.dilation, conv.groups, bias=True)
                fconv.weight.copy_(conv.weight * scale.view(-1, 1, 1, 1))
                fconv.bias.copy_(bn.bias - bn.running_mean * scale)
                m[0] = fconv
                m[1] = nn.Identity()
        for m in list(net.modules()):
            for name, child in list(m.named_children()):
                if _is_pointwise(child):
                    setattr(m, name, Pointwise(child, transposed=child.out_channels <= NARROW))
        # lat2's output is upsampled and added to the stem's for a depthwise convolution:
        # channels-last; up2's 1x1 feeds the head, and the head's is the output: NCHW
        net.lat2[0].channels_last = True
        return net


def build(width: int = 16, stem: int = 8) -> LineNet:
    return LineNet(width, stem)
