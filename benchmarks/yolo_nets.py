"""YOLOv8-seg-shaped networks with random weights, written with plain torch (no torchvision, no
ultralytics) and exported with torch.onnx to the ultralytics segmentation signature, so the
`yolo-onnx` runtime can be timed at realistic sizes without any real weights.

The layout follows the published YOLOv8 segmentation architecture (Conv-BN-SiLU, C2f, SPPF, a PAN
neck, an anchor-free head with DFL box regression, 32 mask coefficients and a prototype branch at
stride 4), scaled by depth and width multiples: `nano` (0.33, 0.25) is the size of YOLOv8n-seg /
YOLO11n-seg, `small` (0.33, 0.50) the size of YOLOv8s-seg, which is FastSAM-s's architecture with one
class. Outputs: output0 (1, 4 + nc + 32, anchors) with xywh boxes in input pixels and sigmoid class
scores, output1 (1, 32, H / 4, W / 4).
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import torch
import torch.nn as nn

SIZES = {"nano": (0.33, 0.25), "small": (0.33, 0.50)}
NM = 32  # mask coefficients
REG_MAX = 16  # DFL bins


class ConvBNAct(nn.Module):
    def __init__(self, c_in: int, c_out: int, k: int = 1, s: int = 1):
        super().__init__()
        self.conv = nn.Conv2d(c_in, c_out, k, s, k // 2, bias=False)
        self.bn = nn.BatchNorm2d(c_out)
        self.act = nn.SiLU()

    def forward(self, x):
        return self.act(self.bn(self.conv(x)))


class Bottleneck(nn.Module):
    def __init__(self, c: int, shortcut: bool):
        super().__init__()
        self.a, self.b, self.add = ConvBNAct(c, c, 3), ConvBNAct(c, c, 3), shortcut

    def forward(self, x):
        y = self.b(self.a(x))
        return x + y if self.add else y


class C2f(nn.Module):
    """Split, n bottlenecks whose every output is kept, concatenate, fuse."""

    def __init__(self, c_in: int, c_out: int, n: int, shortcut: bool):
        super().__init__()
        self.c = c_out // 2
        self.cv1 = ConvBNAct(c_in, 2 * self.c)
        self.cv2 = ConvBNAct((2 + n) * self.c, c_out)
        self.blocks = nn.ModuleList(Bottleneck(self.c, shortcut) for _ in range(n))

    def forward(self, x):
        parts = list(self.cv1(x).chunk(2, 1))
        for block in self.blocks:
            parts.append(block(parts[-1]))
        return self.cv2(torch.cat(parts, 1))


class SPPF(nn.Module):
    def __init__(self, c_in: int, c_out: int):
        super().__init__()
        self.cv1, self.cv2 = ConvBNAct(c_in, c_in // 2), ConvBNAct(2 * c_in, c_out)
        self.pool = nn.MaxPool2d(5, 1, 2)

    def forward(self, x):
        x = self.cv1(x)
        a = self.pool(x)
        b = self.pool(a)
        return self.cv2(torch.cat([x, a, b, self.pool(b)], 1))


def _branch(c_in: int, c_mid: int, c_out: int) -> nn.Sequential:
    return nn.Sequential(ConvBNAct(c_in, c_mid, 3), ConvBNAct(c_mid, c_mid, 3), nn.Conv2d(c_mid, c_out, 1))


class SegHead(nn.Module):
    """Anchor-free boxes (DFL), class scores, mask coefficients per anchor; prototypes from P3."""

    bins: torch.Tensor  # registered buffer (1, 1, REG_MAX, 1): the DFL bin indices

    def __init__(self, nc: int, channels: tuple[int, int, int]):
        super().__init__()
        self.nc = nc
        c2, c3, c4 = max(16, channels[0] // 4, 4 * REG_MAX), max(channels[0], min(nc, 100)), max(channels[0] // 4, NM)
        self.box = nn.ModuleList(_branch(c, c2, 4 * REG_MAX) for c in channels)
        self.cls = nn.ModuleList(_branch(c, c3, nc) for c in channels)
        self.coef = nn.ModuleList(_branch(c, c4, NM) for c in channels)
        p = channels[0]
        self.proto = nn.Sequential(
            ConvBNAct(p, p, 3), nn.ConvTranspose2d(p, p, 2, 2), ConvBNAct(p, p, 3), ConvBNAct(p, NM)
        )
        self.register_buffer("bins", torch.arange(REG_MAX, dtype=torch.float32).view(1, 1, REG_MAX, 1))

    def forward(self, feats, strides=(8, 16, 32)):
        b = feats[0].shape[0]
        boxes, scores, coefs, anchors, stride_of = [], [], [], [], []
        for i, (x, s) in enumerate(zip(feats, strides)):
            h, w = x.shape[-2:]
            boxes.append(self.box[i](x).view(b, 4 * REG_MAX, -1))
            scores.append(self.cls[i](x).view(b, self.nc, -1))
            coefs.append(self.coef[i](x).view(b, NM, -1))
            ys, xs = torch.meshgrid(
                torch.arange(h, dtype=torch.float32) + 0.5, torch.arange(w, dtype=torch.float32) + 0.5, indexing="ij"
            )
            anchors.append(torch.stack([xs.reshape(-1), ys.reshape(-1)]))
            stride_of.append(torch.full((1, h * w), float(s)))
        box = torch.cat(boxes, 2).view(b, 4, REG_MAX, -1).softmax(2)
        ltrb = (box * self.bins).sum(2)  # DFL: expected distance per side, in cells
        anchor, stride = torch.cat(anchors, 1)[None], torch.cat(stride_of, 1)[None]
        lt, rb = ltrb[:, :2], ltrb[:, 2:]
        xywh = torch.cat([(anchor + (rb - lt) / 2), lt + rb], 1) * stride
        output0 = torch.cat([xywh, torch.cat(scores, 2).sigmoid(), torch.cat(coefs, 2)], 1)
        return output0, self.proto(feats[0])


class YoloSeg(nn.Module):
    """Backbone, PAN neck and segmentation head, scaled by (depth, width) multiples."""

    def __init__(self, nc: int, depth: float, width: float, max_channels: int = 1024):
        super().__init__()

        def ch(c: int) -> int:
            return int(math.ceil(min(c, max_channels) * width / 8) * 8)

        def n(k: int) -> int:
            return max(round(k * depth), 1)

        c64, c128, c256, c512, c1024 = ch(64), ch(128), ch(256), ch(512), ch(1024)
        self.stem = nn.Sequential(ConvBNAct(3, c64, 3, 2), ConvBNAct(c64, c128, 3, 2), C2f(c128, c128, n(3), True))
        self.p3 = nn.Sequential(ConvBNAct(c128, c256, 3, 2), C2f(c256, c256, n(6), True))
        self.p4 = nn.Sequential(ConvBNAct(c256, c512, 3, 2), C2f(c512, c512, n(6), True))
        self.p5 = nn.Sequential(ConvBNAct(c512, c1024, 3, 2), C2f(c1024, c1024, n(3), True), SPPF(c1024, c1024))
        self.up = nn.Upsample(scale_factor=2, mode="nearest")
        self.top4 = C2f(c1024 + c512, c512, n(3), False)
        self.top3 = C2f(c512 + c256, c256, n(3), False)
        self.down3 = ConvBNAct(c256, c256, 3, 2)
        self.out4 = C2f(c256 + c512, c512, n(3), False)
        self.down4 = ConvBNAct(c512, c512, 3, 2)
        self.out5 = C2f(c512 + c1024, c1024, n(3), False)
        self.head = SegHead(nc, (c256, c512, c1024))

    def forward(self, x):
        p3 = self.p3(self.stem(x))
        p4 = self.p4(p3)
        p5 = self.p5(p4)
        t4 = self.top4(torch.cat([self.up(p5), p4], 1))
        o3 = self.top3(torch.cat([self.up(t4), p3], 1))
        o4 = self.out4(torch.cat([self.down3(o3), t4], 1))
        o5 = self.out5(torch.cat([self.down4(o4), p5], 1))
        return self.head([o3, o4, o5])


def conv_gflops(model: nn.Module, shape: tuple[int, int]) -> float:
    """GFLOPs (2 x multiply-adds) of the model's convolutions for one (H, W) input."""
    total = [0]

    def hook(module, inputs, output):
        k = module.kernel_size[0] * module.kernel_size[1]
        c_in = module.in_channels // module.groups
        total[0] += 2 * output.numel() * k * c_in

    handles = [m.register_forward_hook(hook) for m in model.modules() if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d))]
    with torch.no_grad():
        model(torch.zeros(1, 3, *shape))
    for h in handles:
        h.remove()
    return total[0] / 1e9


