"""The learned vehicle detector: a small one-stage network in plain PyTorch, trained on the product's own camera.

* :mod:`~dt_highway.perception.learned.data`: synthetic frames and their labels;
* :mod:`~dt_highway.perception.learned.model`: the network, its targets, losses and decoding;
* :mod:`~dt_highway.perception.learned.train`: CPU training with checkpoints;
* :mod:`~dt_highway.evaluation.detector`: COCO AP on held-out frames (pycocotools);
* :mod:`~dt_highway.perception.learned.weights`: the weights file (``weights_only`` loading);
* :class:`LearnedDetector`: the detector interface (``detector.kind = "learned"``).

Import it lazily: it loads torch.
"""

from dt_highway.perception.learned.detector import LearnedDetector
from dt_highway.perception.learned.model import Architecture, PointDetector
from dt_highway.perception.learned.weights import SHIPPED, load_weights, save_weights

__all__ = ["SHIPPED", "Architecture", "LearnedDetector", "PointDetector", "load_weights", "save_weights"]
