"""Hand-written neural networks in the stax style, trained through the renderer.

* :mod:`jaxocean.nn.layers` -- layers ``(init, apply)`` and combinators;
* :mod:`jaxocean.nn.backbones` -- ResNet and UNet built from them;
* :mod:`jaxocean.nn.geometry` -- image -> per-pixel normal and roughness (``load``,
  ``predict``; ``load()`` is the shipped pretrained model);
* :mod:`jaxocean.nn.geometry_train` -- losses, configs, ``train`` and ``evaluate``;
* :mod:`jaxocean.nn.waves` -- a geometry sequence -> component waves (``load``, ``predict``;
  ``load()`` is the shipped pretrained model); :mod:`jaxocean.nn.waves_train` -- its losses,
  configs and ``train``;
* :mod:`jaxocean.nn.training` -- the resumable, data-parallel training loop;
* :mod:`jaxocean.nn.checkpoint`, :mod:`jaxocean.nn.metrics`, :mod:`jaxocean.nn.discriminators`.
"""

from jaxocean.nn import backbones, checkpoint, discriminators, geometry, layers, metrics, training, waves
from jaxocean.nn.checkpoint import CheckpointError

__all__ = ["layers", "backbones", "geometry", "waves", "training", "checkpoint", "metrics", "discriminators",
           "CheckpointError"]