def export(path: Path, names: list[str], size: str, imgsz: tuple[int, int] = (640, 640), seed: int = 0) -> dict:
    """Write a random-weight YOLO-seg of `size` with classes `names` as an ultralytics-style ONNX export."""
    import warnings

    import onnx

    torch.manual_seed(seed)
    depth, width = SIZES[size]
    model = YoloSeg(len(names), depth, width).eval()
    params = sum(p.numel() for p in model.parameters())
    gflops = conv_gflops(model, imgsz)
    buffer = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # The TorchScript exporter (dynamo=False) writes to a file object; torch annotates `f` as a path only.
        torch.onnx.export(
            model,
            (torch.zeros(1, 3, *imgsz),),
            buffer,  # pyright: ignore[reportArgumentType]
            dynamo=False,
            opset_version=17,
            input_names=["images"],
            output_names=["output0", "output1"],
            do_constant_folding=True,
        )
    proto = onnx.load_from_string(buffer.getvalue())
    for key, value in {
        "names": str(dict(enumerate(names))),
        "imgsz": str(list(imgsz)),
        "stride": "32",
        "task": "segment",
    }.items():
        prop = proto.metadata_props.add()
        prop.key, prop.value = key, value
    onnx.save(proto, str(path))
    return {"params_m": params / 1e6, "gflops": gflops, "bytes": Path(path).stat().st_size}
