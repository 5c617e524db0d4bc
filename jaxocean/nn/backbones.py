"""Convolutional backbones built from :mod:`jaxocean.nn.layers`: an encoder-decoder ResNet
and a UNet. Each is a :class:`~jaxocean.nn.layers.Layer` mapping ``(B, H, W, C_in)`` to
``(B, H, W, width)`` features at the input resolution; a head (a 1x1 ``Conv``) turns them
into outputs.

* :func:`ResNet` (He et al. 2016): a stem, ``downsample`` stride-2 convolutions, ``blocks``
  residual blocks ``conv-GN-ReLU-conv-GN + x`` at the reduced resolution, and transposed
  convolutions back up. H and W must be divisible by ``2**downsample``.
* :func:`UNet` (Ronneberger et al. 2015): per level two ``conv-GN-ReLU`` blocks, average
  pooling down, transposed convolution up, skip connections concatenated. H and W must be
  divisible by ``2**(len(widths) - 1)``.

GroupNorm uses ``min(groups, width // 2)`` groups, so every width from 2 up works.
"""

from __future__ import annotations

from jaxocean.nn import layers as nl

__all__ = ["conv_block", "ResNet", "UNet", "size_multiple"]


def _norm(width: int, groups: int) -> nl.Layer:
    g = max(1, min(groups, width // 2))
    while width % g:
        g -= 1
    return nl.GroupNorm(g)


def conv_block(width: int, *, groups: int = 8, stride: int = 1) -> nl.Layer:
    """``Conv(3x3) -> GroupNorm -> ReLU``."""
    return nl.serial(nl.Conv(width, 3, stride), _norm(width, groups), nl.Relu)


def _residual_block(width: int, groups: int) -> nl.Layer:
    body = nl.serial(conv_block(width, groups=groups), nl.Conv(width, 3), _norm(width, groups))
    return nl.serial(nl.residual(body), nl.Relu)


def _sized(layer: nl.Layer, multiple: int, name: str) -> nl.Layer:
    """``layer`` with H and W of its input (at init and apply) checked to divide by ``multiple``."""

    def check(shape):
        if len(shape) == 4 and (shape[1] % multiple or shape[2] % multiple):
            raise ValueError(f"{name} needs H and W divisible by {multiple}; got {tuple(shape[1:3])}")

    def init(key, in_shape):
        check(in_shape)
        return layer.init(key, in_shape)

    def apply(params, x, *, key=None, train=False):
        check(x.shape)
        return layer.apply(params, x, key=key, train=train)

    return nl.Layer(init, apply)


def ResNet(width: int = 32, blocks: int = 4, *, downsample: int = 1, groups: int = 8) -> nl.Layer:
    """Encoder-decoder ResNet: stem, ``downsample`` x (stride-2 conv), ``blocks`` residual
    blocks, ``downsample`` x (transposed conv + conv block). Output ``(B, H, W, width)``."""
    down = [conv_block(width, groups=groups, stride=2) for _ in range(downsample)]
    up = [nl.serial(nl.ConvTranspose(width, 2), conv_block(width, groups=groups)) for _ in range(downsample)]
    # a stride-2 convolution rounds an odd size up and the transposed one doubles it: (H + 1)
    return _sized(nl.serial(conv_block(width, groups=groups), *down,
                            *[_residual_block(width, groups) for _ in range(blocks)], *up),
                  2 ** downsample, f"ResNet(downsample={downsample})")


def UNet(widths=(16, 32, 64), *, groups: int = 8) -> nl.Layer:
    """UNet with ``len(widths)`` levels. Output ``(B, H, W, widths[0])``."""
    widths = tuple(int(w) for w in widths)
    if not widths:
        raise ValueError("UNet needs at least one level")

    def level(i):
        w = widths[i]
        block = nl.serial(conv_block(w, groups=groups), conv_block(w, groups=groups))
        if i == len(widths) - 1:
            return block
        deeper = nl.serial(nl.AvgPool(2), level(i + 1), nl.ConvTranspose(w, 2))
        return nl.serial(block, nl.fan_out(2), nl.parallel(nl.Identity, deeper), nl.fan_in_concat(),
                         conv_block(w, groups=groups), conv_block(w, groups=groups))

    return level(0)


def size_multiple(backbone: str, *, widths=(16, 32, 64), downsample: int = 1) -> int:
    """The integer that H and W must be multiples of for this backbone."""
    if backbone == "unet":
        return 2 ** (len(widths) - 1)
    if backbone == "resnet":
        return 2 ** downsample
    raise ValueError(f"unknown backbone {backbone!r}; known: 'resnet', 'unet'")
