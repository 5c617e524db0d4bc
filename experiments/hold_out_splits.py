"""Rewrite a larger dataset's splits so that it holds out a smaller one's test and validation scenes.

    python experiments/hold_out_splits.py DATASET [--like 400]

``jaxocean simulate`` draws scene i from the seed and i alone, so the first 400 scenes of
``simulate --scenes 1200 --seed 5`` are those of ``simulate --scenes 400 --seed 5``. This
script writes DATASET/splits.json with the 400-scene dataset's test and validation scenes as
its test and validation splits and every other scene for training: a model trained on the
larger dataset is then scored on the same test scenes as the models trained on the smaller
one (the shipped ``gpu`` geometry model was trained this way; docs/training.md).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from jaxocean.files import write_json  # noqa: E402
from jaxocean.io.dataset import DATASET_FILENAME, SPLITS_FILENAME, split_scenes  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset")
    ap.add_argument("--like", type=int, default=400, help="scene count of the smaller dataset (same seed)")
    args = ap.parse_args(argv)
    root = Path(args.dataset)
    settings = json.loads((root / DATASET_FILENAME).read_text())
    n, seed = settings["scenes"], settings["seed"]
    if n < args.like:
        sys.exit(f"{root} holds {n} scenes, fewer than the {args.like} of the dataset to hold out")
    small = split_scenes(args.like, seed)
    held = set(small["test"]) | set(small["val"])
    splits = {"train": [i for i in range(n) if i not in held], "val": small["val"], "test": small["test"]}
    write_json(root / SPLITS_FILENAME, splits)
    print({k: len(v) for k, v in splits.items()})


if __name__ == "__main__":
    main()
